"""Helpers shared by the stochastic-iteration integrators (``stochastic_ray``,
``ray_bundle``): variant check, sensor/spp resolution, the progress hook, and camera
paths followed through delta surfaces (parameters: :mod:`mi_plugins.params`).

Progress hook: an integrator instance has an attribute ``progress_callback`` (default
None). When set, ``progress_callback(done, total)`` is called after every finished
iteration; returning ``False`` (or raising KeyboardInterrupt) stops the render early,
and so does Ctrl-C during an iteration. The image is then made of the finished
iterations; after every render ``integrator.iterations_done`` (finished iterations),
``integrator.interrupted`` and ``integrator.averaged_fraction`` (averaged iterations
finished / planned) tell what the image holds. ``integrator.iteration_count(spp)`` is
the number of iterations a render with ``spp`` runs (what a progress bar counts).
"""
import drjit as dr
import mitsuba as mi


#: scatter-adds into small arrays (image, per-triangle sums) from many lanes: on the LLVM
#: backend, per-core copies of the target instead of contended atomics
SPLAT_MODE = dr.ReduceMode.Expand


def check_variant(who):
    variant = mi.variant() or ""
    if variant.startswith("scalar") or "rgb" not in variant or "polarized" in variant:
        raise RuntimeError("%s: variant '%s' is not supported: this integrator is vectorised with Dr.Jit; "
                           "use a JIT RGB (non-polarized) variant such as 'llvm_ad_rgb' or 'cuda_ad_rgb'" % (who, variant))


def resolve_sensor(scene, sensor):
    if isinstance(sensor, int):
        sensors = scene.sensors()
        if not 0 <= sensor < len(sensors):
            raise ValueError("sensor=%d: the scene has %d sensor(s)" % (sensor, len(sensors)))
        return sensors[sensor]
    return sensor


def sensor_spp(sensor, spp):
    spp = int(spp) if spp else int(sensor.sampler().sample_count())
    if spp < 1:
        raise ValueError("spp=%d: must be >= 1" % spp)
    return spp


def image_to_film(film, tensor, develop):
    """Return the developed image (H, W, 3) like mi.render does."""
    if not develop:
        raise ValueError("develop=False is not supported by the stochastic-iteration integrators; "
                         "they return the developed image")
    return tensor


class Progress:
    """Iterate over ``range(total)`` calling ``owner.progress_callback(done, total)`` after
    each item; stops early when the callback returns False or raises KeyboardInterrupt.
    ``done`` counts the finished iterations, ``averaged`` those after ``burn_in``.

    A KeyboardInterrupt raised inside the loop body (Ctrl-C during an iteration) must be
    caught by the caller, which then calls :meth:`stop`.
    """

    def __init__(self, owner, total, burn_in, steps=None):
        self.owner, self.total, self.burn_in = owner, int(total), int(burn_in)
        self.steps = self.total if steps is None else int(steps)   # what the callback reports as total
        self.done, self.interrupted, self.extra_done = 0, False, 0
        owner.iterations_done, owner.interrupted, owner.averaged_fraction = 0, False, 0.0

    @property
    def averaged(self):
        return max(0, self.done - self.burn_in)

    def __iter__(self):
        for it in range(self.total):
            yield it
            self.done = it + 1
            if not self._report():
                return

    def second_stage(self, count):
        """Iterate over ``range(count)`` steps of a second stage that runs after the
        iterations (``ray_bundle``'s final gathering), reporting them to the callback
        after the iterations (out of ``steps``). The first step always runs; a stop
        request ends the stage after the current step. ``extra_done`` counts them."""
        for k in range(count):
            yield k
            self.extra_done = k + 1
            if not self._report():
                return

    def _report(self):
        """Publish, call the callback; False when it asks to stop (or raises
        KeyboardInterrupt)."""
        self._publish()
        callback = getattr(self.owner, "progress_callback", None)
        if callback is not None:
            try:
                if callback(self.done + self.extra_done, self.steps) is False:
                    self.stop()
                    return False
            except KeyboardInterrupt:
                self.stop()
                return False
        return True

    def stop(self):
        self.interrupted = True
        self._publish()

    def _publish(self):
        self.owner.iterations_done = self.done + self.extra_done
        self.owner.interrupted = self.interrupted
        self.owner.averaged_fraction = self.averaged / max(1, self.total - self.burn_in)


class CameraPaths:
    """Camera samples (``spp`` per pixel) followed through purely specular surfaces.

    ``pixel``: pixel index of each sample; ``emission_image``: flat (H*W*3) Float, the
    emission seen along each sample's specular chain, averaged per pixel; ``ray``,
    ``throughput``, ``valid``: the ray reaching the first surface with a non-delta BSDF
    component, its throughput, and whether such a surface was reached; ``depth``: the
    number of specular bounces before it."""


#: camera paths through specular chains play Russian roulette after this many bounces
#: (survival probability min(max throughput, 0.95), so perfect mirrors terminate too)
CAMERA_RR_DEPTH = 5


def camera_paths(scene, sensor, spp, seed, max_depth=-1, hide_emitters=False):
    """Trace ``spp`` camera rays per pixel and follow them through surfaces whose BSDF is
    purely delta (mirror, glass): such surfaces are sampled, and the path stops at the
    first surface with any non-delta component, where the integrators evaluate their own
    estimate. (The delta lobes of mixed BSDFs such as ``plastic`` are not followed.)
    ``max_depth`` uses Mitsuba's convention (1: emission seen directly only)."""
    film = sensor.film()
    size = film.crop_size()
    n_pix = int(size[0]) * int(size[1])
    n = n_pix * spp
    idx = dr.arange(mi.UInt32, n)
    pixel = idx // spp
    rng = mi.PCG32(n, initstate=dr.opaque(mi.UInt64, seed * 7919 + 17), initseq=mi.UInt64(idx))
    pos = mi.Vector2f(mi.Float(pixel % size[0]), mi.Float(pixel // size[0]))
    pos += mi.Vector2f(rng.next_float32(), rng.next_float32())
    scale = dr.rcp(mi.ScalarVector2f(size))
    ray, ray_w = sensor.sample_ray(0.0, 0.5, pos * scale, mi.Point2f(0.5), True)
    ctx = mi.BSDFContext()
    depth_limit = mi.UInt32(max_depth if max_depth >= 0 else (1 << 30))

    def body(ray, throughput, result, active, reached, depth, rng):
        si = scene.ray_intersect(ray, active)
        emitter = si.emitter(scene, active)
        show = active & (depth < depth_limit) & si.is_valid()
        visible = show & (depth > 0) if hide_emitters else show
        result += dr.select(visible, throughput * mi.Color3f(emitter.eval(si, visible)), 0.0)
        bsdf = si.bsdf(ray)
        flags = bsdf.flags()
        specular = mi.has_flag(flags, mi.BSDFFlags.Delta) & ~mi.has_flag(flags, mi.BSDFFlags.Smooth)
        reached |= show & ~specular & mi.has_flag(flags, mi.BSDFFlags.Smooth)
        follow = show & specular & (depth + 1 < depth_limit)
        bs, w = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), follow)
        throughput = dr.select(follow, throughput * mi.Color3f(w), throughput)
        survive = dr.minimum(dr.max(throughput), 0.95)
        roulette = follow & (depth + 1 >= CAMERA_RR_DEPTH)
        follow &= ~roulette | (rng.next_float32() < survive)
        throughput = dr.select(roulette & follow, throughput / survive, throughput)
        follow &= dr.max(throughput) > 0
        ray = dr.select(follow, si.spawn_ray(si.to_world(bs.wo)), ray)
        depth = dr.select(follow, depth + 1, depth)
        return ray, throughput, result, follow, reached, depth, rng

    state = dr.while_loop((ray, mi.Color3f(ray_w), mi.Color3f(0.0), mi.Bool(True), mi.Bool(False),
                           mi.UInt32(0), rng),
                          lambda ray, throughput, result, active, reached, depth, rng: active, body)
    ray, throughput, result, _, reached, depth, _ = state
    image = dr.zeros(mi.Float, n_pix * 3)
    for c in range(3):
        dr.scatter_add(image, result[c] / spp, pixel * 3 + c)
    paths = CameraPaths()
    paths.pixel, paths.emission_image, paths.ray, paths.throughput = pixel, image, ray, throughput
    paths.valid, paths.depth, paths.count, paths.spp = reached, depth, n, spp
    return paths
