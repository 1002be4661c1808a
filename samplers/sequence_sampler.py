"""Base class of the low-discrepancy samplers (``halton``, ``sobol``, ``faure``).

Mitsuba renders a wavefront of ``pixels x spp`` lanes; lane j belongs to pixel
j // spp and is that pixel's sample j % spp. Every lane draws coordinate ``dim`` of
point (j % spp) of the sequence, and the dimension advances by one per drawn number
(``next_2d`` takes two). The dimension is a Dr.Jit variable, so it advances correctly
inside the symbolic loops of Mitsuba's integrators.

Decorrelation between pixels: each pixel gets its own randomisation of the sequence
(hash of pixel, dimension and seed): Owen scrambling for Sobol, a Cranley-Patterson
rotation for Halton and Faure. With ``scramble=False`` all pixels use the same
unrandomised points (deterministic, correlated across pixels: for studies only).
Dimensions beyond the sequence's table fall back to hashed pseudo-random numbers.

Parameters (all three samplers): ``sample_count`` (int >= 1, default 4; ``mi.render(spp=...)``
overrides it), ``scramble`` (bool, default true), ``seed`` (int 0 .. 2^32 - 1, default 0):
the render seed (``mi.render(seed=...)``) and this seed together select the
randomisation, so scenes that differ only in the sampler's seed give different images
for the same render seed; seed 0 gives the randomisation of the render seed alone.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins import qmc
from mi_plugins.params import Params


class SequenceSampler(mi.Sampler):
    #: sequence name and the number of dimensions its tables cover (set by subclasses)
    sequence = None
    max_dim = 0

    def __init__(self, props):
        # read before the base class, which reads sample_count and seed with its own checks
        p = Params(props, self.sequence)
        p.int("sample_count", 4, lo=1, hi=0xFFFFFFFF)
        sampler_seed = p.int("seed", 0, lo=0, hi=0xFFFFFFFF)
        scramble = p.bool("scramble", True)
        super().__init__(props)
        self.scramble, self.sampler_seed = scramble, sampler_seed
        self.base_seed = mi.UInt32(0)
        self.sample_index = mi.UInt32(0)
        self.pixel = mi.UInt32(0)
        self.dimension = mi.UInt32(0)

    def _properties(self):
        """Fresh Properties with this sampler's parameters (the constructor's are temporary)."""
        props = mi.Properties(self.sequence)
        props["sample_count"] = int(self.sample_count())
        props["scramble"] = bool(self.scramble)
        props["seed"] = int(self.sampler_seed)
        return props

    # ------------------------------------------------------------------ state
    def seed(self, seed, wavefront_size=0xFFFFFFFF):
        width = int(wavefront_size) if wavefront_size != 0xFFFFFFFF else 1
        lane = dr.arange(mi.UInt32, width)
        spp = self.sample_count()
        self.sample_index = lane % spp
        self.pixel = lane // spp
        if isinstance(seed, int):
            seed &= 0xFFFFFFFF
        # the render seed and the sampler's `seed` parameter together (seed 0: as without it)
        if self.sampler_seed == 0:
            self.base_seed = qmc.hash_u32(mi.UInt32(seed), 0xA511E9B3)
        else:
            self.base_seed = qmc.hash_u32(mi.UInt32(seed), 0xA511E9B3, self.sampler_seed)
        self.dimension = dr.zeros(mi.UInt32, width)
        self.wavefront = width

    def _copy_state(self, other):
        other.base_seed = mi.UInt32(self.base_seed)
        other.sample_index = mi.UInt32(self.sample_index)
        other.pixel = mi.UInt32(self.pixel)
        other.dimension = mi.UInt32(self.dimension)
        other.wavefront = getattr(self, "wavefront", 1)
        return other

    def fork(self):
        return type(self)(self._properties())

    def clone(self):
        return self._copy_state(type(self)(self._properties()))

    def schedule_state(self):
        dr.schedule(self.base_seed, self.sample_index, self.pixel, self.dimension)

    # ------------------------------------------------------------------ numbers
    def _value(self, dim, active):
        """Coordinate ``dim`` (UInt32 per lane) of each lane's point."""
        in_table = dim < self.max_dim
        safe_dim = dr.select(in_table, dim, 0)
        value = self.sequence_value(self.sample_index, safe_dim)
        fallback = qmc._hashed_unit(self.pixel, self.sample_index, dim, self.base_seed)
        return dr.select(in_table, value, fallback)

    def sequence_value(self, index, dim):
        raise NotImplementedError

    def _rotate(self, x, dim):
        if not self.scramble:
            return x
        y = x + qmc._hashed_unit(self.pixel, dim, self.base_seed, 0x0C9A)
        return dr.select(y >= 1.0, y - 1.0, y)

    def next_1d(self, active=True):
        x = self._value(self.dimension, active)
        self.dimension += 1
        return x

    def next_2d(self, active=True):
        x = self._value(self.dimension, active)
        y = self._value(self.dimension + 1, active)
        self.dimension += 2
        return mi.Point2f(x, y)

    def to_string(self):
        return "%sSampler[sample_count=%d, scramble=%s, seed=%d]" % (self.sequence.capitalize(), self.sample_count(),
                                                                    self.scramble, self.sampler_seed)
