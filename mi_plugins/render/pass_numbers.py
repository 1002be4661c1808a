"""The numbers a camera pass's samples draw after their film position (light samples, BSDF
samples, gathers), stratified per pixel whichever sampler the sensor has.

With a stratifying sampler (anything but Mitsuba's ``independent``) the sensor's sampler
draws them, as Mitsuba's own integrators do: an orthogonal array or a low-discrepancy
sampler then stratifies the film position and the light jointly. With ``independent``
(Mitsuba's default) a :class:`PixelSobol` draws them instead: point k per_pixel + j of
Sobol's sequence for the j-th sample of a pixel in camera pass k, every dimension
Owen-scrambled per pixel, so that a pixel's samples over all passes stratify every pair
of numbers anyway (dimensions 0 and 1, the first light sample, form a (0, 2)-sequence).

Measured on a furnished room (128 x 96 px, 121 camera samples, the smooth display, direct
light alone): independent numbers for the BSDF samples of the direct light and for the
gathers beside a window's reveal left the pixel variance at 1.9x `path`'s with an
orthogonal sampler; from the sampler it is 1.05x.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.base import sequences


class PixelSobol:
    """Numbers of a camera pass ``cam`` (``per_pixel``, ``count``, ``grid_pixel``) drawn as
    a sampler draws them (:meth:`next_1d`, :meth:`next_2d`, one dimension after the other):
    Sobol's point k per_pixel + j for the j-th sample of a pixel in pass ``k``, scrambled
    per pixel from ``seed`` (the render's stream)."""

    def __init__(self, cam, seed, k):
        per_pixel = dr.opaque(mi.UInt32, cam.per_pixel)    # opaque: one kernel for every camera sample count
        self.index = dr.opaque(mi.UInt32, int(k) * cam.per_pixel) + dr.arange(mi.UInt32, cam.count) % per_pixel
        self.key = sequences.hash32(dr.opaque(mi.UInt32, seed), cam.grid_pixel)
        self.dim = 0        # the next dimension to draw

    def subset(self, lanes):
        """The numbers of the lanes ``lanes`` (UInt32) alone, from the next dimension on."""
        out = object.__new__(PixelSobol)
        out.index, out.key = dr.gather(mi.UInt32, self.index, lanes), dr.gather(mi.UInt32, self.key, lanes)
        out.dim = self.dim
        return out

    def next_1d(self, active=True):
        self.dim += 1
        return sequences.sample("sobol", self.index, self.dim - 1, scramble=True, seed=self.key)

    def next_2d(self, active=True):
        return mi.Point2f(self.next_1d(active), self.next_1d(active))

    def schedule_state(self):
        """(Nothing to schedule: the numbers are a function of the lane.)"""


def pass_numbers(cam, seed, k):
    """What draws the numbers of camera pass ``k`` (module docstring): ``cam.sampler``
    unless it is Mitsuba's independent sampler, else a :class:`PixelSobol` of ``seed``."""
    return PixelSobol(cam, seed, k) if cam.independent else cam.sampler
