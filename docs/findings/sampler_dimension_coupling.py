"""Mitsuba 3.9.1: `stratified`, `multijitter` and `ldsampler` couple the dimensions of one sample and bias `path`

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

A sampler may correlate the samples of a pixel with each other (that is stratification),
but the successive numbers of one sample (one path) must be independent. Scene: the
white furnace inside Mitsuba's `cube` (`flip_normals`, `diffuse` albedo 1/2, `area`
emitter 1/2): every pixel is exactly 1 for any unbiased estimator. Integrator `path` with
default settings (`rr_depth` 5), 16 x 16 px.

Expected: 1 for every sampler; and two numbers of one sample, e.g. dimensions 0 and 4,
fall in the same of N strata with probability 1/N. (One `path` bounce makes 4 sampler
calls, emitter 2D, lobe 1D, direction 2D, roulette 1D, so the roulette numbers of
successive bounces are 4 dimensions apart.)

Measured (64 renders per row; +- is the standard error of the mean):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    path + stratified   4 spp: furnace 1.6757 +- 0.0177   expected 1   z = +38.2
    path + stratified  16 spp: furnace 1.0411 +- 0.0019   expected 1   z = +22.1
    path + ldsampler   16 spp: furnace 1.0035 +- 0.0004   expected 1   z = +8.3
    path + ldsampler   64 spp: furnace 1.0042 +- 0.0002   expected 1   z = +24.8
    path + multijitter  4 spp: furnace 0.9966 +- 0.0007   expected 1   z = -5.2
    path + orthogonal   4 spp: furnace 0.9998 +- 0.0009   expected 1   z = -0.3
    path + independent  4 spp: furnace 1.0008 +- 0.0008   expected 1   z = +1.0
    stratified  4 spp: P(dimensions 0 and 4 in the same stratum) = 0.985   expected 0.250
    independent 4 spp: P(dimensions 0 and 4 in the same stratum) = 0.251   expected 0.250
    (9.8 s)

`stratified` at 4 spp reads 1.7 instead of 1 (z > 20), `stratified` at 16 spp and
`ldsampler` at 64 spp are biased high too; `independent` and `orthogonal` are exact.
The dependence is visible in the raw numbers: with `stratified` at 4 spp, the numbers of
dimensions 0 and 4 of a sample fall in the same stratum in 98 % of the samples instead
of 25 %.

Cause (src/samplers/stratified.cpp, multijitter.cpp, ldsampler.cpp; `next_1d`/`next_2d`):
the permutation of each dimension is seeded with `m_permutation_seed + m_dimension_index++`,
i.e. consecutive integers, and Kensler's `permute_kensler` mixes the bits of nearby seeds
weakly for power-of-two sizes: seeds 4 apart give the same permutation in most sequences
at N = 4. The roulette numbers of successive bounces then come from the same strata, so a
path that survives one roulette test survives the next. `multijitter` multiplies the seed
by odd constants (coupled at 4 and 16 spp only); `ldsampler` also derives its shuffle
from `m_scramble_seed + m_dimension_index` and uses one digital scramble for all
dimensions, so it is coupled at every sample count. (A dimension index frozen inside
symbolic loops is not the cause: it is loop state and advances.)

Suggested fix: derive each dimension's seed by hashing (seed, dimension index), e.g.
`sample_tea_32(m_permutation_seed, m_dimension_index)`, and likewise the scramble of
`ldsampler`, instead of adding the index to the seed.

Run: `python docs/findings/sampler_dimension_coupling.py` (about 11 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")


def furnace(sampler, spp, res=16):
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path"},
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": mi.ScalarTransform4f().look_at([0.4, 0.3, 0.8], [-0.6, -0.4, -1.0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": sampler, "sample_count": spp}},
        "walls": {"type": "cube", "flip_normals": True,
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 0.5}}}})


def same_stratum(sampler, spp, pixels=4096):
    """P(dimension 0 and dimension 4 of a sample fall in the same of ``spp`` 1D strata)."""
    s = mi.load_dict({"type": sampler, "sample_count": spp})
    s.seed(0, pixels * spp)
    u = [np.array(s.next_1d()) for _ in range(5)]
    return np.mean(np.floor(u[0] * spp) == np.floor(u[4] * spp))


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for sampler, spp in [("stratified", 4), ("stratified", 16), ("ldsampler", 16), ("ldsampler", 64),
                         ("multijitter", 4), ("orthogonal", 4), ("independent", 4)]:
        scene = furnace(sampler, spp)
        runs = np.array([np.mean(np.array(mi.render(scene, seed=s), dtype=np.float64)) for s in range(64)])
        mean, se = runs.mean(), runs.std(ddof=1) / np.sqrt(len(runs))
        print("path + %-11s %2d spp: furnace %.4f +- %.4f   expected 1   z = %+.1f" % (sampler, spp, mean, se, (mean - 1) / se))
    for sampler, spp in [("stratified", 4), ("independent", 4)]:
        print("%-11s %d spp: P(dimensions 0 and 4 in the same stratum) = %.3f   expected %.3f"
              % (sampler, spp, same_stratum(sampler, spp), 1 / spp))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
