"""Stochastic iteration with global ray bundles (Szirmay-Kalos, "Stochastic Iteration for
Non-diffuse Global Illumination", sections 5 and 6)."""
import math
import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import qmc
from mi_plugins.meshtable import MeshTable
from mi_plugins.integrators.stochastic_common import (Progress, check_variant, int_param, bool_param, choice_param,
                                                      resolve_sensor, sensor_spp, image_to_film, camera_paths, SPLAT_MODE)

DIRECTION_SEQUENCES = ("independent", "halton", "hammersley", "pi")
ESTIMATES = ("gather", "patch")


def direction_samples(kind, count, seed):
    """``count`` points of [0,1)^2 that pick the global directions, one per iteration.

    'independent': pseudo-random (numpy PCG64 seeded by ``seed``); 'halton': bases 2, 3
    (points 1 .. count); 'hammersley': (n/count, radical inverse base 2), whose first
    coordinate only grows (the paper's figure 7 failure); 'pi': the paper's
    q_n = {(pi - 2) q_{n-1}} scheme (kept modulo 100000 as in the paper; a value that
    falls below 1 is restarted at random, because x -> 1.14 x leaves small values only
    slowly), consecutive values paired. The quasi-random sequences get a random
    Cranley-Patterson shift from ``seed`` (only of the second coordinate for Hammersley,
    whose ordering is the point of it), so that seeds differ."""
    rng = np.random.default_rng(seed)
    if kind == "independent":
        return rng.random((count, 2))
    if kind == "halton":
        pts = qmc.points("halton", count, 2, start=1)
    elif kind == "hammersley":
        pts = qmc.points("hammersley", count, 2)
        pts[:, 0] += 0.5 / count          # centred: (n + 1/2) / count
    else:  # 'pi'
        q = 1.0 + 99999.0 * rng.random()
        vals = []
        for _ in range(2 * count):        # one scalar recurrence step per iteration
            q = ((math.pi - 2.0) * q) % 100000.0
            if q < 1.0:
                q += 1.0 + 99999.0 * rng.random()
            vals.append(q - math.floor(q))
        pts = np.array(vals).reshape(count, 2)
    shift = rng.random(2) if kind != "hammersley" else np.array([0.0, rng.random()])
    return np.mod(pts + shift, 1.0)


def uniform_sphere_directions(samples):
    """Points of [0,1)^2 (numpy (n, 2)) -> uniformly distributed unit directions (n, 3):
    the first coordinate sets z = cos(theta), the second the azimuth (Mitsuba's warp
    takes them the other way round). With Hammersley points the polar angle therefore
    sweeps monotonically from one pole to the other, the paper's failure case."""
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(samples[:, 1], samples[:, 0]))
    return np.stack([np.array(d.x), np.array(d.y), np.array(d.z)], axis=1).astype(np.float64)


def _opaque_dir(v):
    # opaque, so that a new direction does not recompile the kernels
    return mi.Vector3f(*(dr.opaque(mi.Float, float(c)) for c in v))


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
    O(triangles + resolution^2).

    .. list-table::
       * - Parameter, type, default, range: meaning
       * - ``iterations``, int, 64, >= 1: global directions (transfers) per render pass
       * - ``burn_in``, int, 8, 0 .. iterations-1: iterations left out of the image average
       * - ``resolution``, int, 128, >= 1: lines per side of the bundle
       * - ``bidirectional``, bool, true: use every line in both directions
       * - ``estimate``, string, 'gather': 'gather' (per pixel, reflect the stored radiance
           arriving along the bundle direction(s) at the visible point toward the eye) or
           'patch' (per pixel, the patch-averaged incoming radiance of the visible patch)
       * - ``direction_sequence``, string, 'independent': 'independent' | 'halton' |
           'hammersley' | 'pi'. Only 'independent' is correct: the others are 1-uniform
           sequences and bias the result (paper section 6.1).
       * - ``hide_emitters``, bool, false: do not show directly visible emitters

    ``mi.render(scene, spp=k)`` runs ``iterations * k`` global iterations; every averaged
    iteration traces one fresh camera sample per pixel (work linear in ``k``).

    Progress: ``integrator.progress_callback = f``; ``f(done, total)`` after every
    iteration, return ``False`` to stop early; Ctrl-C also stops early; the finished
    iterations make the image.

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
        self.bidirectional = bool_param(props, "bidirectional", True)
        self.estimate = choice_param(props, "estimate", "gather", ESTIMATES, who)
        self.direction_sequence = choice_param(props, "direction_sequence", "independent", DIRECTION_SEQUENCES, who)
        self.hide_emitters = bool_param(props, "hide_emitters", False)
        self.progress_callback = None
        self.iterations_done, self.interrupted, self.averaged_fraction = 0, False, 0.0

    def iteration_count(self, spp):
        """Global iterations of a render with ``spp``: ``iterations * spp``."""
        return self.iterations * int(spp)

    # ------------------------------------------------------------------ patches
    def _patch_interaction(self, table, rng, out_dir):
        tri = dr.arange(mi.UInt32, table.count)
        si = table.surface_interaction(tri, mi.Point2f(rng.next_float32(), rng.next_float32()), out_dir)
        return si

    def _emission(self, scene, si):
        return mi.Color3f(si.emitter(scene).eval(si))

    def _reflect(self, si, incoming, towards_source):
        """f_i(incoming direction -> si.wi) * incoming / A_i, f from bsdf.eval / cos."""
        bsdf = si.bsdf()
        wo = si.to_local(towards_source)
        cos_in = mi.Frame3f.cos_theta(wo)
        value = mi.Color3f(bsdf.eval(mi.BSDFContext(), si, wo, cos_in > 1e-6))
        return dr.select(cos_in > 1e-6, value / cos_in, 0.0) * incoming

    # ------------------------------------------------------------------ transfer
    def _transfer(self, scene, table, d, L_fwd, L_bwd, rng, center, radius):
        """Walk all lines of a bundle along ``d``; returns the radiance power per unit
        projected area arriving at each patch along +d (from L_fwd) and along -d (from
        L_bwd), summed over the lines (i.e. sum_j A(i,j,+-d) L_j)."""
        res = self.resolution
        n_lines = res * res
        frame = mi.Frame3f(d)
        k = dr.arange(mi.UInt32, n_lines)
        cell = 2.0 * radius / res
        u = (mi.Float(k % res) + rng.next_float32()) * cell - radius
        v = (mi.Float(k // res) + rng.next_float32()) * cell - radius
        origin = center + frame.s * u + frame.t * v - d * (1.01 * radius)
        ray = mi.Ray3f(origin, mi.Vector3f(d))
        in_fwd = dr.zeros(mi.Color3f, table.count)
        in_bwd = dr.zeros(mi.Color3f, table.count)
        delta_area = cell * cell
        active = (u * u + v * v) <= radius * radius

        def body(ray, active, prev, prev_fwd):
            pi = scene.ray_intersect_preliminary(ray, active)
            hit = active & pi.is_valid()
            si = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal, hit)
            tri = table.triangle_index(si.shape, si.prim_index)
            n = dr.gather(mi.Normal3f, table.normal, tri, hit)
            cos_d = dr.dot(n, d)
            exchange = hit & prev_fwd & (cos_d < 0)
            dr.scatter_add(in_fwd, dr.gather(mi.Color3f, L_fwd, prev, exchange) * delta_area, tri, exchange, mode=SPLAT_MODE)
            dr.scatter_add(in_bwd, dr.gather(mi.Color3f, L_bwd, tri, exchange) * delta_area, prev, exchange, mode=SPLAT_MODE)
            ray = si.spawn_ray(mi.Vector3f(d))
            return ray, hit, tri, hit & (cos_d > 0)

        dr.while_loop((ray, active, dr.zeros(mi.UInt32, n_lines), mi.Bool(False)),
                      lambda ray, active, prev, prev_fwd: active, body)
        return in_fwd, in_bwd

    # ------------------------------------------------------------------ image
    def _gather(self, scene, table, paths, d, L_fwd, L_bwd, weight):
        """Per camera sample: reflect the stored radiance arriving at the visible point
        along +d (from the patch seen in direction -d) and along -d toward the eye."""
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
            radiance = dr.gather(mi.Color3f, L, tri, ok)
            f_cos = mi.Color3f(bsdf.eval(ctx, si, wo, ok))
            result += dr.select(ok, f_cos * radiance, 0.0)
        return paths.throughput * result * weight

    def _patch_estimate(self, scene, table, paths, d, in_fwd, in_bwd, weight):
        si = scene.ray_intersect(paths.ray, paths.valid)
        valid = paths.valid & si.is_valid()
        tri = table.triangle_index(si.shape, si.prim_index)
        area = dr.gather(mi.Float, table.area, tri, valid)
        result = mi.Color3f(0.0)
        for sign, incoming in ((1.0, in_fwd), (-1.0, in_bwd)):
            if incoming is None:
                continue
            inc = dr.gather(mi.Color3f, incoming, tri, valid) / dr.maximum(area, 1e-30)
            result += dr.select(valid, self._reflect(si, inc, -d * sign), 0.0)
        return paths.throughput * result * weight

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

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        sensor = resolve_sensor(scene, sensor)
        film = sensor.film()
        size = film.crop_size()
        width, height = int(size[0]), int(size[1])
        n_pix = width * height
        spp = sensor_spp(sensor, spp)
        seed = int(seed)
        table = MeshTable(scene, "ray_bundle")
        self._warn_delta(scene)

        bbox = scene.bbox()
        center = mi.ScalarPoint3f(bbox.center())
        radius = float(dr.norm(bbox.extents())) * 0.5 * 1.001 + 1e-6
        total = self.iterations * spp
        burn_in = self.burn_in
        samples = direction_samples(self.direction_sequence, total + 1, seed)
        dirs = uniform_sphere_directions(samples)
        weight = 2.0 * math.pi if self.bidirectional else 4.0 * math.pi

        rng_lines = mi.PCG32(self.resolution ** 2, initstate=dr.opaque(mi.UInt64, seed * 2654435761 + 7),
                             initseq=mi.UInt64(dr.arange(mi.UInt32, self.resolution ** 2)))
        rng_patch = mi.PCG32(table.count, initstate=dr.opaque(mi.UInt64, seed * 1000003 + 11),
                             initseq=mi.UInt64(dr.arange(mi.UInt32, table.count)))

        d = _opaque_dir(dirs[0])
        si = self._patch_interaction(table, rng_patch, d)
        L_fwd = self._emission(scene, si)
        L_bwd = None
        if self.bidirectional:
            si_b = self._patch_interaction(table, rng_patch, -d)
            L_bwd = self._emission(scene, si_b)
        dr.eval(L_fwd, L_bwd, rng_patch.state)

        accum = dr.zeros(mi.Float, n_pix * 3)
        progress = Progress(self, total, burn_in)
        try:
            for m in progress:
                d = _opaque_dir(dirs[m])
                in_fwd, in_bwd = self._transfer(scene, table, d, L_fwd,
                                                L_bwd if L_bwd is not None else L_fwd, rng_lines, center, radius)
                if not self.bidirectional:
                    in_bwd = None
                new_accum = accum
                if m >= burn_in:
                    # one fresh camera sample per pixel and iteration
                    paths = camera_paths(scene, sensor, 1, seed * 1000081 + m, -1, self.hide_emitters)
                    if self.estimate == "gather":
                        est = self._gather(scene, table, paths, d, L_fwd, L_bwd, weight)
                    else:
                        est = self._patch_estimate(scene, table, paths, d, in_fwd, in_bwd, weight)
                    new_accum = accum + paths.emission_image
                    for c in range(3):
                        dr.scatter_add(new_accum, est[c], paths.pixel * 3 + c)
                # new global direction and reflection into it
                d_new = _opaque_dir(dirs[m + 1])
                new_L = []
                for out in ((d_new, -d_new) if self.bidirectional else (d_new,)):
                    si = self._patch_interaction(table, rng_patch, out)
                    L = self._emission(scene, si)
                    area = dr.maximum(table.area, 1e-30)   # degenerate triangles: never hit, no NaN
                    L += weight * self._reflect(si, in_fwd / area, -d)
                    if in_bwd is not None:
                        L += weight * self._reflect(si, in_bwd / area, d)
                    new_L.append(L)
                L_fwd_new = new_L[0]
                L_bwd_new = new_L[1] if self.bidirectional else None
                dr.eval(L_fwd_new, L_bwd_new, new_accum, rng_lines.state, rng_patch.state)
                L_fwd, L_bwd, accum = L_fwd_new, L_bwd_new, new_accum
        except KeyboardInterrupt:
            progress.stop()  # Ctrl-C: keep the finished iterations
        image = accum / max(progress.averaged, 1)
        return image_to_film(film, mi.TensorXf(image, shape=(height, width, 3)), develop)
