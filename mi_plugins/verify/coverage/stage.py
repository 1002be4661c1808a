"""The small scene every coverage row varies: a stage that one Mitsuba feature is put on.

An open stage (no ceiling, no front wall): a diffuse floor and back wall (triangle
meshes of 4 x 4 cells), a subject in the middle (Mitsuba's ``cube``, diffuse), a square
area light above it facing down (out of the frame) and a perspective camera in front,
``resolution`` x ``resolution`` pixels with a box filter and the ``independent``
sampler. Light leaves the stage after a few bounces, so references converge fast; the
floor and wall exchange light with the subject, so a feature that is transported wrongly
changes the image. A row replaces one part (:func:`stage` keywords) or edits the dict.
"""
import mitsuba as mi

from mi_plugins.verify.conformance.meshes import area, diffuse, quad, shape

ALBEDO = 0.5
#: subject: a unit cube scaled to half-size 0.35, resting on the floor
SUBJECT_CENTER = (0.0, 0.35, 0.0)
SUBJECT_HALF = 0.35


def look_at(origin, target, up=(0, 1, 0)):
    return mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=list(up))


def film(resolution, **kw):
    d = {"type": "hdrfilm", "width": int(resolution), "height": int(resolution), "pixel_format": "rgb",
         "rfilter": {"type": "box"}}
    d.update(kw)
    return d


def camera(resolution, kind="perspective", **kw):
    d = {"type": kind, "to_world": look_at((0.0, 1.3, 3.4), (0.0, 0.35, 0.0)),
         "sampler": {"type": "independent", "sample_count": 4}, "film": film(resolution)}
    if kind in ("perspective", "thinlens"):
        d.update(fov=40.0, fov_axis="x")
    d.update(kw)
    return d


def subject_transform():
    return mi.ScalarTransform4f().translate(list(SUBJECT_CENTER)).scale(SUBJECT_HALF)


def light(radiance=6.0, size=0.35, height=2.2):
    """The stage light: a square quad mesh facing down."""
    return shape(quad((0.0, height, 0.2), (size, 0, 0), (0, 0, size)), "stage_light_%g_%g" % (size, height),
                 diffuse(0.0), area(radiance))


def stage(resolution=16, subject=None, subject_bsdf=None, emitter=None, sensor=None, floor_bsdf=None):
    """The stage dict (see the module docstring). ``subject``: a shape dict replacing the
    cube (None: the diffuse cube; False: no subject); ``subject_bsdf``: the cube's BSDF;
    ``emitter``: a dict replacing the light (an emitter plugin, or a shape with an
    emitter); ``sensor``: a sensor dict; ``floor_bsdf``: the floor's BSDF."""
    d = {"type": "scene", "sensor": sensor or camera(resolution),
         "floor": shape(quad((0, 0, 0), (1.5, 0, 0), (0, 0, -1.5), 4), "stage_floor", floor_bsdf or diffuse(ALBEDO)),
         "wall": shape(quad((0, 1.0, -1.5), (1.5, 0, 0), (0, 1.0, 0), 4), "stage_wall", diffuse((0.6, 0.5, 0.4))),
         "light": emitter if emitter is not None else light()}
    if subject is None:
        subject = {"type": "cube", "to_world": subject_transform(), "bsdf": subject_bsdf or diffuse(ALBEDO)}
    if subject is not False:
        d["subject"] = subject
    return d
