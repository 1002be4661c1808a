"""The parameters of ``qmc_lighttrace``, documented once (read in
:class:`.integrator.QMCLightTraceIntegrator`; the shared groups are read and documented
where they belong)."""
from mi_plugins.base.param_docs import Row
from mi_plugins.patches.build import PATCH_ROWS
from mi_plugins.patches.darkness import DARK_ROWS
from mi_plugins.patches.refinement import REFINE_ROWS
from mi_plugins.render.core import HIDE_EMITTERS
from mi_plugins.solution.integrator import DISPLAY_ROWS

ROWS = (
    Row("max_depth", "int", "-1",
        "Mitsuba's: -1 unbounded, D >= 0 paths of at most D segments (1: emission only). A finite D keeps "
        "max(D - 2, 1) deposit layers: D x patches is limited by memory"),
    Row("sequence", "string", "``'sobol'``",
        "``'sobol'``, ``'halton'``, ``'faure'``, ``'lcg'`` (drand48), ``'independent'`` (PCG32)"),
    Row("scramble", "bool", "true",
        "randomise the sequence with the scramble of ``mi_plugins.base.sequences`` (the render seed selects "
        "it); false: the plain sequence (and a fixed stream beyond it)"),
    Row("sequence_depth", "int", "3",
        "Keller's M >= 0: bounces drawn from the sequence (4 + 3M dimensions must fit: Halton/Faure M <= 84); "
        "later bounces play Russian roulette (survival: the bounce's largest weight, at most 0.99). No "
        "truncation"),
    Row("samples", "int", "100000 (``display`` 'gather'); in the display modes 64 per patch, at least 100000, "
        "and at least 0.25 per camera sample of the render",
        "N paths, 1 .. 2^32 (when ``epsilon`` is not given). The display modes read the stored light of the "
        "patches themselves: their default follows the patch count, and grows with the render's camera samples "
        "(spp x pixels) where those ask for more, so that more spp lowers the solve's noise too (a render of "
        "another budget then solves again; a given ``samples`` keeps one solve for every budget)"),
    Row("epsilon", "float", "none", "> 0: adaptive termination threshold on Delta E"),
    Row("batch", "int", "1000", "Delta N, 1 .. 2^32"),
    Row("patience", "int", "2", "T >= 1 consecutive batches below ``epsilon``"),
    Row("max_samples", "int", "10^7", "1 .. 2^32, cap for the adaptive termination"),
    Row("gather_samples", "int", "4 (``display`` 'gather'), 1 (the display modes)",
        "SR gather samples per eye ray, 1 .. 1024; the display modes gather only where they do not read the "
        "solution (glossy points, gap mouths, crowded patches), at every camera sample"),
    Row("share_neighbors", "bool", "false",
        "average the gather samples' results with the 8 neighbouring pixels seeing the same side of the same "
        "diffuse patch (a smoothing bias)"),
    Row("mirror_depth", "int", "-1",
        "-1: follow delta and null lobes as far as ``max_depth`` allows; k >= 0: at most k of them per eye ray "
        "and per gather sample (truncates: darker than ``path``)"),
) + PATCH_ROWS + DARK_ROWS + DISPLAY_ROWS + REFINE_ROWS + (HIDE_EMITTERS,)
