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
from mi_plugins.integrators.stochastic_common import (Progress, check_variant, resolve_sensor, sensor_spp,
                                                      image_to_film, camera_paths, SPLAT_MODE)
from mi_plugins.params import Params

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


class DiffuseAverage:
    """Per-triangle averages over all chains and averaged iterations for the patches
    whose BSDF is purely diffuse (``average_diffuse``): their outgoing radiance does not
    depend on the direction, so every chain's value in every iteration estimates the
    same number. With the 'gather' estimate the average is of the radiance the patches
    reflect from the bundles, R = weight * f * sum_j A(i,j,+-d) L[j] / A_i; the gathered
    point adds its own source term evaluated where the gather ray lands (its emission,
    or with ``first_shot`` its direct light by next-event estimation; with
    ``gather_nee=false`` the direct light is averaged too). With 'patch' it
    is of the incoming radiance weight * sum_j A(i,j,+-d) L[j] / A_i. Only front sides
    are stored (the bundles exchange radiance between front sides)."""

    def __init__(self, table, estimate):
        flags = np.array([shape.bsdf().flags() if shape.bsdf() is not None else 0 for shape in table.meshes],
                         dtype=np.int64)
        diffuse_mesh = (flags & int(mi.BSDFFlags.All)) == int(mi.BSDFFlags.DiffuseReflection)
        diffuse = diffuse_mesh[table.shape_index_np]
        self.covers_all = bool(np.all(diffuse))
        self.estimate = estimate
        self.mask = mi.Bool(diffuse)
        self.table = table
        self.sum = dr.zeros(mi.Color3f, table.count)
        self.count = dr.zeros(mi.Float, table.count)

    def state(self):
        return self.sum, self.count

    def is_averaged(self, tri, active):
        return dr.gather(mi.Bool, self.mask, tri, active)

    def mean(self, tri, active):
        return (dr.gather(mi.Color3f, self.sum, tri, active)
                / dr.maximum(dr.gather(mi.Float, self.count, tri, active), 1.0))

    def add(self, layout, dirs, radiance, incoming, weight):
        """Add one iteration of every chain: the stored radiance (+d, -d or None) of the
        side each patch shows (the front side; one of +-d faces it), or the incoming."""
        tri, chain = layout.slot_triangle_chain()
        if self.estimate == "patch":
            area = dr.maximum(dr.gather(mi.Float, self.table.area, tri), 1e-30)
            value = incoming[0] if incoming[1] is None else incoming[0] + incoming[1]
            value, count = value * (weight / area), mi.Float(1.0)
        else:
            d = dr.gather(mi.Vector3f, dirs, chain)
            cos_d = dr.dot(dr.gather(mi.Normal3f, self.table.normal, tri), d)
            if radiance[1] is None:  # only +d: the patch shows its front to half of the directions
                value, count = dr.select(cos_d > 0, radiance[0], 0.0), dr.select(cos_d > 0, 1.0, 0.0)
            else:
                value, count = dr.select(cos_d > 0, radiance[0], radiance[1]), dr.select(cos_d != 0, 1.0, 0.0)
        dr.scatter_add(self.sum, value, tri, mode=SPLAT_MODE)
        dr.scatter_add(self.count, count, tri, mode=SPLAT_MODE)


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
       * - ``average_diffuse``, bool, false: final gathering from averaged diffuse
           patches. A patch with a purely diffuse BSDF reflects the same radiance in
           every direction, so all chains' values in all averaged iterations estimate
           the same number: their average (O(triangles) memory) replaces the current
           chain's value in the image. The image is then made after the iterations, one
           pass per averaged iteration (same camera samples and directions; with
           ``first_shot`` the gathered point's direct light by next-event estimation).
           Unbiased like the default for the patch-averaged problem; far less noise
           (furnace sphere mesh: 6x lower RMSE at equal time than first shot alone). Non-diffuse patches
           keep the paper's per-chain estimate. false is the paper's algorithm
       * - ``gather_nee``, bool, true: with ``first_shot`` and ``average_diffuse``, the
           direct light of each gathered point by next-event estimation (exact where it
           varies within a patch, e.g. near lights). false: the direct light is part of
           the patch average (no extra rays). true is exact where the reflected
           radiance minus the direct light is constant per patch; where only their
           sum is (neighbouring patches emitting differently, e.g. the Bekaert box:
           0.6 % low) use false
       * - ``hide_emitters``, bool, false: do not show directly visible emitters

    ``mi.render(scene, spp=k)`` runs ``iterations * k`` global iterations of every chain;
    every averaged iteration traces one fresh camera sample per pixel and chain (work
    linear in ``k`` and in ``chains``). With ``average_diffuse`` those camera samples are
    traced after the iterations (the final gathering), and again during the iterations
    when the scene also has non-diffuse patches.

    Progress: ``integrator.progress_callback = f``; ``f(done, total)`` after every
    iteration, return ``False`` to stop early; Ctrl-C also stops early; the finished
    iterations make the image. With ``average_diffuse`` the steps also count the final
    gathering's passes (``integrator.iteration_count(spp)``); stopping during the
    iterations still runs one final-gathering pass per finished averaged iteration
    (stop again to cut it short: the finished passes, at least one, make the image).

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
        p = Params(props, "ray_bundle")
        hide_emitters = p.bool("hide_emitters", False)   # before the base class reads it with its own check
        super().__init__(props)
        check_variant("ray_bundle")
        self.iterations = p.int("iterations", 64, lo=1)
        self.burn_in = p.int("burn_in", min(8, self.iterations - 1), lo=0)
        if self.burn_in > self.iterations - 1:
            raise p.conflict(("burn_in", "iterations"), "burn_in in 0 .. iterations - 1 = %d" % (self.iterations - 1))
        self.resolution = p.int("resolution", 128, lo=1)
        self.chains = p.int("chains", 1, lo=1)
        self.bidirectional = p.bool("bidirectional", True)
        self.first_shot = p.bool("first_shot", False)
        self.estimate = p.choice("estimate", "gather", ESTIMATES)
        self.direction_sequence = p.choice("direction_sequence", "independent", DIRECTION_SEQUENCES)
        independent = self.direction_sequence == "independent"
        self.stratify_chains = p.bool("stratify_chains", independent)
        if self.stratify_chains and not independent:
            raise p.conflict(("stratify_chains", "direction_sequence"),
                             "stratify_chains=true needs direction_sequence='independent' (the other sequences "
                             "give every chain its own sequence)")
        self.hide_emitters = hide_emitters
        self.average_diffuse = p.bool("average_diffuse", False)
        self.gather_nee = p.bool("gather_nee", True)
        self.progress_callback = None
        self.iterations_done, self.interrupted, self.averaged_fraction = 0, False, 0.0

    def iteration_count(self, spp):
        """Steps of a render with ``spp``: ``iterations * spp`` global iterations (each
        advances every chain), plus with ``average_diffuse`` the final gathering's passes
        (one per averaged iteration)."""
        total = self.iterations * int(spp)
        return total + (total - self.burn_in if self.average_diffuse else 0)

    def _both_ways(self, x):
        """(x, -x) when the bundles are used in both directions, else (x,): the global
        direction(s), or their signs, of one iteration."""
        return (x, -x) if self.bidirectional else (x,)

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

    def _gather(self, scene, layout, paths, dirs, L, weight, rng, part="all", average=None):
        """Per camera sample: reflect the radiance arriving at the visible point along +d
        (from the patch seen in direction -d) and along -d toward the eye. ``L``: the
        stored radiance (+d, -d or None). ``part``: 'all' (every source from the
        chains' stored radiance, plus the direct light), 'current' (only sources that
        are not averaged) or 'average' (only averaged diffuse sources, plus the direct
        light); see :class:`DiffuseAverage`."""
        table = layout.table
        chain, d = self._camera_chains(layout, paths, dirs)
        si = scene.ray_intersect(paths.ray, paths.valid)
        valid = paths.valid & si.is_valid()
        bsdf = si.bsdf(paths.ray)
        result = mi.Color3f(0.0)
        ctx = mi.BSDFContext()
        for k, sign in enumerate(self._both_ways(1.0)):
            L_dir = L[k] if L is not None else None     # not needed for the averaged part
            travel = d * sign                      # radiance travels along `travel`
            wo = si.to_local(-travel)              # toward its source
            ok = valid & (mi.Frame3f.cos_theta(wo) > 0)
            src = scene.ray_intersect(si.spawn_ray(-travel), ok)
            ok &= src.is_valid()
            tri = table.triangle_index(src.shape, src.prim_index)
            n_src = dr.gather(mi.Normal3f, table.normal, tri, ok)
            ok &= dr.dot(n_src, travel) > 0
            radiance = self._source_radiance(scene, layout, src, tri, chain, L_dir, part, average, ok, rng)
            f_cos = mi.Color3f(bsdf.eval(ctx, si, wo, ok))
            result += dr.select(ok, f_cos * radiance, 0.0)
        direct = self._direct_at(scene, si, bsdf, valid, rng) if part != "current" else mi.Color3f(0.0)
        return paths.throughput * (result * weight + direct)

    def _source_radiance(self, scene, layout, src, tri, chain, L_dir, part, average, active, rng):
        """Radiance of the gathered source point ``src`` (patch ``tri``) toward the
        camera sample: the chain's stored value, or for averaged diffuse patches the
        average over chains and iterations (plus the emission at ``src`` itself when
        the average holds only reflected radiance)."""
        if part == "all":
            return dr.gather(mi.Color3f, L_dir, layout.slot_of(tri, chain), active)
        diffuse = average.is_averaged(tri, active)
        if part == "current":
            keep = active & ~diffuse
            return dr.select(keep, dr.gather(mi.Color3f, L_dir, layout.slot_of(tri, chain), keep), 0.0)
        use = active & diffuse
        radiance = average.mean(tri, use)
        if not self.first_shot:
            radiance += mi.Color3f(src.emitter(scene, use).eval(src, use))
        elif self.gather_nee:   # first shot: the direct light at the gathered point itself, by NEE
            radiance += _direct_light_mis(scene, src, src.bsdf(), rng, use)
        return dr.select(use, radiance, 0.0)

    def _patch_estimate(self, scene, layout, paths, dirs, incoming, weight, rng, part="all", average=None):
        """Per camera sample: reflect the patch-averaged incoming radiance of the visible
        patch (sum_j A(i,j,+-d) L[j] / A_i) toward the eye at the visible point.
        ``part`` as in :meth:`_gather`; averaged diffuse patches use the average of
        that incoming radiance over chains and iterations."""
        table = layout.table
        chain, d = self._camera_chains(layout, paths, dirs)
        si = scene.ray_intersect(paths.ray, paths.valid)
        valid = paths.valid & si.is_valid()
        bsdf = si.bsdf(paths.ray)
        tri = table.triangle_index(si.shape, si.prim_index)
        result = mi.Color3f(0.0)
        if part == "average":
            use = valid & average.is_averaged(tri, valid)
            # a diffuse BSDF's value does not depend on the directions: take it at the normal
            f = mi.Color3f(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0, 0, 1), use))
            result = dr.select(use, f * average.mean(tri, use), 0.0)
        else:
            area = dr.gather(mi.Float, table.area, tri, valid)
            slot = layout.slot_of(tri, chain)
            for k, sign in enumerate(self._both_ways(1.0)):
                inc = dr.gather(mi.Color3f, incoming[k], slot, valid) / dr.maximum(area, 1e-30)
                result += dr.select(valid, self._reflect(si, inc, -d * sign), 0.0) * weight
            if part == "current":
                result = dr.select(average.is_averaged(tri, valid), 0.0, result)
        direct = self._direct_at(scene, si, bsdf, valid, rng) if part != "current" else mi.Color3f(0.0)
        return paths.throughput * (result + direct)

    def _image_estimate(self, scene, layout, sensor, m, seed, dirs, L, incoming, weight, part, average):
        """One camera sample per pixel and chain (iteration ``m``'s camera seed): the
        flat (H*W*3) image of this estimate, divided by the chains; the directly seen
        emission is included unless ``part`` is 'current'."""
        chains = layout.chains
        paths = camera_paths(scene, sensor, chains, seed * 1000081 + m, -1, self.hide_emitters)
        rng_cam = mi.PCG32(paths.count, initstate=dr.opaque(mi.UInt64, seed * 1000099 + m * 31 + 5),
                           initseq=mi.UInt64(dr.arange(mi.UInt32, paths.count)))
        if self.estimate == "gather":
            est = self._gather(scene, layout, paths, dirs, L, weight, rng_cam, part, average)
        else:
            est = self._patch_estimate(scene, layout, paths, dirs, incoming, weight, rng_cam, part, average)
        image = paths.emission_image if part != "current" else dr.zeros(mi.Float, dr.width(paths.emission_image))
        for c in range(3):
            dr.scatter_add(image, est[c] / chains, paths.pixel * 3 + c, mode=SPLAT_MODE)
        return image

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
        (with ``first_shot``: the direct light T Le). Returns (L, R): lists (+d, -d or
        None) of the radiance and of its part carried by the bundles (zero here)."""
        L = [None, None]
        for k, out_dirs in enumerate(self._both_ways(dirs)):
            si, _, _ = self._patch_interaction(layout, rng_patch, out_dirs)
            L[k] = self._source(scene, si, rng_patch)
        return L, [None if x is None else dr.zeros(mi.Color3f, layout.slots) for x in L]

    def _reflect_into(self, scene, layout, rng_patch, dirs, new_dirs, incoming, weight):
        """L_new = Le(new direction) + R, R = weight * f * (incoming along +-d) / A_i, per
        patch and chain, for +new_dirs (and -new_dirs when bidirectional); with
        ``first_shot`` the direct light T Le replaces Le. Returns (L, R) as
        :meth:`_initial_radiance`."""
        L, R = [None, None], [None, None]
        for k, out_dirs in enumerate(self._both_ways(new_dirs)):
            si, tri, chain = self._patch_interaction(layout, rng_patch, out_dirs)
            d = dr.gather(mi.Vector3f, dirs, chain)
            # degenerate triangles: never hit, no NaN
            area = dr.maximum(dr.gather(mi.Float, layout.table.area, tri), 1e-30)
            R[k] = weight * self._reflect(si, incoming[0] / area, -d)
            if incoming[1] is not None:
                R[k] += weight * self._reflect(si, incoming[1] / area, d)
            L[k] = self._source(scene, si, rng_patch) + R[k]
        return L, R

    def _final_gathering(self, scene, layout, sensor, seed, all_dirs, weight, average, progress):
        """The image of the averaged diffuse patches, the direct light and the seen
        emission: one pass per averaged iteration that finished (same camera samples and
        chain directions as that iteration), from the final averages. Ctrl-C (or the
        progress callback) ends it after the current pass; the image averages the
        finished passes."""
        accum, finished = None, 0
        for k in progress.second_stage(progress.averaged):
            m = self.burn_in + k
            try:
                pass_image = self._image_estimate(scene, layout, sensor, m, seed, _chain_directions(all_dirs[m]),
                                                  None, None, weight, "average", average)
                dr.eval(pass_image)
            except KeyboardInterrupt:
                if accum is None:
                    raise          # no finished pass: there is no image to keep
                progress.stop()
                break
            accum = pass_image if accum is None else accum + pass_image
            finished += 1
        return accum / finished

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
        L, R = self._initial_radiance(scene, layout, rng_patch, dirs)
        dr.eval(L, rng_patch.state)

        average = DiffuseAverage(layout.table, self.estimate) if self.average_diffuse else None
        # without averaging every iteration images everything ('all'); with it, the
        # iterations image only the patches that are not averaged ('current', skipped when
        # there are none) and the final gathering images the averaged ones ('average')
        part = "all" if average is None else "current"
        image_per_iteration = average is None or not average.covers_all
        accum = dr.zeros(mi.Float, n_pix * 3)
        progress = Progress(self, total, burn_in, self.iteration_count(spp))
        try:
            for m in progress:
                incoming = self._transfer(scene, layout, dirs, L[0], L[1] if L[1] is not None else L[0],
                                          rng_lines, center, radius)
                if not self.bidirectional:
                    incoming = (incoming[0], None)
                new_accum = accum
                if m >= burn_in:
                    if average is not None:
                        # the average holds what the gathered point does not add itself
                        average.add(layout, dirs, L if self.first_shot and not self.gather_nee else R,
                                    incoming, weight)
                    if image_per_iteration:
                        new_accum = accum + self._image_estimate(scene, layout, sensor, m, seed, dirs, L,
                                                                 incoming, weight, part, average)
                # new global direction per chain and reflection into it
                new_dirs = _chain_directions(all_dirs[m + 1])
                L, R = self._reflect_into(scene, layout, rng_patch, dirs, new_dirs, incoming, weight)
                dr.eval(L, R if average is not None else None, new_accum, rng_lines.state, rng_patch.state,
                        average.state() if average is not None else None)
                dirs, accum = new_dirs, new_accum   # (Ctrl-C before this line: iteration m is not kept)
        except KeyboardInterrupt:
            progress.stop()  # Ctrl-C: keep the finished iterations
        image = accum / max(progress.averaged, 1) if image_per_iteration else accum
        if average is not None and progress.averaged > 0:
            image = image + self._final_gathering(scene, layout, sensor, seed, all_dirs, weight, average, progress)
        return image_to_film(film, mi.TensorXf(image, shape=(height, width, 3)), develop)
