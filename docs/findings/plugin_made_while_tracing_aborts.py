"""Dr.Jit 1.5.0 / Mitsuba 3.9.1: a BSDF made while a kernel is traced makes LLVM abort the process ("invalid redefinition of function")

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene: a floor `rectangle` and a `cube` lamp whose `area` emitter has a `bitmap`
radiance, both with the same `diffuse` BSDF (one BSDF instance in the process). Two
`BSDF::sample` calls on the floor's interactions are traced into one kernel, and between
them the lamp's `eval_parameterization` is called (as Mitsuba's `area` emitter does when
it samples a textured radiance on a mesh), then the kernel is evaluated.

Expected: the kernel is evaluated (as it is when the parameterization was built first).

Measured:

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    uv scene built while tracing: exit code -6: >>> jit_llvm_compile(): parsing failed. Please see the LLVM IR and error message below: ... drjit_580d6c2fb6e72578fe855be3f6506332:454:24: error: invalid redefinition of function 'fu
    uv scene built before tracing: renders (mean weight 0.500000)
    (0.7 s)

The first process dies: no Python exception, nothing to catch.

Cause: `Mesh::eval_parameterization` builds a uv-space scene on its first call
(`Mesh::build_parameterization`, mitsuba src/render/mesh.cpp), and that scene's mesh gets a
default `diffuse` BSDF: a second BSDF instance appears in Dr.Jit's registry in the middle
of the trace. The first `BSDF::sample` was traced with one instance: Dr.Jit emits it as a
direct call of the callable (`GlobalType::Callable`); the second with two, as an entry of
the indirect call table (`GlobalType::IndirectCallable`). The two have the same body
hash, hence the same function name, and `jitc_call_upload` / the kernel assembly keep them
apart by type (drjit-core, src/call.cpp): the function is written into the module twice,
and LLVM refuses the module; the failure path then aborts. Any plugin created while a
kernel is being traced can set this off, a lazily built one is the easiest way.

Suggested fix: in Dr.Jit, key a callable's definition by its hash alone (one definition
serves both the direct call and the table); in Mitsuba, build the parameterization when
the emitter is attached to the mesh (or with the shape's other acceleration data). Users:
call `shape.eval_parameterization(mi.Point2f(0.5, 0.5))` once, evaluated, for every mesh
carrying a textured area light before rendering (what `mi_plugins` does before any of its
renders).

Run: `python docs/findings/plugin_made_while_tracing_aborts.py` (about 2 s on 2 cores).
"""
import subprocess
import sys
import time

CHILD = r'''
import sys
import numpy as np
import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
T = mi.ScalarTransform4f
texture = mi.Bitmap(np.random.default_rng(0).random((8, 8, 3)).astype(np.float32))
scene = mi.load_dict({
    "type": "scene", "white": {"type": "diffuse", "id": "white"},
    "floor": {"type": "rectangle", "bsdf": {"type": "ref", "id": "white"},
              "to_world": T().rotate([1, 0, 0], -90).scale(4)},
    "lamp": {"type": "cube", "bsdf": {"type": "ref", "id": "white"}, "to_world": T().translate([0, 1, 0]).scale(0.2),
             "emitter": {"type": "area", "radiance": {"type": "bitmap", "bitmap": texture}}}})
lamp = [s for s in scene.shapes() if s.is_mesh() and s.emitter() is not None][0]
if sys.argv[1] == "before":
    dr.eval(lamp.eval_parameterization(mi.Point2f(0.5, 0.5)))
n = 64
ray = mi.Ray3f(mi.Point3f(dr.linspace(mi.Float, -2, 2, n), 3.0, 0.3), mi.Vector3f(0, -1, 0))
si = scene.ray_intersect(ray)
ctx = mi.BSDFContext()
bs1, w1 = si.bsdf().sample(ctx, si, 0.3, mi.Point2f(0.4, 0.6), si.is_valid())   # traced, not evaluated
uv = lamp.eval_parameterization(mi.Point2f(0.5, 0.5))                             # the uv scene, if not built
bs2, w2 = si.bsdf().sample(ctx, si, 0.7, mi.Point2f(0.2, 0.9), si.is_valid())
dr.eval(w1, w2, uv)
print("%.6f" % (0.5 * dr.mean(mi.Color3f(w1).x + mi.Color3f(w2).x, axis=None))[0])
'''


def run(when):
    out = subprocess.run([sys.executable, "-c", CHILD, when], capture_output=True, text=True, timeout=120)
    if out.returncode == 0:
        return "renders (mean weight %s)" % out.stdout.strip()
    error = [line for line in out.stderr.splitlines() if "redefinition" in line or "parsing failed" in line]
    return "exit code %d: %s" % (out.returncode, " ... ".join(e.strip()[:90] for e in error[:2]) or out.stderr[-200:])


if __name__ == "__main__":
    start = time.time()
    print("Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb")
    print("uv scene built while tracing:", run("while"))
    print("uv scene built before tracing:", run("before"))
    print("(%.1f s)" % (time.time() - start))
