"""Stochastic iteration with the single-ray random transport operator
(Szirmay-Kalos, "Stochastic Iteration for Non-diffuse Global Illumination", section 4)."""
import drjit as dr
import mitsuba as mi

from mi_plugins import seeds
from mi_plugins.integrators.camera import specular_chain
from mi_plugins.integrators.core import CoreIntegrator
from mi_plugins.params import Params


class StochasticRayIntegrator(CoreIntegrator):
    r"""
    .. _integrator-stochastic_ray:

    ``stochastic_ray`` (stochastic iteration, single-ray operator)
    --------------------------------------------------------------

    Szirmay-Kalos, section 4: the iteration L_n = Le + T*_n L_{n-1}, where each random
    operator sends the whole power of L_{n-1} along ONE ray: restart from the lights with
    probability Phi_e / Phi_n (Phi_e: emitted power, Phi_n: power carried), otherwise
    continue from the last hit in a BSDF-sampled direction (the BSDF sample weight stands
    in for the albedo, so any Mitsuba BSDF and the ``simulated_area`` / ``directional_area``
    emitters work, negative simulated emission included). Each step's image estimate
    connects the new hit point to the camera (light tracing with direct pixel
    contribution) plus the emission seen directly (camera rays drawn from the sensor's
    sampler and followed through mirrors and glass); the image is the average of the
    steps after ``burn_in``. Many chains run in lockstep, one Dr.Jit lane each, one fused
    kernel per step: no lane idles on short paths.

    .. pluginparameters::

     * - iterations
       - int
       - 32
       - >= 1 transport steps per chain
     * - burn_in
       - int
       - min(8, iterations - 1)
       - 0 .. iterations - 1 first steps left out of the average
     * - max_depth
       - int
       - -1
       - -1 (unbounded) or >= 0, Mitsuba's convention (1 = emission only); chains
         restart when they reach it, so truncated analytic values can be checked
     * - hide_emitters
       - bool
       - false
       - do not show directly visible emitters

    **``spp`` mapping:** ``mi.render(scene, spp=k)`` runs k x width x height chains of
    ``iterations`` steps each: work is linear in k (and in ``iterations``).
    **Burn-in:** the average misses the power defect of the paper's eq. 20, which decays
    like lambda^burn_in / (1 - lambda)^2 for the scene's largest albedo lambda: the
    default is ample up to lambda ~ 0.5; the constant-radiance scenes (albedos ~ 0.9)
    need about 64 (measured: ``constant_lightsource_sierpinski`` z = -8.3 with 32/8, +1.9
    with 96/64; the verify matrix sets ``iterations=96, burn_in=64`` there). Not covered:
    light paths that reach the camera through a specular surface after a diffuse one (as
    in ``ptracer``). Light splats go through the film's reconstruction filter, with the
    part of a wide filter beyond the crop window compensated (Mitsuba's ``ptracer``
    darkens the border pixels there, by ~10 % with the default Gaussian filter).

    .. code-block:: python

        {'type': 'stochastic_ray', 'iterations': 96, 'burn_in': 64}

    .. code-block:: xml

        <integrator type="stochastic_ray"><integer name="iterations" value="96"/>
            <integer name="burn_in" value="64"/></integrator>
    """

    plugin = "stochastic_ray"
    iterative = True

    def __init__(self, props=mi.Properties()):
        super().__init__(props)
        p = Params(props, "stochastic_ray")
        self.read_iterations(p, 32)
        self.max_depth = p.int("max_depth", -1, lo=-1, note="-1: unbounded")

    def iteration_count(self, spp):
        """Iterations (transport steps) of a render with ``spp``: spp scales the number of
        chains, not the number of steps."""
        return self.iterations

    # ------------------------------------------------------------------ light rays
    def _emitted_power(self, scene, seed, eps):
        """A fixed positive scalar estimate of the total emitted power (only steers the
        restart probability; any positive value keeps the estimator unbiased)."""
        if not scene.emitters():
            return 1e-8
        rng = seeds.pcg(1 << 14, seed, "power")
        _, w = self._light_ray(scene, rng, mi.Bool(True), eps)
        return max(float(dr.mean((dr.abs(w.x) + dr.abs(w.y) + dr.abs(w.z)) / 3.0, axis=None)[0]), 1e-8)

    def _light_ray(self, scene, rng, active, eps):
        ray, weight, _ = scene.sample_emitter_ray(0.0, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()),
                                                  mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        # emitted rays start exactly on the surface: step off it to avoid a self-intersection
        return mi.Ray3f(ray.o + ray.d * eps, ray.d), dr.select(active, mi.Color3f(weight), 0.0)

    # ------------------------------------------------------------------ render
    def render_frame(self, frame):
        scene, seed = frame.scene, frame.seed
        chains = frame.spp * frame.pixels
        if self.max_depth != 0:
            # the emission seen from the camera (through specular chains): M(L^e) of every step
            frame.camera_passes(frame.spp, 1)
            cam = frame.camera_pass()
            path = specular_chain(scene, cam.ray, seeds.pcg(cam.count, seed, "camera_path"), self.max_depth,
                                  hide_emitters=self.hide_emitters)
            frame.put_camera(cam, path.emission)
        eps = 1e-4 * max(float(dr.norm(scene.bbox().extents())), 1e-3)
        # opaque: a new value (other seed, simulated emission) must not recompile the step kernel
        phi_e = dr.opaque(mi.Float, self._emitted_power(scene, seed, eps))
        rng = seeds.pcg(chains, seed, "light")
        ray, power = self._light_ray(scene, rng, mi.Bool(True), eps)
        depth = dr.zeros(mi.UInt32, chains)        # surface hits of the current light path so far
        steps = self.steps(self.iterations, self.burn_in)
        # each averaged step's splats estimate the image once per chain and pixel
        scale = lambda: frame.pixels / (chains * max(self.progress.averaged, 1))
        frame.light_block("light", scale)
        try:
            for it in steps.iterations():
                ray, power, depth = self._step(frame, ray, power, depth, rng, phi_e, it >= self.burn_in, eps)
                dr.eval(ray, power, depth, rng.state, frame.state())
                frame.commit()
        except KeyboardInterrupt:
            steps.stop()  # Ctrl-C: keep the finished iterations
            frame.rollback()

    def _step(self, frame, ray, power, depth, rng, phi_e, do_splat, eps):
        """One transport step on every lane: trace the carried ray, splat the hit point to
        the camera, then pick the next ray (restart from the lights or continue)."""
        scene, sensor = frame.scene, frame.sensor
        max_depth = self.max_depth if self.max_depth >= 0 else (1 << 30)
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        carries = dr.any(power != 0)   # (simulated emitters may give negative power samples)
        si = scene.ray_intersect(ray, carries)
        hit = si.is_valid() & carries
        depth_hit = depth + 1
        # --- one BSDF call evaluates toward the camera (image estimate) and samples the
        #     continuation direction
        can_splat = hit & (depth_hit + 1 <= max_depth) & do_splat
        ds, sensor_w = sensor.sample_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), can_splat)
        to_camera = si.to_local(ds.d)
        bsdf = si.bsdf(ray)
        f_camera, _, bs, w = bsdf.eval_pdf_sample(ctx, si, to_camera, rng.next_float32(),
                                                  mi.Point2f(rng.next_float32(), rng.next_float32()), hit)
        # --- image estimate: connect the new hit point to the camera
        visible = can_splat & (ds.pdf > 0) & geometric_side_consistent(si, to_camera)
        visible &= ~scene.ray_test(si.spawn_ray_to(ds.p), visible)
        value = mi.Color3f(f_camera) * power * mi.Color3f(sensor_w) * shading_normal_correction(si, to_camera)
        frame.put_light(ds.uv, value, "light", active=visible)
        # --- next ray: continue from the hit (BSDF sampled) or restart from the lights
        w = mi.Color3f(w) * shading_normal_correction(si, bs.wo)
        can_continue = hit & geometric_side_consistent(si, bs.wo) & (depth_hit + 1 < max_depth) & (bs.pdf > 0)
        cont = dr.select(can_continue, power * w, 0.0)
        cont_s = (dr.abs(cont.x) + dr.abs(cont.y) + dr.abs(cont.z)) / 3.0
        p_restart = phi_e / (phi_e + cont_s)
        restart = rng.next_float32() < p_restart
        light_ray, light_power = self._light_ray(scene, rng, restart, eps)
        new_ray = dr.select(restart, light_ray, si.spawn_ray(si.to_world(bs.wo)))
        new_power = dr.select(restart, light_power / p_restart, cont / dr.maximum(1.0 - p_restart, 1e-12))
        return new_ray, new_power, dr.select(restart, 0, depth_hit)


def geometric_side_consistent(si, wo_local):
    """Both si.wi and ``wo_local`` lie on the same side of the geometric and the shading
    normal (otherwise adjoint transport through shading normals leaks light)."""
    wi_geo = dr.dot(si.n, si.to_world(si.wi))
    wo_geo = dr.dot(si.n, si.to_world(wo_local))
    return (wi_geo * mi.Frame3f.cos_theta(si.wi) > 0) & (wo_geo * mi.Frame3f.cos_theta(wo_local) > 0)


def shading_normal_correction(si, wo_local):
    """|cos_sh(wi) cos_geo(wo) / (cos_sh(wo) cos_geo(wi))|: the adjoint BSDF correction
    for shading normals (Veach 1997, p. 158)."""
    wi_geo = dr.dot(si.n, si.to_world(si.wi))
    wo_geo = dr.dot(si.n, si.to_world(wo_local))
    return dr.abs(mi.Frame3f.cos_theta(si.wi) * wo_geo
                  / dr.maximum(dr.abs(mi.Frame3f.cos_theta(wo_local) * wi_geo), 1e-12))
