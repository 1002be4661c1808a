"""Light sampling for the package's integrators: light rays and next-event estimation.

Mitsuba 3.9.1's ``area`` light samples a spatially varying radiance (a bitmap, a
checkerboard: any texture) in the texture's uv space and maps the sample onto the shape
through its uv parameterization (``Shape.eval_parameterization``). That mapping loses
light in two ways (docs/findings.md): on a mesh whose uv map does not cover the unit
square exactly once (e.g. with seams) the samples that fall outside it, or on a
triangle with the wrong area, are lost or wrongly weighted; and ``rectangle``'s
parameterization ignores ``flip_normals``, so the lit side of a flipped rectangle gets
(almost) no light samples and its dark side gets them. Every estimate below therefore
samples these *textured area lights* uniformly in area on their shape
(``Shape.sample_position``, which honours ``flip_normals``) and uses Mitsuba's own
sampling for every other emitter.

- :func:`sample_emitter_direction` / :func:`pdf_emitter_direction`: next-event
  estimation, the counterparts of ``Scene.sample_emitter_direction`` /
  ``pdf_emitter_direction`` (the emitter chosen as Mitsuba chooses it, its selection
  probability included; the pdf is exactly the density the sampling draws, for MIS).
  Used by ``sampling.direct_light`` (``ray_bundle``, ``qmc_lighttrace``'s diffuse
  continuations) and ``qmc_lighttrace``'s final gathering.
- :func:`sample_light_rays`: an emitter, a ray leaving it and the power it carries, from
  five numbers in [0, 1), for the light tracers (``stochastic_ray``, ``qmc_lighttrace``):
  Mitsuba's ``Emitter.sample_ray`` for delta lights and the package's surface lights;
  for textured area lights a point uniform on the shape and a cosine-distributed
  direction, weighted by the radiance there; for environment and directional lights
  (``envmap``, ``constant``, ``sunsky``, ``directional``) a direction from
  ``sample_direction`` and a point of a disk across the scene's bounding sphere
  perpendicular to it. The latter replaces Mitsuba 3.9.1's own ``envmap`` ray sampling,
  which tilts that disk when the map is rotated (``to_world``): the power of every ray
  is then wrong (docs/findings.md).

Textured area lights are handled one at a time, by direct calls on their own shape: a
vcall over the shapes would trace every shape's ``sample_position``, which raises on
instances and curves (``Shape::sample_position(): not implemented``). The other
emitters' ``sample_ray`` is an evaluated vcall: a symbolic one traces every live
emitter's, and a textured area light's raises for a checkerboard radiance
(``Texture::sample_spectrum(): not implemented``).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base.queries import scene_bounds


def bounding_sphere(scene):
    """(centre, radius) of a sphere around every shape of ``scene``, slightly enlarged
    (from :func:`mi_plugins.patches.meshtable.scene_bounds`: ``scene.bbox()`` misses the meshes
    Mitsuba merges)."""
    lo, hi = scene_bounds(scene)
    center = 0.5 * (lo + hi)
    return mi.Point3f(*(float(c) for c in center)), float(np.linalg.norm(hi - lo)) * 0.5 * 1.001 + 1e-4


def textured_area_lights(scene):
    """[(index, emitter, pmf)] of the scene's textured area lights: Mitsuba's ``area``
    lights whose radiance varies over the surface (``EmitterFlags.SpatiallyVarying``, the
    lights whose own sampling goes through the uv parameterization); ``pmf`` is the
    probability Mitsuba's emitter selection gives them (sampling weight / sum of weights)."""
    emitters = scene.emitters()
    total = sum(float(e.sampling_weight()) for e in emitters)
    return [(i, e, float(e.sampling_weight()) / total) for i, e in enumerate(emitters)
            if e.class_name() == "AreaLight" and mi.has_flag(e.flags(), mi.EmitterFlags.SpatiallyVarying)]


def mitsuba_samples_right(emitter):
    """Whether Mitsuba 3.9.1's own sampling of a textured area light (scalar ``emitter``)
    is right: its shape's uv parameterization maps the unit square onto the surface once,
    with the surface's normals (``sphere``, ``disk``, ``cylinder``; a ``rectangle`` unless
    flipped; a mesh whose uv triangles tile the unit square). Where it is not, what the
    package hands to Mitsuba's integrators (``integrators.handoff``) is wrong too."""
    shape = emitter.get_shape()
    kind = shape.class_name()
    if kind in ("Sphere", "Disk", "Cylinder"):
        return True
    if kind == "Rectangle":
        return not shape.has_flipped_normals()
    params = mi.traverse(shape) if shape.is_mesh() else {}
    if "vertex_texcoords" not in params or dr.width(params["vertex_texcoords"]) == 0:
        return False
    uv = np.array(params["vertex_texcoords"], dtype=np.float64).reshape(-1, 2)
    a, b, c = (uv[corner] for corner in np.array(params["faces"], dtype=np.int64).reshape(-1, 3).T)
    area = 0.5 * np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]).sum()
    if abs(area - 1.0) > 1e-3 or uv.min() < -1e-6 or uv.max() > 1.0 + 1e-6:
        return False
    g = (np.arange(32) + 0.5) / 32            # the uv triangles cover a grid of the square
    u, v = np.meshgrid(g, g)
    return bool(dr.all(shape.eval_parameterization(mi.Point2f(u.ravel(), v.ravel()), active=True).is_valid()))


def _on_shape(emitter, si, sample, active):
    """A direction toward a point uniform in area on ``emitter``'s shape (a scalar
    emitter: direct calls), as (DirectionSample3f, radiance / pdf); the pdf in solid angle,
    without the emitter's selection probability."""
    ps = emitter.get_shape().sample_position(si.time, sample, active)
    d = ps.p - si.p
    dist2 = dr.squared_norm(d)
    dist = dr.sqrt(dist2)
    d = d / dist
    cos = -dr.dot(d, ps.n)
    ok = active & (cos > 0) & (ps.pdf > 0) & (dist2 > 0)
    pdf = dr.select(ok, ps.pdf * dist2 / cos, 0.0)
    it = mi.SurfaceInteraction3f(ps, si.wavelengths)
    it.wi = it.to_local(-d)
    radiance = mi.Color3f(emitter.eval(it, ok))
    ds = mi.DirectionSample3f(ps.p, ps.n, ps.uv, ps.time, pdf, mi.Bool(False), d, dist, mi.EmitterPtr(emitter))
    return ds, dr.select(ok, radiance / pdf, 0.0)


def sample_emitter_direction(scene, si, sample, active=True, test_visibility=True):
    """Next-event estimation from ``si``: (DirectionSample3f, radiance / pdf), as
    ``scene.sample_emitter_direction(si, sample, test_visibility, active)`` returns them
    (the pdf in solid angle with the emitter's selection probability; both zero where the
    sample fails or is occluded), textured area lights sampled uniformly on their shape."""
    lights = textured_area_lights(scene)
    if not lights:
        return scene.sample_emitter_direction(si, sample, test_visibility, active)
    active = mi.Bool(active)
    index, weight, reused = scene.sample_emitter(sample.x, active)
    own = [(active & (index == i), e, pmf) for i, e, pmf in lights]
    theirs = active
    for lanes, _, _ in own:
        theirs = theirs & ~lanes
    ds, spec = scene.sample_emitter_direction(si, sample, test_visibility, theirs)
    spec = mi.Color3f(spec)
    mine = mi.Bool(False)
    for lanes, emitter, pmf in own:
        ds_e, spec_e = _on_shape(emitter, si, mi.Point2f(reused, sample.y), lanes)
        ds_e.pdf = ds_e.pdf * pmf
        ds, spec = dr.select(lanes, ds_e, ds), dr.select(lanes, spec_e * weight, spec)
        mine = mine | lanes
    if test_visibility:
        occluded = scene.ray_test(si.spawn_ray_to(ds.p), mine & (ds.pdf > 0))
        spec = dr.select(occluded, 0.0, spec)
        ds.pdf = dr.select(occluded, 0.0, ds.pdf)
    return ds, spec


def pdf_emitter_direction(scene, si, ds, active=True):
    """The solid-angle density with which :func:`sample_emitter_direction` from ``si``
    draws ``ds`` (e.g. ``mi.DirectionSample3f(scene, hit, si)`` of a BSDF sample's hit),
    the emitter's selection probability included: ``scene.pdf_emitter_direction`` for
    every emitter but the textured area lights."""
    lights = textured_area_lights(scene)
    if not lights:
        return scene.pdf_emitter_direction(si, ds, active)
    active = mi.Bool(active)
    own = [(active & (ds.emitter == mi.EmitterPtr(e)), e, pmf) for _, e, pmf in lights]
    theirs = active
    for lanes, _, _ in own:
        theirs = theirs & ~lanes
    pdf = scene.pdf_emitter_direction(si, ds, theirs)
    for lanes, emitter, pmf in own:
        cos = -dr.dot(ds.d, ds.n)
        ok = lanes & (cos > 0)
        area_pdf = emitter.get_shape().pdf_position(ds, ok)
        pdf = dr.select(lanes, dr.select(ok, area_pdf * dr.square(ds.dist) / cos * pmf, 0.0), pdf)
    return pdf


def _area_light_rays(emitter, position, u_direction, active):
    """Rays of a textured area light (a scalar emitter): a point uniform on the shape, a
    cosine-distributed direction around its normal, the power L pi / pdf (unbiased for
    any radiance)."""
    ps = emitter.get_shape().sample_position(0.0, position, active)
    local = mi.warp.square_to_cosine_hemisphere(u_direction)
    si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
    si.wi = local
    radiance = mi.Color3f(emitter.eval(si, active))
    weight = dr.select(active & (ps.pdf > 0), radiance * dr.pi / ps.pdf, 0.0)
    # spawned off the surface: a ray from the sampled point itself finds the shape again at
    # t ~ 0 (measured: 63 % of the rays of a textured light on a 'sphere'), and the light
    # it carries would be lost
    return si.spawn_ray(mi.Frame3f(ps.n).to_world(local)), weight


def build_parameterizations(scene):
    """Have Mitsuba build now, before any kernel of a render is traced, the uv-space scene
    that ``eval_parameterization`` of a mesh traces (made on its first use: Mitsuba samples
    a textured area light on a mesh through it). Made while a kernel is traced, that scene's
    BSDF joins the BSDFs of every later call in the kernel: the kernel then holds a BSDF
    function both as a direct call (traced before, one BSDF) and in a call table (after,
    two), which Dr.Jit 1.5 writes twice, and LLVM aborts the process ("invalid redefinition
    of function"; docs/findings.md)."""
    for shape in scene.shapes():
        emitter = shape.emitter()
        if shape.is_mesh() and emitter is not None and mi.has_flag(emitter.flags(), mi.EmitterFlags.SpatiallyVarying):
            try:
                dr.eval(shape.eval_parameterization(mi.Point2f(0.5, 0.5)))
            except RuntimeError:        # a mesh without uv: Mitsuba's sampling of it is refused elsewhere
                pass


def has_infinite(scene):
    return any(mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) for e in scene.emitters())


def sample_light_rays(scene, u_emitter, u_position, u_direction, active=True):
    """(ray, power) of light rays: ``u_emitter`` (Float) chooses the emitter,
    ``u_position`` and ``u_direction`` (Point2f) the ray. The power (Color3f) includes the
    probability of the emitter's choice; zero where ``active`` is false."""
    active = mi.Bool(active)
    index, choice_weight, u_reused = scene.sample_emitter(u_emitter, active)
    emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), index, active)
    position = mi.Point2f(u_reused, u_position.y)
    lights = textured_area_lights(scene)
    own = [(active & (index == i), e) for i, e, _ in lights]
    theirs = active
    for lanes, _ in own:
        theirs = theirs & ~lanes
    ray, power = dr.zeros(mi.Ray3f, dr.width(index)), dr.zeros(mi.Color3f, dr.width(index))
    if len(scene.emitters()) == 1 and not lights:
        # one emitter: a direct call, fused into the caller's kernel (a call through the
        # emitter pointers, evaluated as below, splits every light-tracing step into three
        # kernels and their bookkeeping)
        ray, power = scene.emitters()[0].sample_ray(0.0, 0.5, position, u_direction, theirs)
        # (a uniform light's power is then one literal: widened to one value per ray)
        power = mi.Color3f(power) + dr.zeros(mi.Color3f, max(dr.width(u_emitter), dr.width(u_position),
                                                             dr.width(u_direction)))
    elif len(lights) < len(scene.emitters()):
        # an evaluated vcall: it runs only the emitters of its active lanes, where a symbolic
        # one traces the sample_ray of every live emitter, textured area lights of this or
        # any other scene included (measured: no slower on the Cornell box and a scene of
        # seven emitters)
        with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, False):
            ray, power = emitter.sample_ray(0.0, 0.5, position, u_direction, theirs)
        power = mi.Color3f(power)
    for lanes, light in own:
        ray_a, power_a = _area_light_rays(light, position, u_direction, lanes)
        ray, power = dr.select(lanes, ray_a, ray), dr.select(lanes, power_a, power)
    if has_infinite(scene):
        center, r = bounding_sphere(scene)
        it = dr.zeros(mi.Interaction3f)
        it.p = center
        infinite = active & mi.has_flag(emitter.flags(), mi.EmitterFlags.Infinite)
        ds, radiance = emitter.sample_direction(it, u_direction, infinite)
        disk = mi.warp.square_to_uniform_disk_concentric(position)
        origin = center + (ds.d + mi.Frame3f(ds.d).to_world(mi.Vector3f(disk.x, disk.y, 0))) * r
        ray = dr.select(infinite, mi.Ray3f(origin, -ds.d), ray)
        power = dr.select(infinite, radiance * (dr.pi * r * r), power)
    return ray, dr.select(active, mi.Color3f(power * choice_weight), 0.0)
