"""The analytic-scenes paper's "simulated" normalization of the separable BSDF is biased (Jensen's inequality)

Not a Mitsuba bug: a finding about the lightsource-testing method that our package
implements (the `separable` BSDF, `normalization='simulated'`). This reproducer needs
only numpy; it computes the bias of one scattering exactly as the BSDF does.

The separable BSDF (paper, eq. 9) for a surface with emission Le(w) and target radiance
L~ > max Le is

    f(w', w) = (L~ - Le(w)) (L~ - Le(w')) / (L~ D),   D = pi L~ - integral Le(w) cos dw,

and gives radiance L~ everywhere in a closed scene. The paper estimates the integral in D
with M random directions per evaluation ("simulated"): D_M = pi L~ - (2 pi / M) sum
Le(w_i) cos(w_i), w_i uniform on the hemisphere. D_M is unbiased, but f uses 1/D_M, and
E[1/D_M] > 1/E[D_M] (Jensen), so every scattering is scaled by E[D / D_M] > 1.

Setting: Le(w) = 1.5 cos^3 (so Le cos = 1.5 cos^4), L~ = 3, M = 16 (cos of a uniform
hemisphere direction is uniform on [0, 1]). Exact: D = 3 pi - 1.5 * 2 pi / 5 = 2.4 pi.

Expected (unbiased method): E[D / D_M] = 1 per scattering.

Measured (2^22 evaluations of D_M; delta-method prediction 1 + Var(D_M) / D^2):

    numpy 2.4.6
    E[D / D_M] per scattering: 1.00735 +- 0.00004   unbiased: 1   z = +170.3   delta-method prediction 1.00694
    after 6 scatterings: x 1.0449
    (3.0 s)

Each scattering is weighted 0.7 % too high, so a radiance made of k bounces is about
(1.007)^k too high; in the package's test (Le = 0.8 cos^2 on a sphere, L~ = 1, M = 16)
the image reads 1.040 instead of 1.

Cause (the paper's estimator; our `bsdfs/separable.py`, `_denominator` with
`normalization='simulated'`): an unbiased estimate of D in the denominator is a biased
estimate of 1/D; the bias is about Var(D_M) / D^2, i.e. O(1/M).

Suggested fix: use the exact integral (`normalization='exact'`, the package's default), or
an unbiased estimator of 1/D (e.g. a Russian-roulette series with independent samples);
a larger M only shrinks the bias as 1/M.

Run: `python docs/findings/simulated_normalization_jensen.py` (about 3 s).
"""
import time

import numpy as np

L_TARGET, SCALE, M = 3.0, 1.5, 16


def main():
    start = time.time()
    rng = np.random.default_rng(1)
    n = 1 << 22
    exact_d = np.pi * L_TARGET - SCALE * 2 * np.pi / 5
    ratios = np.empty(n)
    chunk = 1 << 20
    for i in range(0, n, chunk):
        c = rng.random((chunk, M))                      # cos(theta) of uniform hemisphere directions
        estimate = 2 * np.pi * np.mean(SCALE * c ** 4, axis=1)
        ratios[i:i + chunk] = exact_d / (np.pi * L_TARGET - estimate)
    mean, se = ratios.mean(), ratios.std() / np.sqrt(n)
    var_c4 = 1 / 9 - 1 / 25                              # Var(cos^4), cos uniform on [0, 1]
    predicted = 1 + (2 * np.pi * SCALE) ** 2 * var_c4 / M / exact_d ** 2
    print("numpy %s" % np.__version__)
    print("E[D / D_M] per scattering: %.5f +- %.5f   unbiased: 1   z = %+.1f   delta-method prediction %.5f"
          % (mean, se, (mean - 1) / se, predicted))
    print("after 6 scatterings: x %.4f" % mean ** 6)
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
