"""Stochastic iteration with the single-ray random transport operator
(Szirmay-Kalos, "Stochastic Iteration for Non-diffuse Global Illumination", section 4)."""
import drjit as dr
import mitsuba as mi

from mi_plugins.base import limits, seeds, errors, queries
from mi_plugins.render import checks
from mi_plugins.render import burn_in
from mi_plugins.render.core import HIDE_EMITTERS, MAX_ITERATIONS, CoreIntegrator
from mi_plugins.render.frame import coverage
from mi_plugins.render.camera import first_shown, unoccluded
from mi_plugins.render.handoff import Handoff
from mi_plugins.light.sources import sample_light_rays
from mi_plugins.base.param_docs import Row, documented
from mi_plugins.base.params import Params

#: memory per chain at most (its ray, power, depth and random state, twice while a step
#: replaces them, and the step's splat)
BYTES_PER_CHAIN = 256
#: emitted rays start this far (relative to 1 + their largest coordinate) off the light,
#: as Mitsuba's spawn_ray offsets rays off a surface
SPAWN_EPSILON = 1e-4


#: the parameters of ``stochastic_ray``
ROWS = (
    Row("iterations", "int", "32", ">= 1 transport steps per chain (more when the burn-in is lengthened, below)"),
    Row("burn_in", "int", "fitted to the scene, at least min(8, iterations - 1)",
        "0 .. iterations - 1 first steps left out of the average; given, it is used as it is"),
    Row("max_iterations", "int", "max(4096, iterations)",
        ">= iterations: the most steps the burn-in fitting and the drift check may run"),
    Row("max_depth", "int", "-1",
        "-1 (unbounded) or >= 0, Mitsuba's convention (1 = emission only); chains restart when they reach it"),
    HIDE_EMITTERS,
)


@documented(ROWS)
class StochasticRayIntegrator(CoreIntegrator):
    r"""
    .. _integrator-stochastic_ray:

    ``stochastic_ray`` (stochastic iteration, single-ray operator)
    --------------------------------------------------------------

    Szirmay-Kalos, section 4: the iteration L_n = Le + T*_n L_{n-1}, where each random
    operator sends the whole power of L_{n-1} along ONE ray: restart from the lights with
    probability Phi_e / Phi_n (Phi_e: emitted power, Phi_n: power carried), otherwise
    continue from the last hit in a BSDF-sampled direction (the BSDF evaluated as
    Mitsuba's path tracer evaluates it on the same path: any Mitsuba BSDF, shading normals,
    bump and normal maps, negative simulated emission). Each step's image estimate
    connects the new hit point to the camera; the camera's own share is the emission of
    the first surface each camera ray meets and the light it passes on through delta and
    null lobes, which no connection reaches: continued there by Mitsuba's ``volpath``
    (:mod:`mi_plugins.render.handoff`). The image is the average of the steps after the
    burn-in. Many chains run in lockstep, one Dr.Jit lane each, one fused kernel per step.

    .. pluginparameters::

    **``spp``:** ``mi.render(scene, spp=k)`` runs k x width x height chains of
    ``iterations`` steps each. **Burn-in** (:mod:`mi_plugins.render.burn_in`): the average
    misses the power defect of the paper's eq. 20, about lambda^b / (1 - lambda)^2 after b
    steps of burn-in, lambda the scene's effective albedo, measured from the chains; the
    burn-in is made long enough for a defect below 1e-3, and after the planned steps a
    drift check compares the halves of the averaged steps (while they differ, the steps so
    far become burn-in and twice as many are averaged). Where ``max_iterations`` leaves
    too little room, the render is refused (``NotConverged``). **Sensors:**
    ``perspective``, ``thinlens``, ``batch`` (light paths connect to them); others are
    refused, naming the sensor. **Refused:** participating media, wrapping integrators
    (``aov``, ``moment``), and a textured ``area`` light that Mitsuba samples wrongly in a
    scene whose light the camera sees through ``volpath``. Light splats go through the
    film's reconstruction filter, its part beyond the crop window compensated.

    .. code-block:: python

        {'type': 'stochastic_ray', 'iterations': 96, 'burn_in': 64}

    .. code-block:: xml

        <integrator type="stochastic_ray"><integer name="iterations" value="96"/>
            <integer name="burn_in" value="64"/></integrator>
    """

    iterative = True
    #: sensors whose importance light paths can reach (Mitsuba implements their sample_direction)
    SENSORS = ("perspective", "thinlens", "batch")

    def __init__(self, props=mi.Properties()):
        super().__init__(props)
        p = Params(props, self.plugin)
        self.read_iterations(p, 32)
        self.auto_burn_in = "burn_in" not in props    # fitted to the scene (burn_in.lengthen)
        self.measured_albedo = None
        self.max_iterations = p.int("max_iterations", max(4096, self.iterations), lo=self.iterations, hi=MAX_ITERATIONS,
                                    note="the most steps the burn-in check may extend a render to")
        self.max_depth = p.int("max_depth", -1, lo=-1, note="-1: unbounded")
        self.handoff = Handoff(self.max_depth)

    def iteration_count(self, spp):
        """Iterations (transport steps) of a render with ``spp``: spp scales the number of
        chains, not the number of steps."""
        return self.iterations

    def check_scene(self, scene, sensor):
        super().check_scene(scene, sensor)
        for cls in sorted(queries.nested_classes(sensor)):
            name = queries.PLUGIN_OF_CLASS.get(cls)
            if name is not None and name in queries.SENSOR_PLUGINS and name not in self.SENSORS:
                raise errors.Unsupported(
                    self.plugin, name, queries.describe(sensor, "sensor") if name == queries.plugin_name(sensor)
                    else "the sensor '%s' inside %s" % (name, queries.describe(sensor, "sensor")),
                    "light paths reach the camera by connecting to it, and Mitsuba gives no connection "
                    "(sample_direction) for this sensor: its directions form a delta distribution or it has no "
                    "aperture to connect to", "render it with 'path', or with 'ray_bundle' / 'qmc_lighttrace', "
                    "which trace camera rays")
        if any(int(bsdf.flags()) & int(mi.BSDFFlags.Delta) for _, bsdf in queries.bsdfs(scene)):
            checks.refuse_textured_lights_behind_handoff(
                self.plugin, scene, "the camera through mirrors, glass and null surfaces")

    # ------------------------------------------------------------------ light rays
    def _emitted_power(self, scene, seed):
        """A fixed positive scalar estimate of the total emitted power (only steers the
        restart probability; any positive value keeps the estimator unbiased)."""
        if not scene.emitters():
            return 1e-8
        rng = seeds.pcg(1 << 14, seed, "power")
        _, w = self._light_ray(scene, rng, mi.Bool(True))
        return max(float(dr.mean((dr.abs(w.x) + dr.abs(w.y) + dr.abs(w.z)) / 3.0, axis=None)[0]), 1e-8)

    @staticmethod
    def _light_ray(scene, rng, active):
        ray, power = sample_light_rays(scene, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()),
                                       mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        # emitted rays start exactly on the surface: step off it as spawn_ray does off a hit
        eps = SPAWN_EPSILON * (1.0 + dr.max(dr.abs(ray.o)))
        return mi.Ray3f(ray.o + ray.d * eps, ray.d), power

    # ------------------------------------------------------------------ render
    def render_frame(self, frame):
        scene, seed = frame.scene, frame.seed
        chains = frame.spp * frame.pixels
        limits.check_lanes(self.plugin, "spp=%d x %d pixels" % (frame.spp, frame.pixels), chains, BYTES_PER_CHAIN,
                           frame.pixels, "spp")
        self._camera_paths(frame)
        if not scene.emitters():      # no light to trace: the camera's share (black) is the image
            self.steps(0, 0)
            return
        # opaque: a new value (other seed, simulated emission) must not recompile the step kernel
        phi_e = dr.opaque(mi.Float, self._emitted_power(scene, seed))
        rng = seeds.pcg(chains, seed, "light")
        # loop state of the chains
        ray, power = self._light_ray(scene, rng, mi.Bool(True))   # the carried ray and the power it carries
        depth = dr.zeros(mi.UInt32, chains)                        # surface hits of the light path so far
        chain = [ray, power, depth]
        steps = self.steps(self.iterations, self.burn_in)
        # each averaged step's splats estimate the image once per chain and pixel
        # (not a closure over the frame, which keeps it: a reference cycle, mi_plugins.base.collection)
        pixels, progress = frame.pixels, self.progress
        scale = lambda: pixels / (chains * max(progress.averaged, 1))
        frame.light_block("light", scale)
        totals = []      # per averaged step: the light block's sum so far (for the drift check)
        ratios = []      # per step of the burn-in's second half: (power carried, power continued)

        def step(it):
            averaged = it >= steps.state.burn_in
            carried = _magnitude(chain[1])
            chain[0], chain[1], chain[2], continued = self._step(frame, *chain, rng, phi_e, averaged)
            window = self.auto_burn_in and steps.state.burn_in // 2 <= it < self.burn_in
            ratio = (dr.sum(carried), dr.sum(_magnitude(continued))) if window else None
            (ratios if window else []).append(ratio)
            return chain, rng.state, ratio

        def after(it):
            # the block's sum once the step is evaluated: read in the step's own kernel, the
            # block being splatted into would split it in two, the second tracing it again
            if it >= steps.state.burn_in:
                totals.append(frame.block_total("light"))
            if self.auto_burn_in and it + 1 == self.burn_in and ratios:
                self.measured_albedo = burn_in.lengthen(self.plugin, steps, ratios, self.max_iterations)
            if it + 1 == steps.count and burn_in.drift_check(self.plugin, steps, totals, self.max_iterations,
                                                             extend=self.auto_burn_in):
                frame.clear("light")
                totals.clear()

        self.run_steps(frame, steps, step, after)

    def _camera_paths(self, frame):
        """The camera's share of every step, M(L^e) plus what no connection reaches: the
        emission of the first surface each camera ray meets (or of the environment), and
        the light reaching that surface's delta and null lobes (mirrors, glass, null and
        mask surfaces), continued by Mitsuba's path (:class:`Handoff`). Its alpha channel
        is the camera rays' coverage."""
        scene = frame.scene
        frame.camera_passes(frame.spp, 1)
        cam = frame.camera_pass()
        si = first_shown(scene, cam.ray, self.hide_emitters)
        value = mi.Color3f(0.0)
        if self.max_depth != 0:
            if not self.hide_emitters:     # (hidden: area emitters are passed through, the sky unseen)
                value += mi.Color3f(si.emitter(scene).eval(si))
            value += self.handoff.sample(scene, cam.sampler, si, si.bsdf(cam.ray), 1, si.is_valid())
        frame.put_camera(cam, value, coverage=coverage(scene, si.is_valid(), self.hide_emitters))

    def _step(self, frame, ray, power, depth, rng, phi_e, do_splat):
        """One transport step on every lane: trace the carried ray, splat the hit point to
        the camera, then pick the next ray (restart from the lights or continue).

        The BSDF is evaluated as Mitsuba's path tracer evaluates it on the same path (at
        the hit, with the direction toward the camera side as wi and toward the light as
        wo), so that shading normals, bump and normal maps and non-reciprocal BSDFs give
        path's result; the geometric cosine of the light's side, already in the particle
        density, is divided out (Veach's adjoint correction, written for any BSDF)."""
        scene, sensor = frame.scene, frame.sensor
        max_depth = self.max_depth if self.max_depth >= 0 else (1 << 30)
        radiance = mi.BSDFContext(mi.TransportMode.Radiance)
        carries = dr.any(power != 0)   # (simulated emitters may give negative power samples)
        si = scene.ray_intersect(ray, carries)
        hit = si.is_valid() & carries
        depth_hit = depth + 1
        bsdf = si.bsdf(ray)
        to_light = si.wi                                    # local, toward where the particle came from
        cos_light = dr.abs(dr.dot(si.n, si.to_world(to_light)))
        # --- image estimate: connect the new hit point to the camera
        can_splat = hit & (depth_hit + 1 <= max_depth) & do_splat
        ds, sensor_w = sensor.sample_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), can_splat)
        visible = can_splat & (ds.pdf > 0)
        if self.hide_emitters:   # hidden area emitters: the camera sees through them, not them
            visible &= si.emitter(scene, visible) == None  # noqa: E711
        visible = unoccluded(scene, si, ds.p, self.hide_emitters, visible)
        value = self._path_weight(si, bsdf, radiance, si.to_local(ds.d), to_light, cos_light, visible)
        frame.put_light(ds.uv, value * power * mi.Color3f(sensor_w), "light", active=visible)
        # --- next ray: a BSDF sample, weighted as path weights the same path
        bs, w = bsdf.sample(mi.BSDFContext(mi.TransportMode.Importance), si, rng.next_float32(),
                            mi.Point2f(rng.next_float32(), rng.next_float32()), hit)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        # a sample Mitsuba weighs 0 is none: roughdielectric keeps its lobe's bs.pdf for directions that
        # crossed to the other lobe's side, where eval() is the other lobe's (docs/findings.md); bs.pdf
        # is the density of the samples of non-zero weight
        drawn = (bs.pdf > 0) & dr.any(mi.Color3f(w) != 0)
        smooth_w = self._path_weight(si, bsdf, radiance, bs.wo, to_light, cos_light, hit & ~delta & drawn)
        w = dr.select(delta, mi.Color3f(w) * shading_normal_correction(si, bs.wo),
                      smooth_w / dr.select(drawn, bs.pdf, 1.0))
        can_continue = hit & (depth_hit + 1 < max_depth) & drawn
        cont = dr.select(can_continue, power * w, 0.0)
        cont_s = _magnitude(cont)
        p_restart = phi_e / (phi_e + cont_s)
        restart = rng.next_float32() < p_restart
        light_ray, light_power = self._light_ray(scene, rng, restart)
        new_ray = dr.select(restart, light_ray, si.spawn_ray(si.to_world(bs.wo)))
        new_power = dr.select(restart, light_power / p_restart, cont / dr.maximum(1.0 - p_restart, 1e-12))
        return new_ray, new_power, dr.select(restart, 0, depth_hit), cont

    @staticmethod
    def _path_weight(si, bsdf, ctx, toward_camera, to_light, cos_light, active):
        """f(toward_camera, to_light) |cos_sh(to_light)| |cos_geo(toward_camera)| /
        |cos_geo(to_light)|: what the particle's power is multiplied by when it leaves
        the hit toward ``toward_camera`` (local), evaluated with the camera-side
        direction as wi, as a path tracer does."""
        at = mi.SurfaceInteraction3f(si)
        at.wi = toward_camera
        f = mi.Color3f(bsdf.eval(ctx, at, to_light, active))
        cos_camera = dr.abs(dr.dot(si.n, si.to_world(toward_camera)))
        return dr.select(active & (cos_light > 0), f * cos_camera / dr.select(cos_light > 0, cos_light, 1.0), 0.0)


def _magnitude(power):
    """The mean of |R|, |G|, |B| of powers (simulated emission can be negative)."""
    return (dr.abs(power.x) + dr.abs(power.y) + dr.abs(power.z)) / 3.0


def shading_normal_correction(si, wo_local):
    """|cos_sh(wi) cos_geo(wo) / (cos_sh(wo) cos_geo(wi))|: the adjoint BSDF correction
    for shading normals (Veach 1997, p. 158), for the delta lobes (which cannot be
    evaluated; their Importance-mode sample weight is the adjoint's)."""
    wi_geo = dr.dot(si.n, si.to_world(si.wi))
    wo_geo = dr.dot(si.n, si.to_world(wo_local))
    return dr.abs(mi.Frame3f.cos_theta(si.wi) * wo_geo
                  / dr.maximum(dr.abs(mi.Frame3f.cos_theta(wo_local) * wi_geo), 1e-12))
