"""Helpers shared by the stochastic-iteration integrators (``stochastic_ray``,
``ray_bundle``): parameter parsing with clear errors, sensor/spp resolution, and the
progress hook.

Progress hook: an integrator instance has an attribute ``progress_callback`` (default
None). When set, ``progress_callback(done, total)`` is called after every finished
iteration; returning ``False`` stops the render early. A KeyboardInterrupt (Ctrl-C)
during an iteration also stops early. In both cases the image is made of the finished
iterations, and ``integrator.iterations_done`` tells how many there were.
"""
import drjit as dr
import mitsuba as mi


def check_variant(who):
    variant = mi.variant() or ""
    if variant.startswith("scalar") or "rgb" not in variant or "polarized" in variant:
        raise RuntimeError("%s: variant '%s' is not supported: this integrator is vectorised with Dr.Jit; "
                           "use a JIT RGB (non-polarized) variant such as 'llvm_ad_rgb' or 'cuda_ad_rgb'" % (who, variant))


def int_param(props, name, default, lo, hi, who):
    value = props.get(name, default)
    if isinstance(value, bool) or int(value) != value:
        raise ValueError("%s: %s=%r must be an integer" % (who, name, value))
    value = int(value)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        rng = "%s .. %s" % (lo if lo is not None else "-inf", hi if hi is not None else "inf")
        raise ValueError("%s: %s=%d is out of range; valid range: %s" % (who, name, value, rng))
    if name == "max_depth" and value < -1:
        raise ValueError("%s: max_depth=%d; valid values: -1 (unbounded) or >= 0" % (who, value))
    return value


def bool_param(props, name, default):
    return bool(props.get(name, default))


def choice_param(props, name, default, choices, who):
    value = str(props.get(name, default))
    if value not in choices:
        raise ValueError("%s: %s='%s' is not valid; choose one of: %s" % (who, name, value, ", ".join(choices)))
    return value


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
    each item; stops early when the callback returns False or on KeyboardInterrupt.
    ``done`` counts the finished iterations."""

    def __init__(self, owner, total):
        self.owner, self.total, self.done = owner, int(total), 0
        self.interrupted = False

    def __iter__(self):
        for it in range(self.total):
            yield it
            self.done = it + 1
            callback = getattr(self.owner, "progress_callback", None)
            if callback is not None:
                try:
                    if callback(self.done, self.total) is False:
                        self.interrupted = True
                        return
                except KeyboardInterrupt:
                    self.interrupted = True
                    return


class CameraPaths:
    """Camera samples (``spp`` per pixel) followed through delta surfaces.

    ``pixel``: pixel index of each sample; ``emission_image``: flat (H*W*3) Float, the
    emission seen along each sample's delta chain averaged per pixel; ``ray``/``throughput``/
    ``valid``: the ray reaching the first non-delta surface, its throughput, and whether
    such a surface was reached within ``max_depth``; ``depth``: its path depth."""


def camera_paths(scene, sensor, spp, seed, max_depth=-1, hide_emitters=False):
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
        bs, w = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), show)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        # a non-delta surface ends the camera path (kept for gathering)
        reached |= show & ~delta & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        new_active = show & delta & (depth + 1 < depth_limit)
        throughput = dr.select(new_active, throughput * mi.Color3f(w), throughput)
        new_active &= dr.any(throughput > 0)
        ray = dr.select(new_active, si.spawn_ray(si.to_world(bs.wo)), ray)
        depth = dr.select(new_active, depth + 1, depth)
        return ray, throughput, result, new_active, reached, depth, rng

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
