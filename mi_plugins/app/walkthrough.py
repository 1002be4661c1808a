"""A walk through the Cornell box: the same camera path rendered by Mitsuba's ``path`` and
from ONE view-independent solve, at equal total time.

``path`` renders every frame at ``path_spp`` camera samples; its total time is the
budget. A solution integrator (``qmc_lighttrace`` or ``ray_bundle``, ``display='smooth'``)
solves once, on a fresh scene object, for ``timesplit.SOLVE_SHARE['walk']`` of that
budget and shows every frame with the camera samples that fit in the rest. Every frame's
error is measured against a long ``path`` reference of that frame (cached on disk:
:mod:`mi_plugins.app.cached_references`), and further runs at a quarter, a fifth or half of
``path``'s time find the time a solution needs to reach ``path``'s error on every frame.
Used by ``mi-plugins demo`` (``mi_plugins.app.demo``)::

    walk = walkthrough.compare(resolution=128, rates={'qmc_lighttrace': rate})
    walk.runs['path'].errors        # (frames, 2): RMSE whole image / away from the lamp
"""
import time

import mitsuba as mi
import numpy as np

from mi_plugins.app import cached_references, timesplit
from mi_plugins.solution import views

#: frames of the walk, the camera's field of view (degrees, along the film's smaller side), path's spp a frame
FRAMES = 30
FOV = 65.0
PATH_SPP = 64
#: the references' samples per pixel, in multiples of path's
REFERENCE_FACTOR = 8
#: the walk's camera: (start, end) of its position and of the point it looks at
WALK_ORIGIN = ((-0.1, 0.55, 1.0), (0.15, 0.45, 0.55))
WALK_TARGET = ((-1.0, -0.45, -0.5), (1.0, -0.45, -0.3))


class Run:
    """One method's frames on the walk: ``images`` (numpy), ``errors`` (frames x 2: RMSE of
    the whole image and away from the lamp, relative to the reference's mean),
    ``seconds`` (end to end), ``how`` (its budget in words), ``fraction`` (of path's
    seconds it was given) and ``info`` (a solution's: size, spp, solve_seconds, overhead)."""

    def __init__(self, images, refs, seconds, how, fraction=1.0):
        self.images = [np.asarray(image, dtype=np.float32)[..., :3] for image in images]
        self.errors = np.array([ref.errors(image) for ref, image in zip(refs, self.images)])
        self.seconds, self.how, self.fraction = float(seconds), how, float(fraction)
        self.info = {}

    def rms(self):
        """The RMS over frames of the per-frame errors (whole image, away from the lamp)."""
        return np.sqrt(np.mean(self.errors ** 2, axis=0))

    def worst_ratio(self, other):
        """The largest per-frame ratio of this run's errors to ``other``'s (whole, away)."""
        return np.max(self.errors / np.maximum(other.errors, 1e-12), axis=0)


class Walk:
    """The comparison: ``runs`` ({name: Run}, 'path' first, then each integrator at
    equal time), ``reach`` ({integrator: [Run of the shorter budgets, in the order
    tried]}), ``refs`` and ``transforms``."""

    def __init__(self, transforms, refs):
        self.transforms, self.refs, self.runs, self.reach = transforms, refs, {}, {}

    def time_to_reach(self, name):
        """(seconds, ratio to path's) of the quickest run of ``name`` whose every frame reaches
        path's error (whole image and away from the lamp); None when none did."""
        path = self.runs["path"]
        done = [r for r in self.reach.get(name, []) + [self.runs[name]] if np.all(r.worst_ratio(path) <= 1.0)]
        if not done:
            return None
        best = min(done, key=lambda r: r.seconds)
        return best.seconds, best.seconds / path.seconds


def scene_dict(resolution):
    """Mitsuba's Cornell box at ``resolution`` x ``resolution`` px, the camera's field of
    view ``FOV`` (the walk's views are inside the box), no integrator."""
    d = mi.cornell_box()
    d.pop("integrator", None)
    d["sensor"]["film"].update(width=int(resolution), height=int(resolution))
    d["sensor"]["fov"] = FOV
    return d


def dolly(frames, origin, target, up=(0.0, 1.0, 0.0)):
    """``frames`` camera transforms (``mi.ScalarTransform4f``) along straight lines from
    ``origin[0]`` to ``origin[1]``, looking from ``target[0]`` to ``target[1]``, eased in
    and out (smoothstep)."""
    if int(frames) < 2:
        raise ValueError("walkthrough: frames=%r: valid: 2 or more" % (frames,))
    o0, o1, t0, t1 = (np.asarray(v, dtype=np.float64) for v in (*origin, *target))
    out = []
    for k in range(int(frames)):
        t = k / (int(frames) - 1)
        s = t * t * (3.0 - 2.0 * t)
        out.append(mi.ScalarTransform4f().look_at(origin=(o0 + s * (o1 - o0)).tolist(),
                                                   target=(t0 + s * (t1 - t0)).tolist(), up=list(up)))
    return out


def cornell_walk(frames=FRAMES):
    """The walk: in at the box's opening, high on the left, looking down at the red wall
    and the tall box, turning past the small box to the green wall (every view inside the
    box or at its opening; the lamp stays out of view)."""
    return dolly(frames, WALK_ORIGIN, WALK_TARGET)


def render_path(scene, transforms, spp, seed=1):
    """Every frame by ``path`` at ``spp``: (images, seconds)."""
    t0 = time.perf_counter()
    images = views.render_camera_path(scene, {"type": "path"}, transforms, spp=spp, seed=seed)
    return [np.array(image) for image in images], time.perf_counter() - t0


def render_solution(scene, rate, transforms, seconds, share=None, seed=2, overhead=0.0):
    """ONE solve of ``scene``, then every frame at the camera samples that fit in the rest
    (pilot renders of frames along the walk). ``overhead``: the seconds the frames cost whatever
    their camera samples (a render's fixed cost per frame, the pilots), when known; the
    solve, sized by ``rate`` (:class:`~mi_plugins.app.timesplit.SolveRate`), gets ``share``
    of the rest of ``seconds``, and the frames' camera samples at least
    ``timesplit.DISPLAY_FLOOR`` of theirs. Returns (images, dict of size, spp,
    solve_seconds, seconds, solves, overhead: the overhead measured: the display's one-time
    and per-frame costs and the shortest pilot)."""
    share = timesplit.SOLVE_SHARE["walk"] if share is None else share
    from mi_plugins import solve
    t0 = time.perf_counter()
    variable = max(seconds - overhead, 0.0)
    size = rate.size(share * variable)
    integ = mi.load_dict(rate.sized(share * variable))
    solve(scene, integ, seed=seed)
    solved = time.perf_counter() - t0
    rate.observe(size, solved)
    frames = iter(transforms[k % len(transforms)] for k in range(0, 1 << 30, 7))

    def render(spp):                      # a pilot render: the next of some frames along the walk
        return views.render_camera_path(scene, integ, [next(frames)], spp=spp, seed=seed)
    fixed, per_spp, _, once = timesplit.pilot(render, max(seconds - solved, (1.0 - share) * variable))
    floor = timesplit.DISPLAY_FLOOR * (1.0 - share) * variable + fixed * len(transforms)
    left = max(seconds - (time.perf_counter() - t0), floor)
    spp = timesplit.spp_for(left / len(transforms), fixed, per_spp)
    images = views.render_camera_path(scene, integ, transforms, spp=spp, seed=seed)
    return [np.array(image) for image in images], dict(
        size=size, spp=spp, solve_seconds=solved, seconds=time.perf_counter() - t0, solves=integ.solve_count,
        overhead=once + fixed * len(transforms) + timesplit.least_pilot(fixed, per_spp))


def _solution_run(d, rate, walk, fraction, seed, overhead=0.0):
    images, info = render_solution(mi.load_dict(d), rate, walk.transforms, fraction * walk.runs["path"].seconds,
                                   seed=seed, overhead=overhead)
    how = "1 solve (%s %d, %.1f s), %d spp a frame" % (rate.name, info["size"], info["solve_seconds"], info["spp"])
    if info["solves"] != 1:
        raise RuntimeError("walkthrough: %s solved %d times for one walk" % (rate.integrator["type"], info["solves"]))
    run = Run(images, walk.refs, info["seconds"], how, fraction)
    run.info = dict(info, name=rate.name)
    return run


def compare(resolution, rates, frames=FRAMES, path_spp=PATH_SPP, cache=None, out=print):
    """The walk at ``resolution`` px: ``path`` at ``path_spp`` a frame, then each integrator
    of ``rates`` ({name: SolveRate}) from one solve at equal time, then at shorter
    budgets (a quarter of path's time; a fifth where a quarter reaches path's error on
    every frame, half where it does not): a :class:`Walk`."""
    d = scene_dict(resolution)
    transforms = cornell_walk(frames)
    refs = cached_references.path_references(d, REFERENCE_FACTOR * path_spp, transforms, tag="walk", cache=cache, out=out)
    walk = Walk(transforms, refs)
    render_path(mi.load_dict(d), transforms[:1], 1, seed=99)            # path's kernels, on another scene object
    images, seconds = render_path(mi.load_dict(d), transforms, path_spp)
    walk.runs["path"] = Run(images, refs, seconds, "%d spp a frame" % path_spp)
    for k, (name, rate) in enumerate(rates.items()):
        walk.runs[name] = _solution_run(d, rate, walk, 1.0, seed=10 * k + 2)
        overhead = walk.runs[name].info["overhead"]          # the frames' fixed costs, known now
        walk.reach[name] = [_solution_run(d, rate, walk, 0.25, seed=10 * k + 3, overhead=overhead)]
        reached = np.all(walk.reach[name][0].worst_ratio(walk.runs["path"]) <= 1.0)
        walk.reach[name].append(_solution_run(d, rate, walk, 0.2 if reached else 0.5, seed=10 * k + 4,
                                              overhead=overhead))
    report(walk, out)
    return walk


def report(walk, out=print):
    """Print every frame's error by method, each method's budget and total seconds, and the
    time each solution needs to reach path's error on every frame."""
    path = walk.runs["path"]
    out("walkthrough: %d frames, %d x %d px; RMSE of each frame relative to its mean (%%), the reference's noise "
        "taken out" % (len(walk.transforms), *path.images[0].shape[1::-1]))
    out("  frame " + "".join("%16s" % name for name in walk.runs))
    for k in range(len(walk.transforms)):
        out("  %3d   " % k + "".join("%16.2f" % (100 * run.errors[k, 0]) for run in walk.runs.values()))
    out("  RMS   " + "".join("%16.2f" % (100 * run.rms()[0]) for run in walk.runs.values()))
    for name, run in walk.runs.items():
        out("  %-15s %5.1f s in all: %s" % (name, run.seconds, run.how))
    for name in walk.reach:
        found = walk.time_to_reach(name)
        tried = "; ".join("%.3gx: %.1f s (%s %d, %d spp), worst frame %.2fx path's" % (
            r.fraction, r.seconds, r.info["name"], r.info["size"], r.info["spp"], r.worst_ratio(path)[0])
            for r in walk.reach[name] + [walk.runs[name]])
        out("  %-15s reaches path's error on every frame %s (budgets tried: %s)" % (
            name, "in %.1f s: %.2fx path's %.1f s" % (found[0], found[1], path.seconds) if found
            else "in none of the budgets tried", tried))
