"""Mitsuba 3.9.1: `timed_sunsky` fails in every render of a scene with a surface (`jit_var_schedule(...): not permitted`)

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene: one `rectangle` with a `diffuse` BSDF, a `perspective` camera (8 x 8 px, 4 spp)
and a `timed_sunsky` emitter with default parameters. Integrators `path`, `direct`,
`ptracer`.

Expected: the scene renders, as it does with `sunsky`.

Measured:

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    path     + timed_sunsky: raises RuntimeError: jit_var_schedule(r1737): not permitted.
    path     + sunsky      : renders (image mean 0.1681)
    direct   + timed_sunsky: raises RuntimeError: jit_var_schedule(r4266): not permitted.
    direct   + sunsky      : renders (image mean 0.167)
    ptracer  + timed_sunsky: raises RuntimeError: jit_var_schedule(r1237): not permitted.
    ptracer  + sunsky      : renders (image mean 0.1628)
    path     + timed_sunsky, evaluated mode (no symbolic calls/loops): renders (image mean 0.006855)
    timed_sunsky.sample_direction inside a symbolic dr.while_loop (child interpreter): exit code -6, >>> jit_var(r1314819328): unknown variable!
    (1.6 s)

Every integrator that samples the emitter from a surface point fails inside the recorded
(symbolic) emitter call with `jit_var_schedule(rN): not permitted` ("You performed an
operation that tried to evaluate a *symbolic* variable"). The same scene renders with
`sunsky`, and with `timed_sunsky` once Dr.Jit's symbolic calls and loops are switched off
(`dr.JitFlag.SymbolicCalls`, `dr.JitFlag.SymbolicLoops` = False, evaluated mode). Calling
the emitter's methods directly (outside a recorded scope) works. Calling them inside a
symbolic `dr.while_loop` aborts the whole process instead ("jit_var(r...): unknown
variable!"; the script checks that in a child interpreter).

Cause (located with a debugger, `catch throw`): `BaseSunskyEmitter::sample_direction` ->
`BaseSunskyEmitter::sample_sky` (include/mitsuba/render/sunsky.h) ->
`TimedSunskyEmitter::get_sampling_weights(sun_theta, active)` (src/emitters/timed_sunsky.cpp)
-> `jit_var_any` -> `jitc_var_eval`, which raises. In the 3.9.1 binary,
`get_sampling_weights` compares the per-lane sun elevation with a bound (`jit_var_le`),
ands it with `active`, takes a horizontal reduction of that mask (`dr::any`, the
`jit_var_any` call) and only then evaluates its weight table (`drjit::Texture::eval`).
In `timed_sunsky` the sun position depends on each ray's time, so the mask is symbolic
inside the recorded emitter call, and a horizontal reduction needs its value, which a
symbolic variable does not have. (`sunsky`'s `get_sampling_weights` returns precomputed
weights and makes no such call, which is why it works.)

Suggested fix: use `dr::any_or<true>(...)` (as `sample_sky` does for its own branches) or
drop the early-out in `TimedSunskyEmitter::get_sampling_weights`; the current development
sources compute the sky-sampling weight with a `gather` instead (`get_sky_sampling_weight`),
which would also remove it.

Run: `python docs/findings/timed_sunsky_symbolic_any.py` (about 3 s on 2 cores).
"""
import gc
import subprocess
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")


def scene(integrator, emitter):
    return mi.load_dict({
        "type": "scene", "integrator": {"type": integrator},
        "sensor": {"type": "perspective",
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 3], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse"}},
        "sky": {"type": emitter}})


def attempt(integrator, emitter):
    try:
        image = mi.render(scene(integrator, emitter))
        return "renders (image mean %.4g)" % np.mean(np.array(image))
    except Exception as e:  # noqa: BLE001  (the point is to show the error)
        cause = e.__cause__ or e   # mi.render wraps the integrator's exception
        message = "raises %s: %s" % (type(cause).__name__, str(cause).splitlines()[0])
        del cause  # its traceback references the scene
    # The failed scene survives in a reference cycle and Dr.Jit would trace its emitter in
    # the next render too (see failed_render_poisons_next.py): collect it.
    gc.collect()
    return message


LOOP = """
import mitsuba as mi, drjit as dr
mi.set_variant('llvm_ad_rgb')
em = mi.load_dict({'type': 'timed_sunsky'})
rng = mi.PCG32(64)
u1, u2 = rng.next_float32(), rng.next_float32()
def body(i, acc):
    it = dr.zeros(mi.Interaction3f); it.time = u1
    ds, w = em.sample_direction(it, mi.Point2f(u1, u2))
    return i + 1, acc + w[0]
i, acc = dr.while_loop((mi.UInt32(0), mi.Float(0)), lambda i, a: i < 1, body, mode='symbolic')
dr.eval(acc)
print('symbolic loop OK')
"""


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for integrator in ("path", "direct", "ptracer"):
        for emitter in ("timed_sunsky", "sunsky"):
            print("%-8s + %-12s: %s" % (integrator, emitter, attempt(integrator, emitter)))
    dr.set_flag(dr.JitFlag.SymbolicCalls, False)
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)
    print("path     + timed_sunsky, evaluated mode (no symbolic calls/loops): %s" % attempt("path", "timed_sunsky"))
    dr.set_flag(dr.JitFlag.SymbolicCalls, True)
    dr.set_flag(dr.JitFlag.SymbolicLoops, True)
    out = subprocess.run([sys.executable, "-c", LOOP], capture_output=True, text=True)
    last = [line for line in (out.stdout + out.stderr).splitlines() if line.strip()][-1:]
    print("timed_sunsky.sample_direction inside a symbolic dr.while_loop (child interpreter): exit code %d, %s"
          % (out.returncode, last[0] if last else ""))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
