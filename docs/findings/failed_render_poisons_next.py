"""Mitsuba 3.9.1 / Dr.Jit 1.5.0: after a render fails inside a plugin, the next render of an unrelated scene fails with the same error (until gc.collect())

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scenes: "bad", a `rectangle` whose `area` emitter has a `blackbody` radiance (which
Mitsuba accepts at load in RGB variants and refuses in `eval()` during the render, see
rgb_variant_spectra_fail_at_render.py); "good", an unrelated `rectangle` with an `rgb`
radiance, and Mitsuba's `cornell_box()`. Integrator `path`, 8 x 8 px.

The failing render is made the way ordinary code keeps an error for a message:

    def try_render(scene):
        try:
            mi.render(scene)
        except RuntimeError as e:
            error = e          # frame -> error -> traceback -> frame: a reference cycle
        return str(error.__cause__)

Expected: once `try_render` has returned, the bad scene is unreachable, and the good
scenes render as before.

Measured:

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    1. good lamp scene, before anything else:      renders
    2. bad scene through try_render():             [BlackBodySpectrum] Not implemented for non-spectral modes
    3. good lamp scene, after try_render returned: raises: [BlackBodySpectrum] Not implemented for non-spectral modes
    4. cornell_box(), same:                        raises: [BlackBodySpectrum] Not implemented for non-spectral modes
    5. gc.collect() -> 49 objects
    6. good lamp scene, after gc.collect():        renders
    7. cornell_box(), same:                        renders
    8. cornell_box() while a bad scene is alive (never rendered): raises: [BlackBodySpectrum] Not implemented for non-spectral modes
    9. the same in evaluated mode (no symbolic calls/loops):     renders
    10. cornell_box() after `del bad` (no cycle, freed at once):   renders
    (0.2 s)

The good scenes fail with the bad scene's error until `gc.collect()` breaks the cycle
(the frame of `try_render` holds `error`, whose traceback holds the frame, which holds
the scene). More generally, a bad scene that is merely alive (loaded, never rendered)
makes every render of every other scene fail, and so does holding the exception object
of a failed render.

Cause: Dr.Jit records a virtual call (`Emitter::eval`, `sample_direction`, ...) in
`ad_call_symbolic` (drjit, src/extra/call.cpp) by looping over every instance id of the
call's domain up to the registry's bound, `ptr = jit_registry_ptr(backend, domain, i + 1)`,
and tracing the method of each registered pointer. Mitsuba registers every plugin
instance under its base class's domain when it is constructed, so the call traces every
live emitter of the process, not only those that the calling scene can reach. A live
instance whose method raises while traced breaks every render, and one whose lifetime
is tied to a reference cycle (here: an exception's traceback) lives until the cycle
collector runs. In evaluated mode (`dr.JitFlag.SymbolicCalls` and `SymbolicLoops`
False), `ad_call_reduce` only calls the instances that occur in the pointer array, and
the good scene renders even while the bad one is alive (line 9). The same mechanism makes every
render slower the more scenes are alive (live_scenes_slow_renders.py).

Suggested fix: trace only the instances that the rendered scene can reach, e.g. by
registering each scene's plugins under a per-scene domain (or passing the scene's
instance set to the call); failing that, document the process-wide effect next to
`mi.render`. Users: drop the failed scene and the exception (`del`), then `gc.collect()`.

Run: `python docs/findings/failed_render_poisons_next.py` (about 3 s on 2 cores).
"""
import gc
import time

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")


def lamp(radiance):
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path"},
        "sensor": {"type": "perspective",
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 3], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "lamp": {"type": "rectangle", "emitter": {"type": "area", "radiance": radiance}}})


def bad_scene():
    return lamp({"type": "blackbody", "temperature": 3000})


def cornell():
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = 8
    return mi.load_dict(d)


def outcome(scene):
    try:
        mi.render(scene, spp=4)
        return "renders"
    except RuntimeError as e:
        return "raises: " + str(e.__cause__ or e).splitlines()[0]


def try_render(scene):
    try:
        mi.render(scene)
    except RuntimeError as e:
        error = e          # frame -> error -> traceback -> frame: a reference cycle
    return str(error.__cause__)


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    good, box = lamp({"type": "rgb", "value": 1.0}), cornell()
    print("1. good lamp scene, before anything else:     ", outcome(good))
    print("2. bad scene through try_render():            ", try_render(bad_scene()).splitlines()[0])
    print("3. good lamp scene, after try_render returned:", outcome(good))
    print("4. cornell_box(), same:                       ", outcome(box))
    print("5. gc.collect() -> %d objects" % gc.collect())
    print("6. good lamp scene, after gc.collect():       ", outcome(good))
    print("7. cornell_box(), same:                       ", outcome(box))
    bad = bad_scene()  # loaded, never rendered, still referenced
    print("8. cornell_box() while a bad scene is alive (never rendered):", outcome(box))
    for flag in (dr.JitFlag.SymbolicCalls, dr.JitFlag.SymbolicLoops):
        dr.set_flag(flag, False)
    print("9. the same in evaluated mode (no symbolic calls/loops):    ", outcome(box))
    for flag in (dr.JitFlag.SymbolicCalls, dr.JitFlag.SymbolicLoops):
        dr.set_flag(flag, True)
    del bad
    print("10. cornell_box() after `del bad` (no cycle, freed at once):  ", outcome(box))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
