"""How the coverage matrix runs each package integrator, and what every cell must give.

Every cell is expected to PASS unless listed here: REFUSED (the refusal's text must
match: it names the integrator and the feature) or N/A (a documented reason).
"""
from dataclasses import dataclass, field

from mi_plugins.conformance.outcomes import PASS, NotApplicable, Refused


@dataclass
class Spec:
    """``params``: the integrator dict (``max_depth`` is set per row); ``spp`` and
    ``runs``: the budget of a cell (``spp`` times the row's ``spp_scale`` where
    ``scale_spp``); ``row_params`` / ``row_spp``: per-row changes; ``refused``: {row:
    pattern}; ``na``: {row: reason}."""
    name: str
    params: dict
    spp: int
    runs: int = 8
    scale_spp: bool = True
    row_params: dict = field(default_factory=dict)
    row_spp: dict = field(default_factory=dict)
    refused: dict = field(default_factory=dict)
    na: dict = field(default_factory=dict)


STOCHASTIC_RAY = Spec("stochastic_ray", {"type": "stochastic_ray", "iterations": 24, "burn_in": 8}, spp=32)
#: ray_bundle's refusals (mi_plugins.integrators.ray_bundle.checks, support.refuse_media, core's wrapper refusal)
_BUNDLE_DELTA = r"ray_bundle: the BSDF '%s' of shape '\w+' is not supported: a purely specular \(delta\) surface"
_BUNDLE_NULL = r"ray_bundle: the BSDF '%s' of shape '\w+' is not supported: its null lobe lets light pass through"
_BUNDLE_TRANSMITS = r"ray_bundle: the BSDF '%s' of shape '\w+' is not supported: it transmits light through the surface"
_BUNDLE_SHAPE = r"ray_bundle: the shape '%s' \(id '\w+'\) is not supported: the bundles exchange radiance between patches"
_BUNDLE_MEDIUM = r"ray_bundle: the participating medium '\w+' \(id '\w+'\), .* is not supported"
_BUNDLE_REFUSED = dict(
    [("bsdf:" + b, _BUNDLE_DELTA % b) for b in ("conductor", "dielectric")]
    + [("bsdf:" + b, _BUNDLE_NULL % b) for b in ("thindielectric", "null", "mask", "hair", "polarizer", "retarder",
                                                 "circular")]
    + [("bsdf:" + b, _BUNDLE_TRANSMITS % b) for b in ("roughdielectric", "principledthin")]
    + [("shape:" + s, _BUNDLE_SHAPE % s) for s in ("instance", "ellipsoids", "ellipsoidsmesh", "bsplinecurve",
                                                   "linearcurve", "sdfgrid")]
    + [("shape:shapegroup", _BUNDLE_SHAPE % "instance")]
    + [(r, _BUNDLE_MEDIUM) for r in ("medium:homogeneous", "medium:heterogeneous", "phase:isotropic", "phase:hg",
                                     "phase:rayleigh", "phase:sggx", "phase:tabphase", "phase:blendphase",
                                     "volume:gridvolume", "volume:constvolume", "case:camera_in_medium")]
    + [("integrator:" + w, r"ray_bundle: being wrapped by an integrator that calls it once per camera ray")
       for w in ("aov", "moment")])
RAY_BUNDLE = Spec("ray_bundle", {"type": "ray_bundle", "chains": 16, "resolution": 16, "iterations": 12,
                                 "burn_in": 6}, spp=1, scale_spp=False, refused=_BUNDLE_REFUSED,
                  na={"texture:blackbody": "Mitsuba 3.9.1 cannot evaluate 'blackbody' in the RGB variants (its own "
                                           "path raises 'Not implemented for non-spectral modes'): no reference"},
                  # the open scene's planes are 80 units wide: at 16^2 lines the patches (2 x the line spacing)
                  # are 17 units, and the indirect light's patch averages miss the spots' falloff (-4 %); 48^2
                  # lines make them 5.8 units
                  row_params={"case:open_many_emitters": {"resolution": 48}})
QMC_LIGHTTRACE = Spec("qmc_lighttrace", {"type": "qmc_lighttrace", "samples": 20000}, spp=64)

INTEGRATORS = {s.name: s for s in (STOCHASTIC_RAY, RAY_BUNDLE, QMC_LIGHTTRACE)}


def expected(row, integrator):
    """PASS, a :class:`Refused` or a :class:`NotApplicable` for the cell."""
    spec = INTEGRATORS[integrator]
    if row.na is not None:             # no cell of the row can be built here (the row's reason)
        return NotApplicable(row.na)
    if row.key in spec.na:
        return NotApplicable(spec.na[row.key])
    if row.key in spec.refused:
        return Refused(spec.refused[row.key])
    return PASS
