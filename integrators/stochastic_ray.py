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

    Stochastic iteration, single-ray transport operator (``stochastic_ray``)
    ------------------------------------------------------------------------

    The iteration :math:`L_n = L^e + T^*_n L_{n-1}` where each random operator sends the
    whole power :math:`\Phi_n` of :math:`L_{n-1}` along one ray: the ray restarts from the
    light sources with probability :math:`\Phi_e/\Phi_n` or continues from the last hit
    point with the complementary probability, its direction sampled by the BSDF (the BSDF
    sample weight stands in for the albedo, so the operator stays unbiased for any BSDF).
    Every step's image estimate connects the newly hit point to the camera (light tracing
    with direct pixel contribution) and adds the emission seen directly (followed through
    delta surfaces); the image is the average over the steps after ``burn_in``.

    Many independent chains run in lockstep, one Dr.Jit lane per chain, every lane doing
    one transport step per iteration (one fused kernel per iteration).
    ``mi.render(scene, spp=k)`` runs ``k * width * height`` chains of ``iterations`` steps
    each (work is linear in ``k``).

    .. list-table::
       * - Parameter, type, default, range: meaning
       * - ``iterations``, int, 32, >= 1: transport steps per chain
       * - ``burn_in``, int, min(8, iterations - 1), 0 .. iterations-1: first steps left out
           of the average (the power defect of the paper's eq. 20 decays like
           lambda^burn_in for the largest albedo lambda: use ~64 when lambda is near 0.9)
       * - ``max_depth``, int, -1, -1 or >= 0: longest path (in Mitsuba's convention,
           1 = emission only); chains restart when they reach it; -1 = unbounded
       * - ``hide_emitters``, bool, false: do not show directly visible emitters

    Progress: set ``integrator.progress_callback = f``; ``f(done, total)`` is called after
    every iteration and may return ``False`` to stop early; Ctrl-C (KeyboardInterrupt)
    also stops early. Either way the finished iterations make the image.

    Caveats: light paths are connected to the camera at non-delta surfaces only, so
    paths of the form light ... diffuse -> specular -> camera are missing (as in Mitsuba's
    ``ptracer``); emission seen through specular chains is included. Camera samples come
    from the sensor's sampler; splats go through the film's reconstruction filter.
    """

    plugin = "stochastic_ray"
    iterative = True

    def __init__(self, props=mi.Properties()):
        p = Params(props, "stochastic_ray")
        hide_emitters = p.bool("hide_emitters", False)   # before the base class reads it with its own check
        super().__init__(props)
        self.iterations = p.int("iterations", 32, lo=1)
        self.burn_in = p.int("burn_in", min(8, self.iterations - 1), lo=0)
        if self.burn_in > self.iterations - 1:
            raise p.conflict(("burn_in", "iterations"), "burn_in in 0 .. iterations - 1 = %d" % (self.iterations - 1))
        self.max_depth = p.int("max_depth", -1, lo=-1, note="-1: unbounded")
        self.hide_emitters = hide_emitters

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
