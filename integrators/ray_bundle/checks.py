"""What ``ray_bundle`` refuses, checked before any work (:class:`mi_plugins.support.Unsupported`).

The bundles carry radiance from patch to patch along random global directions, and a
patch reflects what arrives at it through its BSDF's *smooth* lobes (``bsdf.eval``):

- **null lobes** (``null``, ``mask``, ``thindielectric``'s transmission, ``hair``, the
  RGB variants' ``polarizer``/``retarder``/``circular``): light passes *through* such a
  surface, but every line stops at the first surface it meets and the shadow rays of
  the direct light are blocked by it: refused;
- **purely delta surfaces** (``conductor``, ``dielectric``): a random global direction
  never hits their one reflected or refracted direction, so the light they pass on
  between patches is missing (the camera still sees through them): refused unless
  ``delta_surfaces='camera_only'``, which renders with a RuntimeWarning naming them;
- **transmission lobes** (``roughdielectric``, ``principledthin``): a patch receives and
  sends on one side per lane, so light transmitted to the other side is lost: refused.

Mixed BSDFs with a delta lobe (``plastic``'s specular layer, a ``blendbsdf`` with a
mirror) render: the camera's visible point hands its delta lobes to Mitsuba's ``path``
and the patches reflect the direct light through them (``first_shot``'s BSDF sample).
"""
import warnings

import mitsuba as mi

from mi_plugins import support, tessellation
from mi_plugins.meshtable import _is_mesh

#: Mitsuba class names of BSDFs -> plugin names (support.PLUGIN_OF_CLASS has the common ones)
BSDF_PLUGINS = {"LinearPolarizer": "polarizer", "LinearRetarder": "retarder", "CircularPolarizer": "circular",
                "ThinDielectric": "thindielectric", "SmoothConductor": "conductor", "SmoothDielectric": "dielectric",
                "RoughDielectric": "roughdielectric", "PrincipledThin": "principledthin", "Hair": "hair",
                "SmoothPlastic": "plastic", "Null": "null", "MaskBSDF": "mask"}
#: Mitsuba class names of shapes without patches -> plugin names
SHAPE_PLUGINS = {"Instance": "instance", "Ellipsoids": "ellipsoids", "EllipsoidsMesh": "ellipsoidsmesh",
                 "BSpline": "bsplinecurve", "LinearCurve": "linearcurve", "SDFgrid": "sdfgrid"}
F = mi.BSDFFlags
INSTEAD = "render this scene with Mitsuba's 'path' (or the package's 'stochastic_ray')"


def bsdf_plugin(bsdf):
    name = bsdf.class_name()
    return BSDF_PLUGINS.get(name) or support.PLUGIN_OF_CLASS.get(name, name)


def _has(bsdf, flag):
    return bool(int(bsdf.flags()) & int(flag))


def _subject(bsdf, shape):
    return "the BSDF '%s' of shape '%s'" % (bsdf_plugin(bsdf), shape.id())


def check_shapes(scene):
    """Refuse a shape without patches: the triangle meshes and the analytic rectangle,
    disk, sphere and cylinder have them (mi_plugins.meshtable)."""
    for shape in scene.shapes():
        kind = tessellation.shape_kind(shape)
        if not _is_mesh(shape) and kind not in tessellation.KINDS:
            name = SHAPE_PLUGINS.get(kind, kind.lower())
            raise support.Unsupported(
                "ray_bundle", name, "the shape '%s' (id '%s')" % (name, shape.id()),
                "the bundles exchange radiance between patches, the triangles of meshes and cells of the analytic "
                "rectangle, disk, sphere and cylinder, and this shape has neither", "convert it to a mesh (a "
                "'ply'/'obj' file) or render with Mitsuba's 'path'")


def check_scene(scene, delta_surfaces="refuse"):
    """Raise :class:`Unsupported` for the first shape the bundles cannot carry light
    from or across (see the module docstring); warn for the delta surfaces accepted
    with ``delta_surfaces='camera_only'``."""
    check_shapes(scene)
    delta = []
    for shape, bsdf in support.bsdfs(scene):
        if _has(bsdf, F.Null):
            raise support.Unsupported(
                "ray_bundle", bsdf_plugin(bsdf), _subject(bsdf, shape),
                "its null lobe lets light pass through the surface, but the bundles' lines stop at every surface "
                "they meet and the direct light's shadow rays are blocked by it", INSTEAD)
        if _has(bsdf, F.DiffuseTransmission | F.GlossyTransmission):
            raise support.Unsupported(
                "ray_bundle", bsdf_plugin(bsdf), _subject(bsdf, shape),
                "it transmits light through the surface, and the bundles' patches receive and reflect on one side "
                "only (light transmitted to the other side would be lost)", INSTEAD)
        if _has(bsdf, F.Delta) and not _has(bsdf, F.Smooth):
            delta.append((shape, bsdf))
    if not delta:
        return
    shape, bsdf = delta[0]
    why = ("a purely specular (delta) surface reflects or refracts into one direction, which random global "
           "directions never meet: the light it passes on between surfaces would be missing (the camera still "
           "sees through it)")
    if delta_surfaces == "refuse":
        raise support.Unsupported("ray_bundle", bsdf_plugin(bsdf), _subject(bsdf, shape), why,
                                  INSTEAD + "; or set delta_surfaces='camera_only' to accept that bias")
    warnings.warn("ray_bundle: shape(s) %s have purely delta (mirror/glass) BSDFs: %s. The image misses that "
                  "light (delta_surfaces='camera_only')." % (", ".join("'%s'" % s.id() for s, _ in delta), why),
                  RuntimeWarning, stacklevel=4)


def check_emitters(scene, first_shot):
    """Without first_shot the bundles carry the emission of surfaces and of the
    environment: a delta light (point, spot, directional) cannot be carried."""
    if first_shot:
        return
    for emitter in scene.emitters():
        if int(emitter.flags()) & int(mi.EmitterFlags.Delta):
            raise ValueError("ray_bundle: emitter '%s' (%s) is a delta light, which the bundles cannot carry "
                             "with first_shot=false; use first_shot=true (its next-event estimation lights "
                             "the patches and the visible points with delta lights)"
                             % (emitter.id(), str(emitter).split("[", 1)[0].strip()))
