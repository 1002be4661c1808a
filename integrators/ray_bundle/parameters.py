"""The parameters of ``ray_bundle``, documented once (read in :class:`.integrator.RayBundleIntegrator`;
the shared groups are read and documented where they belong)."""
from mi_plugins.base.param_docs import Row
from mi_plugins.patches.build import PATCH_ROWS
from mi_plugins.patches.darkness import DARK_ROWS
from mi_plugins.patches.refinement import REFINE_ROWS
from mi_plugins.render.core import HIDE_EMITTERS, iteration_rows
from mi_plugins.solution.integrator import DISPLAY_ROWS

OWN = (
    Row("resolution", "int", "32", ">= 1 lines per side of the bundle"),
    Row("chains", "int", "64, fewer where 64 would need over a quarter of the available memory",
        ">= 1 chains (own directions, own patch radiances) advanced in lockstep by one kernel per iteration; the "
        "image averages them. 1 is the paper's algorithm"),
    Row("bidirectional", "bool", "true", "use every line in both directions (A(i,j,w) = A(j,i,-w))"),
    Row("first_shot", "bool", "true",
        "direct light by next-event estimation (a light sample, and a BSDF sample where needed, MIS) at patch "
        "points, line hits (``point_sources``) and camera samples; the bundles carry only the reflected radiance "
        "L - Le. Unbiased. false is the paper's algorithm"),
    Row("estimate", "string", "``'gather'``",
        "``'gather'``: at each pixel's visible point, reflect the stored radiance arriving along +-w_m toward "
        "the eye (the paper's per-pixel variant); ``'patch'``: the visible patch's incoming radiance, reflected "
        "toward the eye"),
    Row("direction_sequence", "string", "``'independent'``",
        "``'independent'``, ``'halton'``, ``'hammersley'``, ``'pi'``. Only random directions are correct: "
        "Halton and Hammersley are 1-uniform and bias the result (paper 6.1; kept to reproduce it)"),
    Row("stratify_chains", "bool", "true with ``'independent'``",
        "every iteration the chains' directions form one evenly spread set, freshly rotated and dealt in a "
        "random order: each chain stays independent and uniform. true with another ``direction_sequence`` is "
        "an error"),
    Row("average_diffuse", "bool", "true",
        "final gathering from averaged diffuse patches: every chain's value of a purely diffuse patch in every "
        "averaged iteration estimates one number; their average replaces the chain's value in the image (one "
        "pass per averaged iteration). Unbiased. false is the paper's"),
    Row("share_diffuse", "bool", "true",
        "every iteration a purely diffuse patch side reflects the mean of what every chain's bundle brought it. "
        "Unbiased; without it a patch that few lines meet per chain reads low. false keeps the chains "
        "independent"),
    Row("gather_nee", "bool", "true",
        "with ``first_shot`` and ``average_diffuse``: the direct light of each gathered point by next-event "
        "estimation; false: part of the patch average"),
) + (PATCH_ROWS[0].but(default="scene diagonal / 24; with ``display`` 'gather' at least 2 x the line spacing"),) \
    + PATCH_ROWS[1:] + DARK_ROWS + (
    HIDE_EMITTERS,
    Row("max_depth", "int", "-1",
        "-1 (unbounded) or 0 .. 64, Mitsuba's meaning (1: emission only); the chains keep every bounce order "
        "apart (memory x orders)"),
    Row("delta_surfaces", "string", "``'refuse'``",
        "``'refuse'``: a purely specular surface is refused (the bundles cannot pass light on through it); "
        "``'camera_only'``: render anyway, the camera seeing through it, with a RuntimeWarning naming the shapes"),
    Row("point_sources", "bool", "true",
        "the source term a line carries evaluated where the line leaves the surface (exact where it varies "
        "within a patch); false: the patch's shared running mean (less noise, exact only where the radiance is "
        "constant per patch)"),
) + DISPLAY_ROWS + REFINE_ROWS + (
    Row("adaptive", "bool", "true",
        "after the averaged iterations, predict the average's bias from the chains and, above 1 %, extend the "
        "burn-in by what the prediction asks for (``mi_plugins.render.burn_in``); false: a RuntimeWarning gives "
        "the numbers instead"),
    Row("max_iterations", "int", "8 x ``iterations`` x spp",
        ">= 1: the most iterations the extended burn-in may reach; a render that would need more is refused "
        "(``NotConverged``, naming the iterations it needs)"),
)

#: every row, in the reference's order
_ITERATIONS, _BURN_IN = iteration_rows(16, "global iterations")
ROWS = (_ITERATIONS.but(
    default="16; in the display modes at least 0.25 bundle lines per camera sample of the render",
    meaning=">= 1 global iterations per unit of ``spp``; in the display modes the solve's iterations (its "
            "default grows with the render's camera samples, spp x pixels, where those ask for more than 16, "
            "resolution^2 x chains lines an iteration: more spp then lowers the solve's noise too, and a render "
            "of another budget solves again; a given ``iterations`` keeps one solve for every budget)"),
        _BURN_IN) + OWN
