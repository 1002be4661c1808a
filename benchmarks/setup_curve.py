"""Setup seconds against triangle count: the first render's setup of the finite-element
integrators (the patch table with its clusters, dark splits and gap mouths, and the
smooth display's field) on the ``room`` interior (`interiors.py`) with a 'scanned'
sculpture of 0 to about 1 M more triangles on its table, the scene loaded anew for every
measurement, the setup cache off (what a first render pays) and then on (what a later
process pays for the same scene). Kernels are warmed up on another scene object first;
the kernels that hold a virtual call (over the scene's shapes, emitters, BSDFs) compile
again for every scene object, Mitsuba's own as the package's: that compilation is
measured (Dr.Jit's kernel history) and shown apart, as the interior benchmarks leave it
out of their ratios.

    python3 benchmarks/setup_curve.py [--sizes 0,100,250,500,1000] [--repeats 3] [--write-docs]

Prints one row per size (median of ``--repeats``); ``--write-docs`` puts the table into
docs/interiors.md.
"""
import argparse
import os
import statistics
import sys
import tempfile
import time

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import mi_plugins  # noqa: E402,F401  (registers the plugins)
from mi_plugins.patches import build, setup_cache  # noqa: E402
from mi_plugins.solution import patchfield  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import interior_geometry as ig  # noqa: E402
import interiors  # noqa: E402
from interior_ladder import compile_seconds  # noqa: E402

DOC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "interiors.md")


def scene_with(extra_k):
    """The room with a sculpture of 20 k^2 triangles more (none for k = 0)."""
    d = interiors.scene_dict("room", 64)
    if extra_k:
        path = ig.ply("curve_sculpture", extra_k, lambda: ig.scanned(extra_k, 0.25, (2.7, 2.1, 0.75), seed=5))
        d["sculpture_curve"] = {"type": "ply", "filename": path, "face_normals": True,
                                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.6}}}
    return d


def setup_seconds(d, integrator):
    """(seconds of the patch table, of the smooth field, patch count, triangles, seconds of
    kernel compilation inside them) on a new scene object, as ``integrator`` builds them;
    the table's and the field's seconds leave the compilation out."""
    scene = mi.load_dict(d)
    integ = mi.load_dict({"type": integrator, "display": "smooth"})
    triangles = sum(int(s.face_count()) for s in scene.shapes() if isinstance(s, mi.Mesh))
    build._LAST.clear()
    compile_seconds()
    t0 = time.perf_counter()
    table = integ.patch_table(scene)
    t1 = time.perf_counter()
    c1 = compile_seconds()
    patchfield.field_of(table)
    t2 = time.perf_counter()
    c2 = compile_seconds()
    return t1 - t0 - c1, t2 - t1 - c2, int(table.front_count), triangles, c1 + c2


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="0,100,250,500,1000", help="sculpture sizes, thousands of triangles")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--integrator", default="qmc_lighttrace", choices=("qmc_lighttrace", "ray_bundle"))
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args()
    cache = tempfile.mkdtemp(prefix="mi_plugins_setup_curve_")
    # 20 k^2 triangles per sculpture
    ks = [0 if int(s) == 0 else max(1, int(round((int(s) * 1000 / 20) ** 0.5))) for s in args.sizes.split(",")]
    os.environ[setup_cache.ENV] = "off"
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    setup_seconds(scene_with(0), args.integrator)       # (kernels compiled on another scene object)
    rows = []
    for k in ks:
        d = scene_with(k)
        os.environ[setup_cache.ENV] = "off"
        cold = [setup_seconds(d, args.integrator) for _ in range(args.repeats)]
        os.environ[setup_cache.ENV] = cache
        setup_seconds(d, args.integrator)                 # (fills the cache)
        warm = [setup_seconds(d, args.integrator) for _ in range(args.repeats)]
        table, field = statistics.median(c[0] for c in cold), statistics.median(c[1] for c in cold)
        cached = statistics.median(w[0] + w[1] for w in warm)          # (compilation left out)
        compiled = statistics.median(c[4] for c in cold)
        rows.append((cold[0][3], cold[0][2], table, field, table + field, compiled, cached))
        print("%9d triangles %7d patches: table %.2f s, field %.2f s, setup %.2f s (and %.2f s of compilation); "
              "from the cache %.2f s" % rows[-1], flush=True)
    lines = ["Setup of `%s` (`display='smooth'`) on `room` with a sculpture of more triangles, median of %d, "
             "load average %.1f (`python3 benchmarks/setup_curve.py`):" % (args.integrator, args.repeats,
                                                                           os.getloadavg()[0]), "",
             "| triangles | patches | patch table (s) | field (s) | setup (s) | compilation in it (s) "
             "| setup from the cache (s) |",
             "|---:|---:|---:|---:|---:|---:|---:|"]
    lines += ["| %d | %d | %.2f | %.2f | %.2f | %.2f | %.2f |" % row for row in rows]
    print("\n".join(lines))
    if args.write_docs:
        text = open(DOC).read()
        start, end = "<!-- setup:start -->", "<!-- setup:end -->"
        body = "\n".join(lines)
        if start in text:
            text = text[:text.index(start) + len(start)] + "\n" + body + "\n" + text[text.index(end):]
        else:
            text += "\n## Setup against triangle count\n\n%s\n%s\n%s\n" % (start, body, end)
        with open(DOC, "w") as f:
            f.write(text)


if __name__ == "__main__":
    main()
