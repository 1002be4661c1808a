"""Mitsuba 3.9.1: `roughdielectric.sample` gives a positive pdf to samples it weighs 0, where eval() is the other lobe's

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

A `roughdielectric` (Beckmann, alpha 0.2, int_ior 1.5) in `Importance` mode (as a light
tracer samples it), light arriving at cos_i from outside (cos_i > 0) or from inside the
glass (cos_i < 0; the critical angle is at |cos_i| = 0.745); 2^20 samples per angle.

Expected: `BSDFSample.pdf` is the density of the drawn direction and `pdf()` at that
direction returns the same value; the drawn directions follow that density (Mitsuba's chi2
test, `mitsuba.chi2.ChiSquareTest`, 128 x 64 cells); E[weight], E[eval / pdf()] and
E[eval / bs.pdf] all equal the albedo (eval integrated over the sphere by a 1024 x 2048
midpoint rule in (cos theta, phi), converged to 1e-6).

Measured (+- is the standard error; "other lobe's side": a reflection whose direction
crossed the surface, or a refraction that stayed on the side it came from):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    cos_i +0.90 (outside): 0.000 % of the samples (0) lie on the other lobe's side: none of weight 0, eval() > 0 at none; bs.pdf != pdf() on 0.000 % (0), none on the other side
       chi2 against pdf(): samples of weight != 0 accepted (p = 0.56); all samples accepted (p = 0.56); histogram 1.0000, pdf() 1.0000
       albedo 1.00000; E[weight] 1.00000 +- 0.00000 (z +0.6); E[eval / pdf()] 1.00000 (+0.00 %); E[eval / bs.pdf] 1.00000 +- 0.00000 (+0.0 %, z +0.5); weight != 0 only: 1.00000
    cos_i +0.50 (outside): 0.430 % of the samples (4513) lie on the other lobe's side: all of weight 0, eval() > 0 at none; bs.pdf != pdf() on 0.430 % (4513), all on the other side
       chi2 against pdf(): samples of weight != 0 accepted (p = 0.94); all samples rejected (p = 0, samples where pdf() is 0); histogram 1.0000, pdf() 0.9956
       albedo 0.99275; E[weight] 0.99291 +- 0.00007 (z +2.2); E[eval / pdf()] 0.99291 (+0.02 %); E[eval / bs.pdf] 0.99291 +- 0.00007 (+0.0 %, z +2.2); weight != 0 only: 0.99291
    cos_i -0.90 (inside, below the critical angle): 0.000 % of the samples (5) lie on the other lobe's side: all of weight 0, eval() > 0 at none; bs.pdf != pdf() on 0.000 % (5), all on the other side
       chi2 against pdf(): samples of weight != 0 accepted (p = 0.98); all samples rejected (p = 0.95, samples where pdf() is 0); histogram 1.0000, pdf() 1.0000
       albedo 0.99997; E[weight] 0.99996 +- 0.00000 (z -1.0); E[eval / pdf()] 0.99996 (-0.00 %); E[eval / bs.pdf] 0.99996 +- 0.00000 (-0.0 %, z -1.0); weight != 0 only: 0.99996
    cos_i -0.70 (inside, beyond the critical angle): 0.206 % of the samples (2164) lie on the other lobe's side: all of weight 0, eval() > 0 at all; bs.pdf != pdf() on 0.206 % (2163), all on the other side
       chi2 against pdf(): samples of weight != 0 accepted (p = 0.45); all samples rejected (p = 0); histogram 1.0000, pdf() 0.9979
       albedo 0.98726; E[weight] 0.98731 +- 0.00007 (z +0.7); E[eval / pdf()] 0.98819 (+0.09 %); E[eval / bs.pdf] 1.20802 +- 0.03930 (+22.4 %, z +5.6); weight != 0 only: 0.98731
    cos_i -0.50 (inside, beyond the critical angle): 2.090 % of the samples (21912) lie on the other lobe's side: all of weight 0, eval() > 0 at all; bs.pdf != pdf() on 2.090 % (21911), all on the other side
       chi2 against pdf(): samples of weight != 0 accepted (p = 0.88); all samples rejected (p = 0); histogram 1.0000, pdf() 0.9790
       albedo 0.96448; E[weight] 0.96450 +- 0.00016 (z +0.1); E[eval / pdf()] 0.97802 (+1.40 %); E[eval / bs.pdf] 1.11185 +- 0.01648 (+15.3 %, z +8.9); weight != 0 only: 0.96450
    cos_i -0.40 (inside, beyond the critical angle): 2.944 % of the samples (30869) lie on the other lobe's side: all of weight 0, eval() > 0 at 30595 of 30869; bs.pdf != pdf() on 2.944 % (30869), all on the other side
       chi2 against pdf(): samples of weight != 0 accepted (p = 0.80); all samples rejected (p = 0, samples where pdf() is 0); histogram 1.0000, pdf() 0.9707
       albedo 0.94798; E[weight] 0.94789 +- 0.00019 (z -0.4); E[eval / pdf()] 0.96628 (+1.93 %); E[eval / bs.pdf] 1.26578 +- 0.02472 (+33.5 %, z +12.9); weight != 0 only: 0.94789
    Radiance mode, cos_i -0.50: bs.pdf != pdf() on 2.090 % of the samples, all of weight 0; E[eval / bs.pdf] / E[weight] = 1.1548
    (2.7 s)

Outside the glass and inside below the critical angle every estimator agrees (from
outside, 0.4 % of the samples at cos_i 0.5 cross the surface, but eval() is 0 there).
Inside beyond the critical angle 0.2-2.9 % of the samples lie on the other lobe's side:
every one has weight 0, `bs.pdf` disagrees with `pdf()` on exactly these, and eval() is
positive there (a legitimate transmission direction). The directions of the samples of
non-zero weight follow `pdf()` (accepted); all the directions do not (rejected: they hold
1 - the integral of pdf() more). So a light tracer that weighs a bounce by eval / bs.pdf
is 15-34 % too bright per bounce there, with a heavy tail (`bs.pdf` is the density of the
reflection that drew the direction, often tiny); eval / pdf() is 0.1-1.9 % too bright
(it counts the samples of weight 0 too). Mitsuba's weight, and eval / bs.pdf over the
samples of non-zero weight, are right. The Radiance mode does the same. Mitsuba's own
integrators multiply by the weight (and use `bs.pdf` only in MIS weights, where a sample
of weight 0 contributes nothing), and Mitsuba's chi2 `BSDFAdapter` drops samples of
weight 0, so its tests do not see it.

Cause (src/bsdfs/roughdielectric.cpp, `RoughDielectricBSDF::sample`): the direction is
reflected or refracted about the sampled microfacet normal m, which can take it across
the macrosurface (cos_theta_i * cos_theta_o of the wrong sign for the lobe drawn). The
sample stays active: only its weight becomes 0 (through `distr.smith_g1(bs.wo, m)`,
include/mitsuba/render/microfacet.h, zero when wo and m disagree on the side), while
`bs.pdf` (the chosen lobe's density: F or 1 - F times the visible-normal density times
the Jacobian) and `sampled_type` are returned unchanged. `eval()` and `pdf()` decide the
lobe from the hemisphere (`reflect = cos_theta_i * cos_theta_o > 0`) and return the
other lobe's value and density at such a direction; `pdf()` also filters the side
disagreement (its "micro/macro-surface don't agree on the side" test), so it is the
density of the samples of non-zero weight only.

A separate, smaller effect (the angles above are not affected): at |cos_i| < 0.31 (alpha
0.2) `pdf()` and `bs.pdf` use Walter's rational approximation of Beckmann's Smith G1 in
the visible-normal density (`MicrofacetDistribution::smith_g1`, exactly 1 for a >= 1.6)
while the visible normals are sampled exactly, so pdf() and bs.pdf are G1_approx /
G1_exact times the samples' density, and the weight the inverse times right (pdf() too
high by -0.28 % at |cos_i| 0.1, +0.30 % at 0.25, +0.21 % at 0.3, matching the ratio).

Suggested fix: in `sample()`, deactivate a sample whose direction lies on the other
lobe's side (`active &= dr::dot(bs.wo, m) * Frame3f::cos_theta(bs.wo) > 0` before
returning), so that it comes back with `bs.pdf = 0`, as `pdf()`'s side test already has
it; or document that a sample of weight 0 is no sample and its `pdf` no density.

Run: `python docs/findings/roughdielectric_sample_pdf.py` (about 3 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np
from mitsuba.chi2 import ChiSquareTest, SphericalDomain

mi.set_variant("llvm_ad_rgb")

N = 1 << 20
BSDF = mi.load_dict({"type": "roughdielectric", "int_ior": 1.5, "alpha": 0.2})
IMPORTANCE = mi.BSDFContext(mi.TransportMode.Importance)


def interaction(cos_i, n):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(float(np.sqrt(1 - cos_i * cos_i)), 0.0, float(cos_i))
    return si


def sphere_grid(nz):
    """Midpoints of an nz x 2nz grid in (cos theta, phi), and the solid angle of a cell."""
    z = (np.arange(nz) + 0.5) / nz * 2 - 1
    phi = (np.arange(2 * nz) + 0.5) / (2 * nz) * 2 * np.pi
    z, phi = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - z * z)
    d = mi.Vector3f(*[np.ravel(c).astype(np.float32) for c in (s * np.cos(phi), s * np.sin(phi), z)])
    return d, 4 * np.pi / (2 * nz * nz)


GRID, CELL = sphere_grid(1024)


def draw(ctx, cos_i):
    si = interaction(cos_i, N)
    rng = mi.PCG32(N, dr.arange(mi.UInt64, N))
    bs, w = BSDF.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()))
    f = np.array(mi.Color3f(BSDF.eval(ctx, si, bs.wo)).x, dtype=np.float64)
    p = np.array(BSDF.pdf(ctx, si, bs.wo), dtype=np.float64)
    bp = np.array(bs.pdf, dtype=np.float64)
    w = np.array(mi.Color3f(w).x, dtype=np.float64)
    reflected = np.array(mi.has_flag(bs.sampled_type, mi.BSDFFlags.Reflection))
    other_side = reflected != (cos_i * np.array(bs.wo.z) > 0)
    return f, p, bp, w, other_side & (bp > 0)


def chi2(cos_i, all_samples):
    def sample(u):
        bs, w = BSDF.sample(IMPORTANCE, interaction(cos_i, dr.width(u)), u[0], mi.Point2f(u[1], u[2]))
        keep = (bs.pdf > 0) & (all_samples | dr.any(mi.Color3f(w) != 0))
        return bs.wo, dr.select(keep, 1.0, 0.0)

    def density(wo):
        return BSDF.pdf(IMPORTANCE, interaction(cos_i, dr.width(wo)), wo)

    test = ChiSquareTest(SphericalDomain(), sample, density, sample_dim=3, sample_count=N, res=64, ires=16)
    ok = test.run(0.01, quiet=True)
    note = ", samples where pdf() is 0" if "expected frequency 0" in test.messages else ""
    p_value = float(test.p_value)
    verdict = "accepted (p = %.2f)" % p_value if ok else "rejected (p = %.2g%s)" % (p_value, note)
    return verdict, float(test.histogram_sum[0]), float(test.pdf_sum[0])


def share(mask):
    """'all', 'none' or 'k of n' of a boolean array."""
    k, n = int(mask.sum()), mask.size
    return "none" if k == 0 else "all" if k == n else "%d of %d" % (k, n)


def mean_se(x):
    return x.mean(), x.std() / np.sqrt(len(x))


def main():
    t0 = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for cos_i in (0.9, 0.5, -0.9, -0.7, -0.5, -0.4):
        where = "outside" if cos_i > 0 else "inside, %s the critical angle" % ("below" if cos_i < -0.745 else "beyond")
        f, p, bp, w, other_side = draw(IMPORTANCE, cos_i)
        differ = (bp > 0) & (np.abs(bp - p) > 1e-3 * np.maximum(bp, p))
        print("cos_i %+.2f (%s): %.3f %% of the samples (%d) lie on the other lobe's side: %s of weight 0, eval() > 0 "
              "at %s; bs.pdf != pdf() on %.3f %% (%d), %s on the other side"
              % (cos_i, where, 100 * other_side.mean(), other_side.sum(), share(w[other_side] == 0),
                 share(f[other_side] > 0), 100 * differ.mean(), differ.sum(), share(other_side[differ])))
        nonzero = chi2(cos_i, False)[0]
        every = chi2(cos_i, True)
        print("   chi2 against pdf(): samples of weight != 0 %s; all samples %s; histogram %.4f, pdf() %.4f"
              % (nonzero, every[0], every[1], every[2]))
        si = interaction(cos_i, dr.width(GRID))
        albedo = float(np.array(mi.Color3f(BSDF.eval(IMPORTANCE, si, GRID)).x, dtype=np.float64).sum() * CELL)
        by_weight = mean_se(w)
        by_pdf = np.where(p > 0, f / np.where(p > 0, p, 1), 0).mean()
        by_bs = mean_se(np.where(bp > 0, f / np.where(bp > 0, bp, 1), 0))
        kept = np.where((bp > 0) & (w != 0), f / np.where(bp > 0, bp, 1), 0).mean()
        z = lambda m_se: (m_se[0] - albedo) / max(m_se[1], 1e-12)
        print("   albedo %.5f; E[weight] %.5f +- %.5f (z %+.1f); E[eval / pdf()] %.5f (%+.2f %%); "
              "E[eval / bs.pdf] %.5f +- %.5f (%+.1f %%, z %+.1f); weight != 0 only: %.5f"
              % (albedo, *by_weight, z(by_weight), by_pdf, 100 * (by_pdf / albedo - 1), *by_bs,
                 100 * (by_bs[0] / albedo - 1), z(by_bs), kept))
    f, p, bp, w, _ = draw(mi.BSDFContext(mi.TransportMode.Radiance), -0.5)
    differ = (bp > 0) & (np.abs(bp - p) > 1e-3 * np.maximum(bp, p))
    print("Radiance mode, cos_i -0.50: bs.pdf != pdf() on %.3f %% of the samples, %s of weight 0; "
          "E[eval / bs.pdf] / E[weight] = %.4f" % (100 * differ.mean(), share(w[differ] == 0),
                                                  np.where(bp > 0, f / np.where(bp > 0, bp, 1), 0).mean() / w.mean()))
    print("(%.1f s)" % (time.time() - t0))


if __name__ == "__main__":
    main()
