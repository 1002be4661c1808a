"""What ``ray_bundle`` refuses, checked before any work (:class:`mi_plugins.base.errors.Unsupported`).

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
and the patches reflect the direct light through them (``first_shot``'s BSDF sample);
with a textured area light that Mitsuba samples wrongly (a ``flip_normals`` rectangle,
a mesh whose uv map does not tile the unit square) they are refused
(:func:`mi_plugins.base.errors.refuse_textured_lights_behind_handoff`).
"""
import warnings

import mitsuba as mi

from mi_plugins.base import errors, queries
from mi_plugins.render import checks

F = mi.BSDFFlags
INSTEAD = "render this scene with Mitsuba's 'path' (or the package's 'stochastic_ray')"


def _has(bsdf, flag):
    return bool(int(bsdf.flags()) & int(flag))


def _subject(bsdf, shape):
    return "the BSDF '%s' of shape '%s'" % (queries.plugin_name(bsdf), shape.id())


def check_scene(plugin, scene, delta_surfaces="refuse"):
    """Raise :class:`Unsupported` for the first shape the bundles cannot carry light
    from or across (see the module docstring); warn for the delta surfaces accepted
    with ``delta_surfaces='camera_only'``."""
    checks.refuse_shapes_without_patches(plugin, scene)
    checks.refuse_one_direction_emitters(plugin, scene)
    delta = []
    for shape, bsdf in queries.bsdfs(scene):
        if _has(bsdf, F.Null):
            raise errors.Unsupported(
                plugin, queries.plugin_name(bsdf), _subject(bsdf, shape),
                "its null lobe lets light pass through the surface, but the bundles' lines stop at every surface "
                "they meet and the direct light's shadow rays are blocked by it", INSTEAD)
        if _has(bsdf, F.DiffuseTransmission | F.GlossyTransmission):
            raise errors.Unsupported(
                plugin, queries.plugin_name(bsdf), _subject(bsdf, shape),
                "it transmits light through the surface, and the bundles' patches receive and reflect on one side "
                "only (light transmitted to the other side would be lost)", INSTEAD)
        if _has(bsdf, F.Delta) and not _has(bsdf, F.Smooth):
            delta.append((shape, bsdf))
    if any(_has(bsdf, F.Delta) for _, bsdf in queries.bsdfs(scene)):
        checks.refuse_textured_lights_behind_handoff(plugin, scene, "the camera through delta lobes")
    if not delta:
        return
    shape, bsdf = delta[0]
    why = ("a purely specular (delta) surface reflects or refracts into one direction, which random global "
           "directions never meet: the light it passes on between surfaces would be missing (the camera still "
           "sees through it)")
    if delta_surfaces == "refuse":
        raise errors.Unsupported(plugin, queries.plugin_name(bsdf), _subject(bsdf, shape), why,
                                  INSTEAD + "; or set delta_surfaces='camera_only' to accept that bias")
    warnings.warn("%s: shape(s) %s have purely delta (mirror/glass) BSDFs: %s. The image misses that "
                  "light (delta_surfaces='camera_only')." % (plugin, ", ".join("'%s'" % s.id() for s, _ in delta),
                                                             why),
                  RuntimeWarning, stacklevel=4)


def check_emitters(plugin, scene, first_shot):
    """Without first_shot the bundles carry the emission of surfaces and of the
    environment: a delta light (point, spot, directional) cannot be carried."""
    if first_shot:
        return
    for emitter in scene.emitters():
        if int(emitter.flags()) & int(mi.EmitterFlags.Delta):
            raise ValueError("%s: emitter '%s' (%s) is a delta light, which the bundles cannot carry "
                             "with first_shot=false; use first_shot=true (its next-event estimation lights "
                             "the patches and the visible points with delta lights)"
                             % (plugin, emitter.id(), str(emitter).split("[", 1)[0].strip()))
