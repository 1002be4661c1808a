"""Stochastic iteration with the single-ray random transport operator
(Szirmay-Kalos, "Stochastic Iteration for Non-diffuse Global Illumination", section 4)."""
import drjit as dr
import mitsuba as mi

from mi_plugins.integrators.stochastic_common import (Progress, check_variant, resolve_sensor, sensor_spp,
                                                      image_to_film, camera_paths, SPLAT_MODE)
from mi_plugins.params import Params


class StochasticRayIntegrator(mi.SamplingIntegrator):
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
    ``ptracer``); emission seen through specular chains is included. The splat goes to
    the pixel containing the projected point (box reconstruction).
    """

    def __init__(self, props=mi.Properties()):
        p = Params(props, "stochastic_ray")
        hide_emitters = p.bool("hide_emitters", False)   # before the base class reads it with its own check
        super().__init__(props)
        check_variant("stochastic_ray")
        self.iterations = p.int("iterations", 32, lo=1)
        self.burn_in = p.int("burn_in", min(8, self.iterations - 1), lo=0)
        if self.burn_in > self.iterations - 1:
            raise p.conflict(("burn_in", "iterations"), "burn_in in 0 .. iterations - 1 = %d" % (self.iterations - 1))
        self.max_depth = p.int("max_depth", -1, lo=-1, note="-1: unbounded")
        self.hide_emitters = hide_emitters
        self.progress_callback = None
        self.iterations_done, self.interrupted, self.averaged_fraction = 0, False, 0.0

    def iteration_count(self, spp):
        """Iterations (transport steps) of a render with ``spp``: spp scales the number of
        chains, not the number of steps."""
        return self.iterations

    # ------------------------------------------------------------------ helpers
    def _emitted_power(self, scene, seed):
        """A fixed positive scalar estimate of the total emitted power (only steers the
        restart probability; any positive value keeps the estimator unbiased)."""
        if not scene.emitters():
            return 1e-8
        rng = mi.PCG32(1 << 14, initstate=dr.opaque(mi.UInt64, seed * 2654435761 + 12345))
        _, w = self._sample_light_ray(scene, rng, mi.Bool(True))
        return max(float(dr.mean((dr.abs(w.x) + dr.abs(w.y) + dr.abs(w.z)) / 3.0, axis=None)[0]), 1e-8)

    def _sample_light_ray(self, scene, rng, active):
        ray, weight, _ = scene.sample_emitter_ray(0.0, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()),
                                                  mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        # emitted rays start exactly on the surface: step off it to avoid a self-intersection
        ray = mi.Ray3f(ray.o + ray.d * self._ray_eps, ray.d)
        return ray, dr.select(active, mi.Color3f(weight), 0.0)

    def _direct_emission(self, scene, sensor, spp, seed):
        """Emission seen from the camera, followed through delta (specular) surfaces:
        the M(L^e) term of every step (plus its specular reflections)."""
        paths = camera_paths(scene, sensor, spp, seed, self.max_depth, self.hide_emitters)
        return paths.emission_image

    # ------------------------------------------------------------------ render
    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        sensor = resolve_sensor(scene, sensor)
        film = sensor.film()
        size = film.crop_size()
        spp = sensor_spp(sensor, spp)
        width, height = int(size[0]), int(size[1])
        n_pix = width * height
        n_chains = spp * n_pix
        seed = int(seed)

        image = self._direct_emission(scene, sensor, spp, seed) if self.max_depth != 0 else dr.zeros(mi.Float, n_pix * 3)
        dr.eval(image)
        splat = dr.zeros(mi.Float, n_pix * 3)

        self._ray_eps = 1e-4 * max(float(dr.norm(scene.bbox().extents())), 1e-3)
        # opaque: a new value (other seed, simulated emission) must not recompile the step kernel
        phi_e = dr.opaque(mi.Float, self._emitted_power(scene, seed))
        lane = dr.arange(mi.UInt32, n_chains)
        rng = mi.PCG32(n_chains, initstate=dr.opaque(mi.UInt64, seed * 1000003 + 1), initseq=mi.UInt64(lane))
        ray, power = self._sample_light_ray(scene, rng, mi.Bool(True))
        depth = dr.zeros(mi.UInt32, n_chains)      # surface hits of the current light path so far
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        max_depth = self.max_depth if self.max_depth >= 0 else (1 << 30)

        progress = Progress(self, self.iterations, self.burn_in)
        try:
            for it in progress:
                step_splat = dr.zeros(mi.Float, n_pix * 3)
                ray, power, depth = self._step(scene, sensor, ray, power, depth, rng, step_splat, ctx, phi_e,
                                               max_depth, it >= self.burn_in, width, height)
                new_splat = splat + step_splat
                dr.eval(ray, power, depth, rng.state, new_splat)
                splat = new_splat
        except KeyboardInterrupt:
            progress.stop()  # Ctrl-C: keep the finished iterations
        steps_averaged = progress.averaged
        if steps_averaged > 0:
            image = image + splat * (float(n_pix) / (float(n_chains) * steps_averaged))
        tensor = mi.TensorXf(image, shape=(height, width, 3))
        return image_to_film(film, tensor, develop)

    def _step(self, scene, sensor, ray, power, depth, rng, splat, ctx, phi_e, max_depth, do_splat, width, height):
        """One transport step on every lane: trace the carried ray, splat the hit point to
        the camera, then pick the next ray (restart from the lights or continue)."""
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
        self._splat(scene, si, ds, sensor_w, to_camera, mi.Color3f(f_camera), power, splat,
                    can_splat & (ds.pdf > 0), width, height)
        # --- next ray: continue from the hit (BSDF sampled) or restart from the lights
        w = mi.Color3f(w) * shading_normal_correction(si, bs.wo)
        wo_world = si.to_world(bs.wo)
        can_continue = hit & geometric_side_consistent(si, bs.wo) & (depth_hit + 1 < max_depth) & (bs.pdf > 0)
        cont = dr.select(can_continue, power * w, 0.0)
        cont_s = (dr.abs(cont.x) + dr.abs(cont.y) + dr.abs(cont.z)) / 3.0
        p_restart = phi_e / (phi_e + cont_s)
        restart = rng.next_float32() < p_restart
        light_ray, light_power = self._sample_light_ray(scene, rng, restart)
        new_ray = dr.select(restart, light_ray, si.spawn_ray(wo_world))
        new_power = dr.select(restart, light_power / p_restart, cont / dr.maximum(1.0 - p_restart, 1e-12))
        new_depth = dr.select(restart, 0, depth_hit)
        return new_ray, new_power, new_depth

    def _splat(self, scene, si, ds, sensor_w, to_camera, f_camera, power, splat, active, width, height):
        """Add the hit point's contribution, seen through the camera sample ``ds``, to its
        pixel (light tracing with direct pixel contribution)."""
        active &= ~scene.ray_test(si.spawn_ray_to(ds.p), active)
        active &= geometric_side_consistent(si, to_camera)
        value = f_camera * power * mi.Color3f(sensor_w) * shading_normal_correction(si, to_camera)
        px = mi.Int32(dr.floor(ds.uv.x))
        py = mi.Int32(dr.floor(ds.uv.y))
        active &= (px >= 0) & (py >= 0) & (px < width) & (py < height)
        index = mi.UInt32(py * width + px)
        for c in range(3):
            dr.scatter_add(splat, value[c], index * 3 + c, active, mode=SPLAT_MODE)


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
