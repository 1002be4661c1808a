"""Are a sampler's dimensions independent? The check behind the stratified-sampler finding.

A sampler for Monte Carlo rendering must give every drawn number the uniform
distribution and, within one sample (one path), numbers that are *jointly* uniform:
the estimator is unbiased only if the integrand's dimensions are sampled from their
product density. Stratification may couple the samples of one pixel with each other, but
never two dimensions of the same sample.

:func:`pair_dependence` draws the numbers of one sample the way Mitsuba's ``path``
integrator does (a 2D pixel sample, then per bounce: 2D emitter sample, 1D lobe choice,
2D direction, 1D Russian roulette), in a symbolic loop like the integrator's, over many
pixels, and tests for every pair of drawn 1D coordinates (a, b) whether
P(u_a < q and u_b < q) = q^2: the event "both Russian-roulette tests survive" of a path.
The z-scores use the binomial standard error over *pixels* (the samples of one pixel
are deliberately dependent; different pixels are independent), so |z| > 4.5 is a
dependence, not chance (false-alarm rate per pair ~7e-6).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

#: the calls of one `path` bounce: emitter sample, BSDF lobe, BSDF direction, roulette
BOUNCE = ("2d", "1d", "2d", "1d")


def draw_path_numbers(sampler, spp, bounces=4, pixels=4096, seed=0):
    """(pixels, spp, k) numpy array of the 1D coordinates a `path` sample draws: pixel
    sample (2), then ``bounces`` x (2 + 1 + 2 + 1), drawn in a ``dr.while_loop`` over the
    bounces with the sampler as loop state (as Mitsuba's integrators do)."""
    s = mi.load_dict(dict(sampler, sample_count=spp)) if isinstance(sampler, dict) else sampler
    spp = int(s.sample_count())
    width = pixels * spp
    s.set_samples_per_wavefront(spp)
    s.seed(seed, width)
    per_bounce = sum(2 if c == "2d" else 1 for c in BOUNCE)
    k = 2 + bounces * per_bounce
    out = dr.zeros(mi.Float, width * k)
    lane = dr.arange(mi.UInt32, width) * k
    first = s.next_2d()
    dr.scatter(out, first.x, lane)
    dr.scatter(out, first.y, lane + 1)

    def body(bounce, sampler):
        col = 2 + bounce * per_bounce
        for call in BOUNCE:
            if call == "2d":
                p = sampler.next_2d()
                dr.scatter(out, p.x, lane + col)
                dr.scatter(out, p.y, lane + col + 1)
                col += 2
            else:
                dr.scatter(out, sampler.next_1d(), lane + col)
                col += 1
        return bounce + 1, sampler

    dr.while_loop((mi.UInt32(0), s), lambda bounce, _: bounce < bounces, body)
    return out.numpy().reshape(pixels, spp, k)


def pair_dependence(sampler, spp, q=0.5, bounces=4, pixels=4096, seed=0):
    """z-scores (k x k, NaN on the diagonal) of P(u_a < q, u_b < q) - q^2 for every pair
    of coordinates of one `path` sample; and the frequencies. Returns (z, freq)."""
    u = draw_path_numbers(sampler, spp, bounces, pixels, seed)
    below = (u < q).astype(np.float64)                      # (pixels, spp, k)
    joint = np.einsum("psa,psb->pab", below, below) / u.shape[1]   # per pixel: fraction of samples
    freq = joint.mean(0)
    se = joint.std(0, ddof=1) / np.sqrt(u.shape[0])
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (freq - q * q) / se
    np.fill_diagonal(z, np.nan)
    return z, freq


def max_dependence(sampler, spp, **kw):
    """(max |z|, (a, b), frequency) over the pairs of :func:`pair_dependence`."""
    z, freq = pair_dependence(sampler, spp, **kw)
    a, b = np.unravel_index(np.nanargmax(np.abs(z)), z.shape)
    return float(abs(z[a, b])), (int(a), int(b)), float(freq[a, b])
