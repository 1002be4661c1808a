"""Coverage rows of narrow gaps: lamps facing a surface across a gap, an object close
above a floor.

A finite-element solution keeps one value per patch; a patch that reaches past the mouth
of a gap (a ceiling patch over the rim of a lamp facing it) mixes the light trapped in
the gap with the open side's (:mod:`mi_plugins.patches.gaps`). ``gap_lamps_<width>``: Mitsuba's
Cornell box (``mi.cornell_box()``, the conformance suite's camera) with three copies of
its lamp (white on its emitting side, as there), each facing a surface across a gap of
one of :data:`WIDTHS`: the box's own turned up under the ceiling (cove lighting; at 1 cm
the scene of the report that found the leak), one facing the back wall and one facing
the floor, both behind the tall block. The mouths are out of the camera's sight: the
image is the room lit through the gaps. The reference is ``ptracer``, which follows the
light out of a gap as it goes (``path`` must find the gaps from the room: heavy-tailed at
these widths). ``gap_object_<width>``: the stage's subject lifted above the floor (every
other row shows it resting on the floor).
"""
import mitsuba as mi

from mi_plugins.verify.conformance.scene_library import mitsuba_cornell
from mi_plugins.verify.coverage.stage import SUBJECT_CENTER, SUBJECT_HALF, stage

#: gap widths of the lamp rows (metres; the Cornell box is 2 wide, its patches 0.14)
WIDTHS = (0.005, 0.02, 0.05, 0.2)
#: ... and of the object rows (the stage's patches: 0.2)
OBJECT_WIDTHS = (0.005, 0.05)
T = mi.ScalarTransform4f


def _label(width):
    return ("%g" % (100 * width)).replace(".", "_") + "cm"


#: the lamps: (shape id, to_world at a gap width (a ``rectangle``: normal +z before it),
#: flip_normals); the ceiling's is the box's own lamp turned up (the user's scene at 1 cm)
LAMPS = (("light", lambda w: T().translate([0, 1 - w, 0.01]).rotate([1, 0, 0], 90).scale([0.23, 0.19, 1]), True),
         ("wall_light", lambda w: T().translate([-0.33, -0.55, -1 + w]).scale([0.15, 0.15, 1]), True),
         ("floor_light", lambda w: T().translate([-0.33, -1 + w, -0.8]).rotate([1, 0, 0], 90).scale([0.15, 0.15, 1]),
          False))


def gap_lamps(width):
    """Mitsuba's Cornell box with three lamps (the box's own, white on their emitting side as
    it is), each facing a surface ``width`` away: the ceiling, the back wall behind the tall
    block, the floor behind the tall block."""
    def build(r):
        d = mitsuba_cornell(r)
        lamp = d.pop("light")
        for name, place, flip in LAMPS:
            d[name] = dict(lamp, to_world=place(width), flip_normals=flip)
        return d
    return build


def gap_object(width):
    def build(r):
        d = stage(r)
        d["subject"]["to_world"] = T().translate([SUBJECT_CENTER[0], SUBJECT_CENTER[1] + width,
                                                  SUBJECT_CENTER[2]]).scale(SUBJECT_HALF)
        return d
    return build


def lamp_row(width):
    """The key of the lamp row of gap ``width``."""
    return "case:gap_lamps_" + _label(width)


def lamp_rows(below=float("inf")):
    """The keys of the lamp rows whose gap is narrower than ``below``."""
    return [lamp_row(w) for w in WIDTHS if w < below]


def gap_rows(Row):
    """The rows (``Row``: the coverage row class): case:gap_lamps_<width>, case:gap_object_<width>."""
    # (twice the matrix's samples: at its default the smooth display's cell of the 0.5 cm
    # row detected 9-12 % over processes, against the 10 % limit)
    rows = [Row(lamp_row(w), None, gap_lamps(w), reference="ptracer", spp_scale=2,
                note="the Cornell box's lamp facing its ceiling, one facing the back wall, one facing the floor, "
                     "each %g cm away" % (100 * w)) for w in WIDTHS]
    rows += [Row("case:gap_object_%s" % _label(w), None, gap_object(w),
                 note="the stage's subject lifted %g cm above the floor" % (100 * w)) for w in OBJECT_WIDTHS]
    return rows
