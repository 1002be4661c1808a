"""Counting the rays each integrator of the stochastic-iteration benchmark traces.

Rays per second (a column of `stochastic_iteration.py`'s report) need the number of
rays a render traces; it comes from an untimed counting render per integrator and
scene (:func:`count_rays`):

- the Python integrators (`stochastic_ray`, `ray_bundle` and its variants) are
  instrumented: :class:`RayCounter` counts the active lanes of every
  `Scene.ray_intersect`, `ray_intersect_preliminary` and `ray_test` call, and the
  shadow rays of `sample_emitter_direction(..., test_visibility=True)`;
- Mitsuba's C++ `path` and `ptracer` cannot be instrumented from Python: they are
  counted with Python replicas of their loops (:func:`count_path_rays`,
  :func:`count_ptracer_rays`: same camera/light sampling, BSDF sampling, Russian
  roulette and shadow rays as Mitsuba 3.9).

Import after ``mi.set_variant('llvm_ad_rgb')``; the benchmark's driver does so. Run the
benchmark from the repository root:

    python3 benchmarks/stochastic_iteration.py --quick --scenes furnace
"""
import math
import warnings

import drjit as dr
import mitsuba as mi

def _count(mask, width):
    """Active lanes of a mask (None or a width-1 mask: all or none of ``width``)."""
    if mask is None:
        return width
    if dr.width(mask) == 1:
        return width if bool(mask[0]) else 0
    c = dr.count(mask)
    return int(c[0]) if dr.width(c) >= 1 and not isinstance(c, int) else int(c)


class RayCounter:
    """Counts the active lanes of every Python call to Scene.ray_intersect,
    ray_intersect_preliminary and ray_test, and the shadow rays of
    sample_emitter_direction(..., test_visibility=True) (loops run in evaluated mode
    meanwhile)."""

    METHODS = ("ray_intersect", "ray_intersect_preliminary", "ray_test", "sample_emitter_direction")

    def __init__(self):
        self.counts = {m: 0 for m in self.METHODS}

    @property
    def total(self):
        return sum(self.counts.values())

    def _wrap(self, name, original):
        counter = self

        def wrapper(scene, ray, *args, **kwargs):
            mask = None
            for value in list(args) + list(kwargs.values()):
                if isinstance(value, mi.Bool):
                    mask = value
            counter.counts[name] += _count(mask, dr.width(ray.o))
            return original(scene, ray, *args, **kwargs)

        def emitter_wrapper(scene, ref, sample, test_visibility=True, active=True):
            if test_visibility:   # one shadow ray per active lane
                counter.counts[name] += _count(active if isinstance(active, mi.Bool) else None, dr.width(ref.p))
            return original(scene, ref, sample, test_visibility, active)
        return emitter_wrapper if name == "sample_emitter_direction" else wrapper

    def __enter__(self):
        self.saved = {m: getattr(mi.Scene, m) for m in self.METHODS}
        for m in self.METHODS:
            setattr(mi.Scene, m, self._wrap(m, self.saved[m]))
        self.symbolic = dr.flag(dr.JitFlag.SymbolicLoops)
        dr.set_flag(dr.JitFlag.SymbolicLoops, False)
        return self

    def __exit__(self, *exc):
        for m, f in self.saved.items():
            setattr(mi.Scene, m, f)
        dr.set_flag(dr.JitFlag.SymbolicLoops, self.symbolic)


def _rng(n, seed):
    return mi.PCG32(n, initstate=mi.UInt64(seed * 7 + 3), initseq=mi.UInt64(dr.arange(mi.UInt32, n)))


def _camera_rays(scene, spp, rng):
    sensor = scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().crop_size())
    n = w * h * spp
    pixel = dr.arange(mi.UInt32, n) // spp
    pos = mi.Vector2f(mi.Float(pixel % w), mi.Float(pixel // w)) + mi.Vector2f(rng.next_float32(), rng.next_float32())
    ray, _ = sensor.sample_ray(0.0, 0.5, pos * dr.rcp(mi.ScalarVector2f(w, h)), mi.Point2f(0.5))
    return mi.Ray3f(ray)


def count_path_rays(scene, spp, rr_depth=5, max_iter=1000):
    """Replica of Mitsuba 3.9's `path` loop (max_depth -1): each iteration intersects the
    current ray (1 ray) and, at a smooth BSDF, samples an emitter (1 shadow ray where the
    emitter sample has a nonzero pdf); Russian roulette from depth rr_depth with
    q = min(max(throughput), 0.95)."""
    w, h = (int(v) for v in scene.sensors()[0].film().crop_size())
    n = w * h * spp
    rng = _rng(n, 1)
    ray = _camera_rays(scene, spp, rng)
    throughput, active, depth = mi.Color3f(1.0), dr.full(mi.Bool, True, n), mi.UInt32(0)
    ctx, rays = mi.BSDFContext(), 0
    for _ in range(max_iter):
        rays += _count(active, n)
        si = scene.ray_intersect(ray, active)
        active_next = active & si.is_valid()
        bsdf = si.bsdf(ray)
        active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds, _ = scene.sample_emitter_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), False, active_em)
        rays += _count(active_em & (ds.pdf != 0), n)
        bs, w = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), active_next)
        throughput = dr.select(active_next, throughput * mi.Color3f(w), throughput)
        ray = dr.select(active_next, si.spawn_ray(si.to_world(bs.wo)), ray)
        depth = dr.select(active_next, depth + 1, depth)
        t_max = dr.max(throughput)
        rr_prob = dr.minimum(t_max, 0.95)
        rr_active = depth >= rr_depth
        throughput = dr.select(rr_active, throughput / rr_prob, throughput)
        active = active_next & (~rr_active | (rng.next_float32() < rr_prob)) & (t_max != 0)
        dr.eval(ray, throughput, active, depth, rng.state)
        if _count(active, n) == 0:
            break
    return rays


def count_ptracer_rays(scene, spp, rr_depth=5, max_iter=1000):
    """Replica of Mitsuba 3.9's `ptracer` (max_depth -1), spp * W * H light paths: one
    shadow ray connecting the emitter sample to the camera, then per vertex one ray to the
    next vertex and one shadow ray to the camera where the camera sample is valid; Russian
    roulette after depth rr_depth with q = min(max(throughput), 0.95), the throughput
    starting at the emitter sample weight (power / pdf)."""
    sensor = scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().crop_size())
    n = w * h * spp
    rng = _rng(n, 2)
    rays = 0
    ray, weight, _ = scene.sample_emitter_ray(0.0, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()),
                                              mi.Point2f(rng.next_float32(), rng.next_float32()), True)
    it = dr.zeros(mi.Interaction3f, n)
    it.p = ray.o
    ds_e, _ = sensor.sample_direction(it, mi.Point2f(rng.next_float32(), rng.next_float32()), True)
    rays += _count(ds_e.pdf > 0, n)                       # sample_visible_emitters' connection
    throughput = mi.Color3f(weight)
    rays += n
    si = scene.ray_intersect(mi.Ray3f(ray), True)
    active = si.is_valid() & dr.any(throughput != 0)
    depth = mi.UInt32(1)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    for _ in range(max_iter):
        bsdf = si.bsdf(ray)
        ds, _ = sensor.sample_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        rays += _count(active & (ds.pdf > 0) & dr.any(throughput != 0), n)
        bs, bw = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        wo = si.to_world(bs.wo)
        wi_g, wo_g = dr.dot(si.n, -ray.d), dr.dot(si.n, wo)
        active &= (wi_g * mi.Frame3f.cos_theta(si.wi) > 0) & (wo_g * mi.Frame3f.cos_theta(bs.wo) > 0)
        corr = dr.abs(mi.Frame3f.cos_theta(si.wi) * wo_g / (mi.Frame3f.cos_theta(bs.wo) * wi_g))
        throughput = dr.select(active, throughput * mi.Color3f(bw) * corr, throughput)
        active &= dr.any(throughput != 0)
        ray = dr.select(active, si.spawn_ray(wo), ray)
        rays += _count(active, n)
        si = scene.ray_intersect(ray, active)
        depth = dr.select(active, depth + 1, depth)
        active &= si.is_valid()
        use_rr = depth > rr_depth
        q = dr.minimum(dr.max(throughput), 0.95)
        active &= ~use_rr | (rng.next_float32() < q)
        throughput = dr.select(use_rr, throughput / q, throughput)
        dr.eval(ray, si, throughput, active, depth, rng.state)
        if _count(active, n) == 0:
            break
    return rays


def count_rays(case, method, budgets):
    """{budget: rays traced by a render at that budget} plus a note on how it was counted."""
    b0 = method.ladder[0]
    cfg, spp = method.config(b0)
    scene = case.scene(cfg)
    if method.name == "path":
        per = count_path_rays(scene, 1)
        return {b: per * b for b in budgets}, "replica of path's loop, 1 spp, x spp"
    if method.name == "ptracer":
        per = count_ptracer_rays(scene, 1)
        return {b: per * b for b in budgets}, "replica of ptracer's loop, 1 spp, x spp"
    integ = scene.integrator()
    if method.name == "stochastic_ray":
        with RayCounter() as rc, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mi.render(scene, spp=spp, seed=5)
        return ({b: rc.total * b // spp for b in budgets},
                "instrumented, 1 spp x %d steps, x spp; %.2f rays per chain step"
                % (integ.iterations, rc.total / (dr.prod(scene.sensors()[0].film().crop_size()) * integ.iterations)))
    # ray_bundle: rays per burn-in iteration and per averaged iteration, from the progress hook
    # (its steps not frozen: a replayed step would not call the counting hooks)
    from mi_plugins.integrators.ray_bundle import frozen
    marks, was = [], frozen.ENABLED
    integ.progress_callback = lambda done, total: marks.append(rc.total)
    integ.iterations, total = integ.burn_in + 4, integ.burn_in + 4
    frozen.ENABLED = False
    try:
        with RayCounter() as rc, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mi.render(scene, spp=1, seed=5)
            prelim = rc.counts["ray_intersect_preliminary"]
    finally:
        integ.progress_callback = None
        frozen.ENABLED = was
    marks = [0] + marks
    burn = (marks[integ.burn_in] - marks[0]) / max(integ.burn_in, 1)
    # (with average_diffuse the final gathering's passes, one per averaged iteration, come last)
    averaged = (marks[-1] - marks[integ.burn_in]) / (total - integ.burn_in)
    res = integ.resolution
    lines = math.pi / 4 * res * res * integ.chains   # lines inside the bounding disks (expected number)
    counts = {b: int(round(method.config(b)[0]["burn_in"] * burn + (b - integ.burn_in) * averaged)) for b in budgets}
    return counts, ("instrumented, %d bundle rays per iteration (%.1f hits per line), %d per averaged iteration"
                    % (burn, prelim / (total * lines) - 1.0, averaged))
