"""Command line interface: ``mi-plugins verify``, ``render``, ``demo`` and ``view``.

Also available as ``python -m mi_plugins``.
"""
import argparse
import os
import re
import sys
import time

from mi_plugins.base.errors import root_cause


def _parser():
    p = argparse.ArgumentParser(prog="mi-plugins", description="Mitsuba 3 plugins with analytic verification.")
    sub = p.add_subparsers(dest="command", required=True)

    v = sub.add_parser("verify", help="run the integrator x analytic-case verification matrix, the "
                                      "conformance suite of ordinary scenes (--suite scenes) or the coverage matrix "
                                      "of every Mitsuba feature (--suite coverage)")
    v.add_argument("--suite", choices=("analytic", "scenes", "coverage"), default="analytic",
                   help="analytic: integrator x analytic-case matrix (default); scenes: conformance suite "
                        "(ordinary Mitsuba scenes, every package integrator against Mitsuba's path); coverage: every "
                        "plugin Mitsuba ships (and a few cases) against every package integrator")
    v.add_argument("--quick", action="store_true", help="small subset at low resolution (about 3 minutes on 2 cores)")
    v.add_argument("--integrators", nargs="+", metavar="NAME", help="integrators of the matrix to run")
    v.add_argument("--scenes", nargs="+", metavar="CASE",
                   help="analytic cases (conformance scenes, coverage rows such as bsdf:plastic) to run")
    v.add_argument("--report", metavar="DIR", help="write verify.json and verify.md into DIR")
    v.add_argument("--seed", type=int, default=0)
    v.add_argument("--list", action="store_true", help="list the integrators and cases and exit")
    v.add_argument("--gradients", action="store_true",
                   help="the gradient matrix instead: Mitsuba's differentiable integrators against the analytic "
                        "cases' exact derivatives, forward and reverse mode (--report writes gradients.json/.md)")

    d = sub.add_parser("demo", help="render the Cornell box with path and the package's integrators at equal time "
                                    "(PNGs and a contact sheet), a walkthrough from one solve against path at equal "
                                    "time (an animated GIF and a strip), then a short analytic check")
    d.add_argument("--out", default="reports/demo", metavar="DIR", help="where the PNGs go (default reports/demo)")
    d.add_argument("--seconds", type=float, default=5.0, help="seconds per integrator on one view (default 5)")
    d.add_argument("--resolution", type=int, default=128, help="pixels per side (default 128)")
    d.add_argument("--frames", type=int, default=30, help="frames of the walkthrough (default 30; 0: none)")
    d.add_argument("--no-check", action="store_true", help="skip the analytic check")

    r = sub.add_parser("render", help="render a Mitsuba XML scene in passes to an EXR, PNG or JPEG file")
    r.add_argument("scene", metavar="SCENE.xml")
    r.add_argument("-o", "--output", required=True, metavar="OUT.{exr,png,jpg}",
                   help="output image: .exr (float32 RGB with metadata), .png or .jpg/.jpeg (8-bit sRGB)")
    r.add_argument("--spp", type=int, default=None, help="samples per pixel (default: the scene's sampler)")
    r.add_argument("--passes", type=int, default=None,
                   help="number of passes the spp are split into (default 8; 1 where the integrator displays a "
                        "view-independent solution: each pass has its own seed, hence its own solve)")
    r.add_argument("--sensors", default=None, metavar="all|I,J,..",
                   help="render these sensors of the scene (one image each: OUT with _<index> before its extension) "
                        "from one solve")
    r.add_argument("--preview-every", type=int, default=0, metavar="N",
                   help="ray_bundle / qmc_lighttrace: write OUT every N steps of the solve (iterations, particle "
                        "ranges) with the image of the solution so far")
    r.add_argument("--seed", type=int, default=0, help="0 .. 42948 (42947 above 38452 passes)")
    r.add_argument("-D", dest="defines", action="append", default=[], metavar="name=value",
                   help="set an XML $parameter (repeatable)")
    where = r.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="N",
                       help="render on a local Dask cluster of N worker processes (needs mi-plugins[distributed])")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="render on an existing Dask cluster, e.g. tcp://host:8786")
    r.add_argument("--tasks", type=int, default=None, metavar="N",
                   help="with --workers/--scheduler: tasks the render is split into (default 16; the image "
                        "depends on it, not on the number of workers)")
    w = sub.add_parser("view", help="write one self-contained HTML page (WebGL, no network) that shows a saved "
                                    "solution's baked radiance from a walkthrough camera")
    w.add_argument("solution", metavar="SOLUTION.npz", help="a solution saved by Solution.save")
    w.add_argument("--scene", required=True, metavar="SCENE.xml", help="the scene it was computed for (its geometry)")
    w.add_argument("-o", "--output", required=True, metavar="OUT.html")
    w.add_argument("--sensor", type=int, default=0, help="the scene's sensor the camera starts from (default 0)")
    w.add_argument("--exposure", type=float, default=0.0, help="initial exposure in stops, -20 .. 20 (default 0)")
    w.add_argument("-D", dest="defines", action="append", default=[], metavar="name=value",
                   help="set an XML $parameter (repeatable)")
    return p


def _view(args):
    from mi_plugins.app.view import view_files
    path = view_files(args.solution, args.scene, args.output, args.sensor, args.exposure, _parse_defines(args.defines))
    print("wrote %s (%.0f kB)" % (path, os.path.getsize(path) / 1e3))
    return 0


def _verify(args):
    if args.gradients and args.suite != "analytic":
        raise ValueError("--gradients applies to --suite analytic (got --suite %s)" % args.suite)
    if args.suite == "coverage":
        from mi_plugins.verify import coverage
        from mi_plugins.verify.coverage import report
        if args.list:
            print("integrators: " + ", ".join(coverage.expected.INTEGRATORS))
            print("rows:        " + ", ".join(coverage.matrix.rows()))
            return 0
        return report.verify(args.integrators, args.scenes, quick=args.quick, report=args.report, seed=args.seed)
    if args.suite == "scenes":
        from mi_plugins.verify import conformance
        if args.list:
            print("integrators: " + ", ".join(conformance.INTEGRATORS))
            print("scenes:      " + ", ".join(conformance.scenes()))
            return 0
        return conformance.verify(args.integrators, args.scenes, quick=args.quick, report=args.report, seed=args.seed)
    from mi_plugins.verify.analytic import gradient_matrix, matrix
    if args.gradients:
        matrix = gradient_matrix  # the same interface: run, format_table, write_reports, INTEGRATORS, cases
    if args.list:
        print("integrators: " + ", ".join(matrix.INTEGRATORS))
        print("cases:       " + ", ".join(matrix.all_cases()))
        print("quick cases: " + ", ".join(matrix.quick_cases()))
        return 0
    t0 = time.perf_counter()

    def progress(r):
        what = " dL/d%s %s" % (r.parameter, r.mode) if args.gradients else ""
        print("  %-5s %-22s %-16s%s %s" % (r.status, r.case, r.integrator, what,
                                           r.reason if not r.applicable else "z=%+.2f  %.2fs" % (r.z, r.seconds)),
              flush=True)

    results = matrix.run(args.integrators, args.scenes, quick=args.quick, seed=args.seed, progress=progress)
    print()
    print(matrix.format_table(results))
    bad = [r for r in results if not r.ok]
    counts = {s: sum(r.status == s for r in results) for s in ("PASS", "FAIL", "XFAIL", "XPASS", "N/A")}
    print("\n%d passed, %d failed, %d known failures, %d unexpected passes, %d not applicable (%.1f s)"
          % (counts["PASS"], counts["FAIL"], counts["XFAIL"], counts["XPASS"], counts["N/A"],
             time.perf_counter() - t0))
    for r in bad:
        print("\n" + repr(r))
    if args.report:
        for path in matrix.write_reports(results, args.report):
            print("wrote " + path)
    return 1 if bad else 0


def _parse_defines(defines):
    params = {}
    for item in defines:
        if "=" not in item:
            raise ValueError("-D %s: expected name=value" % item)
        name, value = item.split("=", 1)
        params[name.strip()] = value
    return params


def _render(args):
    import mitsuba as mi
    from mi_plugins.app import exr, passes
    from mi_plugins.render import pass_seeds
    if args.spp is not None and args.spp < 1:
        raise ValueError("--spp %d: must be a positive integer (valid range: 1 or more)" % args.spp)
    if args.passes is not None and args.passes < 1:
        raise ValueError("--passes %d: must be a positive integer (valid range: 1 or more)" % args.passes)
    if args.preview_every < 0:
        raise ValueError("--preview-every %d: valid range: 0 (no previews) or more" % args.preview_every)
    exr.check_output(args.output)  # before any work: a bad output path fails fast
    if not os.path.isfile(args.scene):
        raise FileNotFoundError("scene file '%s' does not exist" % args.scene)
    defines = _parse_defines(args.defines)
    scene = mi.load_file(args.scene, **defines)
    if scene.integrator() is None:
        raise ValueError("scene '%s' has no integrator; add one, e.g. <integrator type=\"path\"/>" % args.scene)
    integrator = _integrator_name(scene.integrator(), args.scene, defines)
    spp = pass_seeds.scene_spp(scene) if args.spp is None else args.spp
    if spp < 1:  # Mitsuba would die with SIGFPE
        raise ValueError("the scene's sampler has sample_count=%d; valid range: 1 or more (set it in the scene, "
                         "with -D spp=N where the scene reads $spp, or override it with --spp N)" % spp)
    from mi_plugins.solution import views
    sensors = list(range(len(scene.sensors()))) if args.sensors in (None, "all") else _indices(args.sensors)
    views.sensor_list(scene, sensors)              # a bad index is refused before any work
    if args.sensors is None:
        sensors = [0]
    if args.workers is not None or args.scheduler is not None:
        return _render_distributed(args, integrator, spp, defines, sensors)
    from mi_plugins.distributed.plan import keeps_solution
    display = getattr(scene.integrator(), "display", "gather") != "gather"
    keeps = display or (args.sensors is not None and keeps_solution(scene.integrator()))
    count = args.passes if args.passes is not None else (1 if keeps else 8)
    _previews(scene.integrator(), args)
    code = 0
    for k in sensors:
        out = args.output if args.sensors is None else frame_path(args.output, k)
        result = passes.render_in_passes(scene, spp=args.spp, passes=count, seed=args.seed, progress_bar=True,
                                         sensor=k)
        meta = {"integrator": integrator, "sensor": str(k),
                "spp": str(result.spp_done), "seed": str(args.seed), "seconds": "%.3f" % result.seconds,
                "passes": "%d/%d" % (result.passes_done, result.passes), "scene": os.path.abspath(args.scene)}
        if result.iterations:
            meta["iterations"] = "%d/%d" % (result.iterations_done, result.iterations)
        exr.save(out, result.image, meta)
        state = "interrupted after" if result.interrupted else "finished"
        iterations = ", %s iterations" % meta["iterations"] if result.iterations else ""
        print("%s %d/%d passes (%d spp%s, %.2f s); wrote %s"
              % (state, result.passes_done, result.passes, result.spp_done, iterations, result.seconds, out))
        if result.interrupted:
            return 130 if result.empty else 0
    return code


def _indices(text):
    try:
        return [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise ValueError("--sensors %s: valid: 'all' or sensor indices separated by commas, e.g. 0,2" % text)


def frame_path(output, index):
    """OUT.exr -> OUT_<index>.exr: the image of sensor ``index``."""
    stem, ext = os.path.splitext(output)
    return "%s_%d%s" % (stem, index, ext)


def _previews(integrator, args):
    """With --preview-every, the integrator writes the output file with the image of its
    solution every N steps of a solve."""
    if not args.preview_every:
        return
    from mi_plugins.app import exr
    if not hasattr(integrator, "preview_every") or (integrator.plugin == "ray_bundle"
                                                    and integrator.display == "gather"):
        raise ValueError("--preview-every: the scene's integrator has no view-independent solve to preview "
                         "(qmc_lighttrace has; ray_bundle has with display 'smooth', 'patches' or 'baked')")
    integrator.preview_every = int(args.preview_every)

    def write(image, done, total):
        exr.save(args.output, __import__("numpy").array(image), {"preview": "%d/%d" % (done, total)})
        print("preview %d/%d: wrote %s" % (done, total, args.output), flush=True)
    integrator.preview_callback = write


def _render_distributed(args, integrator, spp, defines, sensors):
    """``render --workers N`` / ``--scheduler ADDRESS``: the render split into tasks on Dask
    (with --sensors: one task per sensor, the solution computed once and shipped to all)."""
    from mi_plugins import distributed
    from mi_plugins.app import exr
    if args.sensors is not None:
        with distributed.connect(args.workers, args.scheduler) as client:
            result = distributed.render_views(args.scene, spp, sensors=sensors, client=client, seed=args.seed,
                                              params=defines)
        for k, image in zip(sensors, result.images):
            exr.save(frame_path(args.output, k), image, {"integrator": integrator, "sensor": str(k),
                                                          "spp": str(spp), "seed": str(args.seed)})
        print("finished %d views on %d workers (%d solve(s), %.2f s); wrote %s"
              % (len(result.images), result.workers, result.solves, result.seconds,
                 frame_path(args.output, sensors[0]) + (" ..." if len(sensors) > 1 else "")))
        return 130 if result.interrupted else 0
    if args.workers is not None and args.workers < 1:
        raise ValueError("--workers %d: valid range: 1 or more" % args.workers)
    if args.tasks is not None and args.tasks < 1:
        raise ValueError("--tasks %d: valid range: 1 or more" % args.tasks)
    with distributed.connect(args.workers, args.scheduler) as client:
        result = distributed.render(args.scene, spp, client=client, seed=args.seed, params=defines, tasks=args.tasks)
    meta = {"integrator": integrator, "spp": str(result.spp_done), "seed": str(args.seed),
            "seconds": "%.3f" % result.seconds, "passes": "%d/%d" % (result.tasks_done, result.tasks),
            "workers": str(result.workers), "scene": os.path.abspath(args.scene)}
    exr.save(args.output, result.image, meta)
    state = "interrupted after" if result.interrupted else "finished"
    print("%s %d/%d tasks on %d workers (%d spp, %.2f s); wrote %s"
          % (state, result.tasks_done, result.tasks, result.workers, result.spp_done, result.seconds, args.output))
    return 130 if result.interrupted and result.tasks_done == 0 else 0


def _integrator_name(integrator, scene_file, defines):
    """The registered plugin name of the scene's integrator ('path', 'ptracer',
    'ray_bundle', ...): the package's integrators know theirs; for others it is the
    ``type`` of the scene file's top-level <integrator> (read with Mitsuba's parser)."""
    import mitsuba as mi
    from mitsuba import parser
    from mi_plugins.render.core import CoreIntegrator
    if isinstance(integrator, CoreIntegrator):
        return integrator.plugin
    state = parser.parse_file(parser.ParserConfig(mi.variant()), scene_file, **defines)
    for _, value in state.root.props.items():
        if isinstance(value, mi.Properties.ResolvedReference):
            node = state.nodes[value.index()]
            if node.type == mi.ObjectType.Integrator:
                return node.props.plugin_name()
    return integrator.class_name()  # not found in the file (e.g. a <ref>): Mitsuba's class name


def main(argv=None):
    args = _parser().parse_args(argv)
    try:
        if args.command == "demo":
            from mi_plugins.app import demo
            return demo.run(args.out, args.seconds, args.resolution, check=not args.no_check, frames=args.frames)
        if args.command == "view":
            return _view(args)
        return _verify(args) if args.command == "verify" else _render(args)
    except KeyboardInterrupt:
        print("mi-plugins: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # one clear line instead of a traceback
        if os.environ.get("MI_PLUGINS_DEBUG"):
            raise
        cause = root_cause(e)
        msg = _parameter_error(str(cause)) or str(cause).strip().splitlines()
        print("mi-plugins: error: %s" % (" ".join(m.strip() for m in msg) if msg else type(cause).__name__),
              file=sys.stderr)
        return 2


def _parameter_error(text):
    """A plugin's ParameterError wrapped by Mitsuba's loader (with the Python traceback):
    its message and the place in the scene file, or None."""
    marker = "ParameterError: "
    if marker not in text:
        return None
    where = re.search(r"At (.*?): failed to instantiate", text)
    return [text[text.rindex(marker) + len(marker):].strip().splitlines()[0]
            + (" (at %s)" % where.group(1) if where else "")]


if __name__ == "__main__":
    sys.exit(main())
