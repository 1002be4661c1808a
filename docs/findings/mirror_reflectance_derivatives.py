"""Mitsuba 3.9.1: PRB-style integrators cannot differentiate an ideal mirror's reflectance (and `prbvolpath` silently returns 0)

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene: the inside of an analytic `sphere` (`flip_normals`) that is an ideal mirror
(`conductor`, `material: none`, `specular_reflectance` k = 1/2) and emits an `area`
radiance Le = 1/2; the camera is inside. Every ray bounces between mirror points that
all emit Le, so with at most D = 6 vertices L = Le (1 + k + ... + k^5) in every pixel and

    dL/dk  = Le * sum_{j<6} j k^(j-1) = 1.78125,     dL/dLe = sum_{j<6} k^j = 1.96875.

Expected: every differentiable integrator returns these derivatives, or refuses clearly.

Measured (4 renders of 8 x 8 px at 16 spp per line; the parameter is moved by a
gradient-enabled Color3f theta added to it in all channels; forward mode:
`dr.forward_to(image)`, reverse mode: `dr.backward(mean(image))`, value = d mean / d theta
summed over channels):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    path              d/dreflectance forward 1.76904 +- 0.01662   expected 1.78125   z = -0.7
    path              d/dreflectance reverse 1.76904 +- 0.01662   expected 1.78125   z = -0.7
    prb               d/dreflectance forward raises Exception: The contribution computed by the differential rendering phase is not attached to the AD graph! Raising an exce
    prb               d/dreflectance reverse raises Exception: The contribution computed by the differential rendering phase is not attached to the AD graph! Raising an exce
    prb_basic         d/dreflectance forward raises RuntimeError: drjit.forward_to(): the argument does not depend on the input variable(s) being differentiated. Raising an exc
    prb_basic         d/dreflectance reverse raises RuntimeError: drjit.backward_from(): the argument does not depend on the input variable(s) being differentiated. Raising an 
    direct_projective d/dreflectance forward raises RuntimeError: drjit.forward_to(): the argument does not depend on the input variable(s) being differentiated. Raising an exc
    direct_projective d/dreflectance reverse 0.00000 +- 0.00000   expected 1.78125   z = +inf
    prbvolpath        d/dreflectance reverse 0.00000 +- 0.00000   expected 1.78125   z = +inf
    prb               d/demission    forward raises RuntimeError: ad_traverse(): tried to forward-propagate derivatives across edge a4 -> a26, which lies outside of the current
    prb               d/demission    reverse 1.96875 +- 0.00000   expected 1.96875   z = +0.0
    prb_basic         d/demission    forward 1.96875 +- 0.00000   expected 1.96875   z = +0.0
    prb_basic         d/demission    reverse 1.96875 +- 0.00000   expected 1.96875   z = +0.0
    (20.3 s)

Dr.Jit's automatic differentiation of `path` is right. For the mirror's reflectance, `prb`
and `prb_basic` raise (the contribution is not attached to the AD graph), `direct_projective`
raises in forward mode, and **`prbvolpath` and `direct_projective` in reverse mode return
exactly 0 without any warning**. Separately, on this all-delta scene `prb` in forward mode
raises a Dr.Jit `isolate_grad` error even for the emission derivative, which it gets right
in reverse mode (and `prb_basic` in both modes).

Cause (python/ad/integrators/prb.py, prb_basic.py, prbvolpath.py, direct_projective.py):
these integrators replay the path and attach the BSDF's derivatives through a
re-evaluation `bsdf.eval(ctx, si, wo)` / `bsdf.eval_pdf(...)` (`prb.py`: "Re-evaluate
BSDF * cos(theta) differentiably", `Lr_ind = L * dr.relative_grad(bsdf_val) * ...`;
`prbvolpath.py`: `Lo = bsdf_eval * detach(L / bsdf_eval)` under
`if dr.grad_enabled(bsdf_eval)`; `direct_projective.py`:
`dr.replace_grad(weight_bsdf, bsdf_val * detach(inv_bsdf_pdf))`). `eval()` of a Dirac lobe
is zero, so the reflectance never enters the AD graph: `prb`/`prb_basic` detect the
detached contribution and raise, `prbvolpath` skips the step and `direct_projective`
replaces the gradient by that of zero, which yields 0. The forward-mode `isolate_grad`
error of `prb` on the emission derivative was not traced to its line.

Suggested fix: for sampled lobes with the Delta flag, attach the derivative through the
sample weight returned by `bsdf.sample()` (which carries the reflectance) instead of
`bsdf.eval()`; at least raise in `prbvolpath`/`direct_projective` instead of returning 0.

Run: `python docs/findings/mirror_reflectance_derivatives.py` (about 20 s on 2 cores: one interpreter per line).
"""
import subprocess
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

K, LE, DEPTH = 0.5, 0.5, 6
KEYS = {"reflectance": ("walls.bsdf.specular_reflectance.value", K,
                        LE * sum(j * K ** (j - 1) for j in range(1, DEPTH))),
        "emission": ("walls.emitter.radiance.value", LE, sum(K ** j for j in range(DEPTH)))}


def mirror_sphere(integrator, res=8):
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": mi.ScalarTransform4f().look_at([0.3, 0.2, 0.4], [-0.5, -0.1, -1.0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "walls": {"type": "sphere", "flip_normals": True,
                  "bsdf": {"type": "conductor", "material": "none",
                           "specular_reflectance": {"type": "rgb", "value": K}},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": LE}}}})


def derivative(integrator, name, mode, runs=4, spp=16):
    key, value, _ = KEYS[name]
    scene = mirror_sphere({"type": integrator, "max_depth": DEPTH})
    params = mi.traverse(scene)
    out = []
    for seed in range(runs):
        theta = dr.zeros(mi.Color3f, 1)
        dr.enable_grad(theta)
        params[key] = mi.Color3f(value) + theta
        params.update()
        image = mi.render(scene, params, spp=spp, seed=seed)
        if mode == "forward":
            dr.set_grad(theta, 1.0)
            out.append(float(np.mean(np.array(dr.forward_to(image)))))
        else:
            dr.backward(dr.mean(image, axis=None))
            out.append(float(np.sum(np.array(dr.grad(theta)))))
    return np.array(out)


def root_cause(e):
    while e.__cause__ is not None:
        e = e.__cause__
    return e


def one_case(integrator, name, mode):
    """Print one line: the derivative, or what the integrator raises."""
    label = "%-17s d/d%-11s %-7s" % (integrator, name, mode)
    expected = KEYS[name][2]
    try:
        v = derivative(integrator, name, mode)
    except Exception as e:  # noqa: BLE001  (the point is to show what each one raises)
        c = root_cause(e)
        print("%s raises %s: %s" % (label, type(c).__name__, str(c).splitlines()[0][:110]))
        return
    mean, se = v.mean(), v.std(ddof=1) / np.sqrt(len(v))
    z = (mean - expected) / se if se > 0 else (0.0 if mean == expected else float("inf"))
    print("%s %.5f +- %.5f   expected %.5f   z = %+.1f" % (label, mean, se, expected, z))


def main():
    # Each case runs in its own interpreter: after the forward-mode isolate_grad error the
    # next AD render in the same process can abort it (jit_var_select(): operands have
    # incompatible sizes).
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    rows = [("path", "reflectance"), ("prb", "reflectance"), ("prb_basic", "reflectance"),
            ("direct_projective", "reflectance"), ("prbvolpath", "reflectance"),
            ("prb", "emission"), ("prb_basic", "emission")]
    for integrator, name in rows:
        for mode in ("forward", "reverse"):
            if integrator == "prbvolpath" and mode == "forward":
                continue  # prbvolpath documents that it has no forward mode (and says so when asked)
            out = subprocess.run([sys.executable, __file__, integrator, name, mode],
                                 capture_output=True, text=True)
            lines = [line for line in out.stdout.splitlines() if line.strip()]
            print(lines[-1] if lines else "%s %s %s: process died (%d): %s"
                  % (integrator, name, mode, out.returncode, out.stderr.strip().splitlines()[-1:]))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    if len(sys.argv) == 4:
        one_case(*sys.argv[1:])
    else:
        main()
