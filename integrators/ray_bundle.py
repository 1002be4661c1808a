"""Stochastic iteration with global ray bundles (Szirmay-Kalos, "Stochastic Iteration for
Non-diffuse Global Illumination", sections 5 and 6)."""
import math
import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import qmc
from mi_plugins.meshtable import MeshTable
from mi_plugins.sampling import direct_light, stratified_direction_sets
from mi_plugins.integrators.stochastic_common import (Progress, check_variant, int_param, bool_param, choice_param,
                                                      resolve_sensor, sensor_spp, image_to_film, camera_paths, SPLAT_MODE)

DIRECTION_SEQUENCES = ("independent", "halton", "hammersley", "pi")
ESTIMATES = ("gather", "patch")


def direction_samples(kind, count, seed, chains=1):
    """``count`` points of [0,1)^2 per chain that pick the global directions, one per
    iteration: numpy array (count, chains, 2).

    'independent': pseudo-random (numpy PCG64 seeded by ``seed``); 'halton': bases 2, 3
    (points 1 .. count); 'hammersley': (n/count, radical inverse base 2), whose first
    coordinate only grows (the paper's figure 7 failure); 'pi': the paper's
    q_n = {(pi - 2) q_{n-1}} scheme (kept modulo 100000 as in the paper; a value that
    falls below 1 is restarted at random, because x -> 1.14 x leaves small values only
    slowly), consecutive values paired. Every chain of the quasi-random sequences gets
    its own random Cranley-Patterson shift from ``seed`` (only of the second coordinate
    for Hammersley, whose ordering is the point of it), so that seeds and chains differ."""
    rng = np.random.default_rng(seed)
    if kind == "independent":
        return rng.random((count, chains, 2))
    if kind == "halton":
        pts = qmc.points("halton", count, 2, start=1)
    elif kind == "hammersley":
        pts = qmc.points("hammersley", count, 2)
        pts[:, 0] += 0.5 / count          # centred: (n + 1/2) / count
    else:  # 'pi'
        return np.stack([_pi_sequence(count, rng) for _ in range(chains)], axis=1)
    pts = np.repeat(pts[:, None, :], chains, axis=1)
    shift = rng.random((chains, 2))
    if kind == "hammersley":
        shift[:, 0] = 0.0
    return np.mod(pts + shift[None], 1.0)


def _pi_sequence(count, rng):
    """``count`` 2-d points of the paper's q_n = {(pi - 2) q_{n-1}} scheme (a scalar
    recurrence: one step per value), with a random start and shift."""
    q = 1.0 + 99999.0 * rng.random()
    vals = []
    for _ in range(2 * count):
        q = ((math.pi - 2.0) * q) % 100000.0
        if q < 1.0:
            q += 1.0 + 99999.0 * rng.random()
        vals.append(q - math.floor(q))
    return np.mod(np.array(vals).reshape(count, 2) + rng.random(2), 1.0)


def uniform_sphere_directions(samples):
    """Points of [0,1)^2 (numpy (n, 2)) -> uniformly distributed unit directions (n, 3):
    the first coordinate sets z = cos(theta), the second the azimuth (Mitsuba's warp
    takes them the other way round). With Hammersley points the polar angle therefore
    sweeps monotonically from one pole to the other, the paper's failure case."""
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(samples[:, 1], samples[:, 0]))
    return np.stack([np.array(d.x), np.array(d.y), np.array(d.z)], axis=1).astype(np.float64)


def _chain_directions(dirs):
    """numpy (chains, 3) -> Vector3f with one direction per chain (a fresh buffer every
    iteration, so a new direction does not recompile the kernels)."""
    return mi.Vector3f(*(mi.Float(np.ascontiguousarray(dirs[:, c], dtype=np.float32)) for c in range(3)))


def _bounding_sphere(scene, table):
    """Centre (the bounding box's) and radius (farthest vertex, slightly enlarged) of a
    sphere around all triangles: tighter than the box's circumsphere for round scenes,
    so fewer bundle lines miss everything."""
    center = np.array(scene.bbox().center(), dtype=np.float64)
    radius = float(np.sqrt(np.max(np.sum((table.vertices_np - center) ** 2, axis=-1))))
    return mi.ScalarPoint3f(*center), radius * 1.001 + 1e-6


def _direct_light_mis(scene, si, bsdf, rng, active):
    """Direct light at ``si`` toward ``si.wi``: one light and one BSDF sample, MIS."""
    light_sample = mi.Point2f(rng.next_float32(), rng.next_float32())
    bsdf_sample = (rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()))
    return direct_light(scene, si, bsdf, light_sample, active, bsdf_sample)


class ChainLayout:
    """Lane bookkeeping for ``chains`` independent chains run in lockstep: patch ``t``
    of chain ``b`` is slot ``b * count + t`` of the radiance arrays."""

    def __init__(self, table, chains):
        self.table, self.chains, self.count = table, chains, table.count
        self.slots = chains * table.count

    def slot_triangle_chain(self):
        slot = dr.arange(mi.UInt32, self.slots)
        return slot % self.count, slot // self.count

    def slot_of(self, tri, chain):
        return chain * self.count + tri


class RayBundleIntegrator(mi.SamplingIntegrator):
    r"""
    .. _integrator-ray_bundle:

    Stochastic iteration with global ray bundles (``ray_bundle``)
    -------------------------------------------------------------

    Finite-element stochastic iteration over the triangles of the scene's meshes. Each
    patch :math:`i` keeps only its radiance :math:`L[i]` in the current global direction
    :math:`\omega_m` (and in :math:`-\omega_m` when ``bidirectional``). Every iteration
    transfers all patch radiances along :math:`\omega_m` with a bundle of
    ``resolution`` x ``resolution`` jittered parallel lines across the scene's bounding
    sphere (all successive hits along each line; consecutive hits facing each other
    exchange radiance), picks a new direction :math:`\omega_{m+1}`, and reflects:

    .. math:: L_{new}[i] = L^e_i(\omega_{m+1}) + 4\pi f_i(\omega_m,\omega_{m+1}) \sum_j A(i,j,\omega_m)/A_i\, L[j]

    (with ``bidirectional`` both :math:`\pm\omega` are used and each gets weight
    :math:`2\pi`). Emission and BSDF are evaluated at a uniformly random point of each
    patch every iteration, so textures are averaged without bias. Memory is
    O(chains x (triangles + resolution^2)).

    .. list-table::
       * - Parameter, type, default, range: meaning
       * - ``iterations``, int, 64, >= 1: global directions (transfers) per render pass
       * - ``burn_in``, int, 8, 0 .. iterations-1: iterations left out of the image average
       * - ``resolution``, int, 128, >= 1: lines per side of the bundle
       * - ``chains``, int, 1, >= 1: chains (own direction sequence, own
           patch radiances) run in lockstep, one kernel per iteration for all of them;
           the image averages the chains. 1 is the paper's algorithm; more chains use the
           cores better when ``resolution^2`` or the triangle count is small
       * - ``bidirectional``, bool, true: use every line in both directions
       * - ``first_shot``, bool, false: direct light by next-event estimation (one
           visibility-tested light sample per patch point and per camera sample, as in
           the "first shot" of radiosity); the bundles then carry only reflected
           radiance. Unbiased like the default; much less noise where direct light
           dominates (small lights). false is the paper's algorithm
       * - ``estimate``, string, 'gather': 'gather' (per pixel, reflect the stored radiance
           arriving along the bundle direction(s) at the visible point toward the eye) or
           'patch' (per pixel, the patch-averaged incoming radiance of the visible patch)
       * - ``direction_sequence``, string, 'independent': 'independent' | 'halton' |
           'hammersley' | 'pi'. Only 'independent' is correct: the others are 1-uniform
           sequences and bias the result (paper section 6.1).
       * - ``stratify_chains``, bool, true with 'independent': every iteration, the
           directions of the chains form one evenly spread set (a spherical Fibonacci
           set, over the hemisphere when ``bidirectional``), freshly randomly rotated and
           dealt to the chains in a fresh random order. Each chain's directions stay
           independent and uniform (unbiased, as the paper requires) while the image,
           which averages the chains, has less noise (RMSE halved on the furnace
           sphere mesh with 64 chains). false: independent directions in every
           chain. No effect with one chain; only with 'independent'
       * - ``hide_emitters``, bool, false: do not show directly visible emitters

    ``mi.render(scene, spp=k)`` runs ``iterations * k`` global iterations of every chain;
    every averaged iteration traces one fresh camera sample per pixel and chain (work
    linear in ``k`` and in ``chains``).

    Progress: ``integrator.progress_callback = f``; ``f(done, total)`` after every
    iteration, return ``False`` to stop early; Ctrl-C also stops early; the finished
    iterations make the image.

    With ``first_shot`` the stored radiance is the reflected part
    :math:`L_r = L - L^e` and the iteration is
    :math:`L_r^{new}[i] = (T L^e)_i(\omega_{m+1}) + 4\pi f_i \sum_j A(i,j,\omega_m)/A_i\, L_r[j]`
    with :math:`T L^e` (direct light) estimated by one light sample at the patch point;
    the image adds the directly seen emission, the direct light at the visible point
    (one light sample) and the gathered or patch-averaged reflected radiance.

    Caveats: only triangle meshes (other shapes: ``NonMeshShapeError``). The radiance is
    constant per patch, so non-constant radiance over a patch is averaged (bias of order
    of the radiance variation within a triangle; zero in the furnace and constant-radiance
    cases). Transport through delta (mirror/glass) surfaces cannot be captured by random
    global directions: such surfaces only reflect the camera rays (a warning is issued).
    """

    def __init__(self, props=mi.Properties()):
        super().__init__(props)
        who = "ray_bundle"
        check_variant(who)
        self.iterations = int_param(props, "iterations", 64, 1, None, who)
        self.burn_in = int_param(props, "burn_in", min(8, self.iterations - 1), 0, self.iterations - 1, who)
        self.resolution = int_param(props, "resolution", 128, 1, None, who)
        self.chains = int_param(props, "chains", 1, 1, None, who)
        self.bidirectional = bool_param(props, "bidirectional", True)
        self.first_shot = bool_param(props, "first_shot", False)
        self.estimate = choice_param(props, "estimate", "gather", ESTIMATES, who)
        self.direction_sequence = choice_param(props, "direction_sequence", "independent", DIRECTION_SEQUENCES, who)
        independent = self.direction_sequence == "independent"
        self.stratify_chains = bool_param(props, "stratify_chains", independent)
        if self.stratify_chains and not independent:
            raise ValueError("ray_bundle: stratify_chains=true needs direction_sequence='independent' (got %r): "
                             "the other sequences give every chain its own sequence"
                             % self.direction_sequence)
        self.hide_emitters = bool_param(props, "hide_emitters", False)
        self.progress_callback = None
        self.iterations_done, self.interrupted, self.averaged_fraction = 0, False, 0.0

    def iteration_count(self, spp):
        """Global iterations of a render with ``spp``: ``iterations * spp`` (each advances
        every chain)."""
        return self.iterations * int(spp)

    # ------------------------------------------------------------------ patches
    def _patch_interaction(self, layout, rng, out_dirs):
        """A uniformly random point of every patch of every chain, seen from the chain's
        direction ``out_dirs`` (one per chain)."""
        tri, chain = layout.slot_triangle_chain()
        out = dr.gather(mi.Vector3f, out_dirs, chain)
        si = layout.table.surface_interaction(tri, mi.Point2f(rng.next_float32(), rng.next_float32()), out)
        return si, tri, chain

    def _source(self, scene, si, rng):
        """The radiance a patch point sends toward ``si.wi`` without the bundles'
        transport: its emission Le, or with ``first_shot`` the direct light it reflects
        (T Le, one light sample drawn from ``rng``; no rays where ``si.wi`` is behind a
        surface that neither transmits nor has a back side)."""
        if self.first_shot:
            bsdf = si.bsdf()
            flags = bsdf.flags()
            can_reach = ((mi.Frame3f.cos_theta(si.wi) > 0) | mi.has_flag(flags, mi.BSDFFlags.BackSide)
                         | mi.has_flag(flags, mi.BSDFFlags.Transmission))
            return _direct_light_mis(scene, si, bsdf, rng, can_reach)
        return mi.Color3f(si.emitter(scene).eval(si))

    def _direct_at(self, scene, si, bsdf, valid, rng):
        """Direct light at the camera samples' visible points with ``first_shot`` (the
        bundles carry only reflected radiance then), else zero."""
        if not self.first_shot:
            return mi.Color3f(0.0)
        return _direct_light_mis(scene, si, bsdf, rng, valid)

    def _reflect(self, si, incoming, towards_source):
        """f_i(incoming direction -> si.wi) * incoming / A_i, f from bsdf.eval / cos."""
        bsdf = si.bsdf()
        wo = si.to_local(towards_source)
        cos_in = mi.Frame3f.cos_theta(wo)
        value = mi.Color3f(bsdf.eval(mi.BSDFContext(), si, wo, cos_in > 1e-6))
        return dr.select(cos_in > 1e-6, value / cos_in, 0.0) * incoming

    # ------------------------------------------------------------------ transfer
    def _transfer(self, scene, layout, dirs, L_fwd, L_bwd, rng, center, radius):
        """Walk all lines of every chain's bundle along its direction ``d`` (``dirs``: one
        per chain); returns the radiance power per unit projected area arriving at each
        patch along +d (from L_fwd) and along -d (from L_bwd), summed over the lines
        (i.e. sum_j A(i,j,+-d) L_j), per chain."""
        table, res = layout.table, self.resolution
        per_chain = res * res
        n_lines = per_chain * layout.chains
        k = dr.arange(mi.UInt32, n_lines)
        chain, line = k // per_chain, k % per_chain
        d = dr.gather(mi.Vector3f, dirs, chain)
        frame = mi.Frame3f(d)
        cell = 2.0 * radius / res
        u = (mi.Float(line % res) + rng.next_float32()) * cell - radius
        v = (mi.Float(line // res) + rng.next_float32()) * cell - radius
        origin = center + frame.s * u + frame.t * v - d * (1.01 * radius)
        ray = mi.Ray3f(origin, d)
        in_fwd = dr.zeros(mi.Color3f, layout.slots)
        in_bwd = dr.zeros(mi.Color3f, layout.slots)
        delta_area = cell * cell
        active = (u * u + v * v) <= radius * radius

        def body(ray, active, prev, prev_fwd):
            pi = scene.ray_intersect_preliminary(ray, active)
            hit = active & pi.is_valid()
            si = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal, hit)
            tri = table.triangle_index(si.shape, si.prim_index)
            n = dr.gather(mi.Normal3f, table.normal, tri, hit)
            cos_d = dr.dot(n, d)
            slot = layout.slot_of(tri, chain)
            exchange = hit & prev_fwd & (cos_d < 0)
            dr.scatter_add(in_fwd, dr.gather(mi.Color3f, L_fwd, prev, exchange) * delta_area, slot, exchange, mode=SPLAT_MODE)
            dr.scatter_add(in_bwd, dr.gather(mi.Color3f, L_bwd, slot, exchange) * delta_area, prev, exchange, mode=SPLAT_MODE)
            ray = si.spawn_ray(d)
            return ray, hit, slot, hit & (cos_d > 0)

        dr.while_loop((ray, active, dr.zeros(mi.UInt32, n_lines), mi.Bool(False)),
                      lambda ray, active, prev, prev_fwd: active, body)
        return in_fwd, in_bwd

    # ------------------------------------------------------------------ image
    def _camera_chains(self, layout, paths, dirs):
        """Chain of each camera sample (``chains`` samples per pixel, one per chain) and
        that chain's direction."""
        chain = dr.arange(mi.UInt32, paths.count) % layout.chains
        return chain, dr.gather(mi.Vector3f, dirs, chain)

    def _gather(self, scene, layout, paths, dirs, L_fwd, L_bwd, weight, rng):
        """Per camera sample: reflect the stored radiance arriving at the visible point
        along +d (from the patch seen in direction -d) and along -d toward the eye."""
        table = layout.table
        chain, d = self._camera_chains(layout, paths, dirs)
        si = scene.ray_intersect(paths.ray, paths.valid)
        valid = paths.valid & si.is_valid()
        bsdf = si.bsdf(paths.ray)
        result = mi.Color3f(0.0)
        ctx = mi.BSDFContext()
        for sign, L in ((1.0, L_fwd), (-1.0, L_bwd)):
            if L is None:
                continue
            travel = d * sign                      # radiance travels along `travel`
            wo = si.to_local(-travel)              # toward its source
            ok = valid & (mi.Frame3f.cos_theta(wo) > 0)
            src = scene.ray_intersect(si.spawn_ray(-travel), ok)
            ok &= src.is_valid()
            tri = table.triangle_index(src.shape, src.prim_index)
            n_src = dr.gather(mi.Normal3f, table.normal, tri, ok)
            ok &= dr.dot(n_src, travel) > 0
            radiance = dr.gather(mi.Color3f, L, layout.slot_of(tri, chain), ok)
            f_cos = mi.Color3f(bsdf.eval(ctx, si, wo, ok))
            result += dr.select(ok, f_cos * radiance, 0.0)
        return paths.throughput * (result * weight + self._direct_at(scene, si, bsdf, valid, rng))

    def _patch_estimate(self, scene, layout, paths, dirs, in_fwd, in_bwd, weight, rng):
        """Per camera sample: reflect the patch-averaged incoming radiance of the visible
        patch (sum_j A(i,j,+-d) L[j] / A_i) toward the eye at the visible point."""
        table = layout.table
        chain, d = self._camera_chains(layout, paths, dirs)
        si = scene.ray_intersect(paths.ray, paths.valid)
        valid = paths.valid & si.is_valid()
        tri = table.triangle_index(si.shape, si.prim_index)
        area = dr.gather(mi.Float, table.area, tri, valid)
        slot = layout.slot_of(tri, chain)
        result = mi.Color3f(0.0)
        for sign, incoming in ((1.0, in_fwd), (-1.0, in_bwd)):
            if incoming is None:
                continue
            inc = dr.gather(mi.Color3f, incoming, slot, valid) / dr.maximum(area, 1e-30)
            result += dr.select(valid, self._reflect(si, inc, -d * sign), 0.0)
        return paths.throughput * (result * weight + self._direct_at(scene, si, si.bsdf(paths.ray), valid, rng))

    # ------------------------------------------------------------------ render
    def _warn_delta(self, scene):
        names = [s.id() for s in scene.shapes()
                 if s.bsdf() is not None and mi.has_flag(s.bsdf().flags(), mi.BSDFFlags.Delta)]
        if names:
            warnings.warn("ray_bundle: shape(s) %s have delta (mirror/glass) BSDF lobes; light transport "
                          "through delta surfaces cannot be captured by random global directions, only "
                          "camera rays are reflected by them. The result is biased where transport depends "
                          "on them; use stochastic_ray or path for such scenes." % ", ".join(names),
                          RuntimeWarning, stacklevel=2)

    def _initial_radiance(self, scene, layout, rng_patch, dirs):
        """Source radiance of every patch along +d (and -d when bidirectional): L_0 = Le
        (with ``first_shot``: the direct light T Le)."""
        si, _, _ = self._patch_interaction(layout, rng_patch, dirs)
        L_fwd = self._source(scene, si, rng_patch)
        L_bwd = None
        if self.bidirectional:
            si_b, _, _ = self._patch_interaction(layout, rng_patch, -dirs)
            L_bwd = self._source(scene, si_b, rng_patch)
        return L_fwd, L_bwd

    def _reflect_into(self, scene, layout, rng_patch, dirs, new_dirs, in_fwd, in_bwd, weight):
        """L_new = Le(new direction) + weight * f * (incoming along +-d) / A_i, per patch
        and chain, for +new_dirs (and -new_dirs when bidirectional); with ``first_shot``
        the direct light T Le replaces Le."""
        new_L = []
        for out_dirs in ((new_dirs, -new_dirs) if self.bidirectional else (new_dirs,)):
            si, tri, chain = self._patch_interaction(layout, rng_patch, out_dirs)
            d = dr.gather(mi.Vector3f, dirs, chain)
            # degenerate triangles: never hit, no NaN
            area = dr.maximum(dr.gather(mi.Float, layout.table.area, tri), 1e-30)
            L = self._source(scene, si, rng_patch)
            L += weight * self._reflect(si, in_fwd / area, -d)
            if in_bwd is not None:
                L += weight * self._reflect(si, in_bwd / area, d)
            new_L.append(L)
        return new_L[0], (new_L[1] if self.bidirectional else None)

    def _global_directions(self, count, seed):
        """The global direction of every chain for ``count`` iterations: numpy
        (count, chains, 3); stratified across the chains with ``stratify_chains``
        (and more than one chain)."""
        if self.stratify_chains and self.chains > 1:
            rng = np.random.default_rng(seed)
            return stratified_direction_sets(count, self.chains, rng, antipodal=self.bidirectional)
        samples = direction_samples(self.direction_sequence, count, seed, self.chains)
        return uniform_sphere_directions(samples.reshape(-1, 2)).reshape(count, self.chains, 3)

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        sensor = resolve_sensor(scene, sensor)
        film = sensor.film()
        size = film.crop_size()
        width, height = int(size[0]), int(size[1])
        n_pix = width * height
        spp = sensor_spp(sensor, spp)
        seed = int(seed)
        chains = self.chains
        layout = ChainLayout(MeshTable(scene, "ray_bundle"), chains)
        self._warn_delta(scene)

        center, radius = _bounding_sphere(scene, layout.table)
        total = self.iterations * spp
        burn_in = self.burn_in
        all_dirs = self._global_directions(total + 1, seed)
        weight = 2.0 * math.pi if self.bidirectional else 4.0 * math.pi

        n_lines = self.resolution ** 2 * chains
        rng_lines = mi.PCG32(n_lines, initstate=dr.opaque(mi.UInt64, seed * 2654435761 + 7),
                             initseq=mi.UInt64(dr.arange(mi.UInt32, n_lines)))
        rng_patch = mi.PCG32(layout.slots, initstate=dr.opaque(mi.UInt64, seed * 1000003 + 11),
                             initseq=mi.UInt64(dr.arange(mi.UInt32, layout.slots)))

        dirs = _chain_directions(all_dirs[0])
        L_fwd, L_bwd = self._initial_radiance(scene, layout, rng_patch, dirs)
        dr.eval(L_fwd, L_bwd, rng_patch.state)

        accum = dr.zeros(mi.Float, n_pix * 3)
        progress = Progress(self, total, burn_in)
        try:
            for m in progress:
                in_fwd, in_bwd = self._transfer(scene, layout, dirs, L_fwd,
                                                L_bwd if L_bwd is not None else L_fwd, rng_lines, center, radius)
                if not self.bidirectional:
                    in_bwd = None
                new_accum = accum
                if m >= burn_in:
                    # one fresh camera sample per pixel, chain and iteration
                    paths = camera_paths(scene, sensor, chains, seed * 1000081 + m, -1, self.hide_emitters)
                    rng_cam = mi.PCG32(paths.count, initstate=dr.opaque(mi.UInt64, seed * 1000099 + m * 31 + 5),
                                       initseq=mi.UInt64(dr.arange(mi.UInt32, paths.count)))
                    if self.estimate == "gather":
                        est = self._gather(scene, layout, paths, dirs, L_fwd, L_bwd, weight, rng_cam)
                    else:
                        est = self._patch_estimate(scene, layout, paths, dirs, in_fwd, in_bwd, weight, rng_cam)
                    new_accum = accum + paths.emission_image
                    for c in range(3):
                        dr.scatter_add(new_accum, est[c] / chains, paths.pixel * 3 + c, mode=SPLAT_MODE)
                # new global direction per chain and reflection into it
                new_dirs = _chain_directions(all_dirs[m + 1])
                L_fwd_new, L_bwd_new = self._reflect_into(scene, layout, rng_patch, dirs, new_dirs,
                                                          in_fwd, in_bwd, weight)
                dr.eval(L_fwd_new, L_bwd_new, new_accum, rng_lines.state, rng_patch.state)
                L_fwd, L_bwd, accum, dirs = L_fwd_new, L_bwd_new, new_accum, new_dirs
        except KeyboardInterrupt:
            progress.stop()  # Ctrl-C: keep the finished iterations
        image = accum / max(progress.averaged, 1)
        return image_to_film(film, mi.TensorXf(image, shape=(height, width, 3)), develop)
