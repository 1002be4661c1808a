"""Mitsuba 3.9.1: `irregular`, `regular` and `blackbody` load in RGB variants and only fail during the render

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene: one `rectangle` with an `area` emitter whose `radiance` is an `irregular`
spectrum (wavelengths "400, 700", values "1, 2"), a `regular` spectrum (400-700 nm,
values "1, 2") or a `blackbody` (3000 K); a `perspective` camera, `path`, 8 x 8 px.

Expected: either the radiance is converted to RGB at load time, as Mitsuba already does
for a `spectrum` given as wavelength/value pairs, or the scene is refused at load time
with a clear message.

Measured:

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    irregular           load: OK; render: raises RuntimeError: [IrregularSpectrum] IrregularSpectrum::eval(): not implemented!
    regular             load: OK; render: raises RuntimeError: [RegularSpectrum] RegularSpectrum::eval(): not implemented!
    blackbody           load: OK; render: raises RuntimeError: [BlackBodySpectrum] Not implemented for non-spectral modes
    spectrum (control)  load: OK; render: renders, image mean RGB [2.14   1.4042 1.0171]
    (0.3 s)

All three load without a word and raise during the render, from inside the integrator's
kernel (`mi.render` re-raises a generic "error while performing a custom differentiable
operation"; the real error is its `__cause__`). The same wavelength/value pairs given as a
`spectrum` are converted to sRGB at load and render. Besides the late error, a failure
inside a render leaves the scene alive in a reference cycle, and Dr.Jit then traces its
plugins in the next, unrelated renders, which fail with the same error until
`gc.collect()` runs (see failed_render_poisons_next.py).

Cause (src/spectra/irregular.cpp, regular.cpp, blackbody.cpp): `eval()`, `pdf_spectrum()`
and `sample_spectrum()` are implemented for spectral variants only (`if constexpr
(is_spectral_v<Spectrum>)`); otherwise they call `NotImplementedError("eval")` (blackbody:
"Not implemented for non-spectral modes"), but the constructors accept any variant. The
scene parser turns a `spectrum` with wavelength/value pairs into `irregular` only in
spectral variants and into an sRGB value (`spectrum_list_to_srgb`) otherwise, but a plugin
dict or XML element of type `irregular`/`regular`/`blackbody` bypasses that conversion.

Suggested fix: in non-spectral variants, have these constructors throw ("irregular: only
available in spectral variants; use a 'spectrum' with wavelength/value pairs, which is
converted to RGB"), or convert the spectrum to an sRGB constant at load time as the
parser does.

Run: `python docs/findings/rgb_variant_spectra_fail_at_render.py` (about 3 s on 2 cores).
"""
import gc
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

RADIANCES = [
    ("irregular", {"type": "irregular", "wavelengths": "400, 700", "values": "1, 2"}),
    ("regular", {"type": "regular", "wavelength_min": 400, "wavelength_max": 700, "values": "1, 2"}),
    ("blackbody", {"type": "blackbody", "temperature": 3000}),
    ("spectrum (control)", {"type": "spectrum", "value": [(400.0, 1.0), (700.0, 2.0)]}),
]


def scene_dict(radiance):
    return {"type": "scene", "integrator": {"type": "path"},
            "sensor": {"type": "perspective",
                       "to_world": mi.ScalarTransform4f().look_at([0, 0, 3], [0, 0, 0], [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 8, "height": 8},
                       "sampler": {"type": "independent", "sample_count": 4}},
            "lamp": {"type": "rectangle", "emitter": {"type": "area", "radiance": radiance}}}


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for label, radiance in RADIANCES:
        try:
            scene = mi.load_dict(scene_dict(radiance))
        except Exception as e:  # noqa: BLE001
            print("%-19s load: raises %s" % (label, str(e).splitlines()[0]))
            continue
        try:
            image = mi.render(scene)
            result = "renders, image mean RGB %s" % np.round(np.mean(np.array(image), axis=(0, 1)), 4)
        except Exception as e:  # noqa: BLE001  (the point is to show the error)
            cause = e.__cause__ or e
            result = "raises %s: %s" % (type(cause).__name__, str(cause).splitlines()[0])
            del cause, e
        print("%-19s load: OK; render: %s" % (label, result))
        del scene
        gc.collect()  # the failed scene would otherwise make the next render fail too
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
