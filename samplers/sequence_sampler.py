"""Base class of the package's samplers (``halton``, ``sobol``, ``faure``; the padded
``padded_sobol``, ``zsobol``, ``lattice`` and ``cmj`` build on it in ``padded_sobol.py``).

Mitsuba's protocol: ``sample_count()`` = N samples per pixel in total,
``set_samples_per_wavefront(k)`` (k per pixel per pass; N when not called),
``seed(seed, pixels * k)`` and ``advance()`` between passes. Lane j of pass p is
sample p * k + j % k of pixel j // k; it draws coordinate ``dim`` of that point of the
sequence, the dimension advancing by one per drawn number (``next_2d`` takes two) and
``advance()`` resetting it to 0. The dimension is a Dr.Jit variable, so it advances
correctly inside the symbolic loops of Mitsuba's integrators. With k = N (one pass)
lane j is sample j % N of pixel j // N.

``set_samples_per_wavefront(k)`` applies to the next ``seed()`` only: Mitsuba's C++
renderer sets its own value through a non-virtual call that a Python sampler cannot
see, so a value left by an earlier Python caller must not leak into it. (A C++
multi-pass render, e.g. ``samples_per_pass`` of Mitsuba's integrators, is therefore
seen as passes of N samples per pixel: unbiased, but the pixels do not get the points
0 .. N-1; ``advance()`` warns.)

Decorrelation between pixels: each pixel's points are scrambled with its own seed (hash
of pixel and render seed), with the scramble :mod:`mi_plugins.base.sequences` defines for the
sequence (Owen for Sobol, random digit permutations for Halton, Faure's permutation and
random digit shifts for Faure). With ``scramble=False`` all pixels use the same
unrandomised points (deterministic, correlated across pixels: for studies only).
Dimensions beyond the sequence's table fall back to hashed pseudo-random numbers.

The user reference of each sampler is its class docstring, made by :func:`reference`.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.base import sequences
from mi_plugins.base.params import Params


_SCRAMBLE_ROW = """
     * - scramble
       - bool
       - true
       - each pixel's points randomised with its own seed by %s; ``false``:
         the same unrandomised points in every pixel (deterministic; for studies)"""


def reference(name, title, scramble, note=""):
    """The class docstring (plugin reference) of the sampler ``name``: the parameters are
    the same for every sampler of the package, the scramble and the note are the
    sampler's own (``scramble=None``: always randomised, no ``scramble`` parameter)."""
    return """
    .. _sampler-%(name)s:

    ``%(name)s`` (%(title)s)
    %(rule)s

    A low-discrepancy sampler for every Mitsuba integrator (Mitsuba 3.9.1 has no Halton,
    Sobol or lattice sampler): use it as the sensor's sampler with ``path``, ``volpath``,
    ``ptracer``, ``prb`` or this package's integrators (protocol, randomisation and which
    sampler to choose: see the samplers section below).%(note)s

    .. pluginparameters::

     * - sample_count
       - int
       - 4
       - 1 .. 2^32 - 1 samples per pixel (``mi.render(spp=...)`` overrides it)%(scramble)s
     * - seed
       - int
       - 0
       - 0 .. 2^32 - 1: selects the randomisation together with the render seed
         (``mi.render(seed=...)``): scenes differing only in the sampler's ``seed`` give
         different images for the same render seed; 0 = the render seed alone

    .. code-block:: python

        'sampler': {'type': '%(name)s', 'sample_count': 64}

    .. code-block:: xml

        <sampler type="%(name)s"><integer name="sample_count" value="64"/></sampler>
    """ % dict(name=name, title=title, rule="-" * (len(name) + len(title) + 7),
               scramble=_SCRAMBLE_ROW % scramble if scramble else "",
               note=(" " + note) if note else "")


class SequenceSampler(mi.Sampler):
    #: sequence name (set by subclasses) and the dimensions its tables cover
    sequence = None
    max_dim = 0
    #: the plugin name (the sequence's unless a subclass says otherwise)
    plugin = None
    #: whether the plugin has the ``scramble`` parameter (otherwise always randomised)
    has_scramble = True

    def __init__(self, props):
        # read before the base class, which reads sample_count and seed with its own checks
        p = Params(props, self.name())
        p.int("sample_count", 4, lo=1, hi=0xFFFFFFFF)
        sampler_seed = p.int("seed", 0, lo=0, hi=0xFFFFFFFF)
        scramble = p.bool("scramble", True) if self.has_scramble else True
        super().__init__(props)
        self.scramble, self.sampler_seed = scramble, sampler_seed
        self.next_per_pixel = None        # set_samples_per_wavefront(k) for the next seed()
        self.per_pixel, self.per_pixel_told, self.passes = 1, False, 0
        self.base_seed = self.sample_index = self.pixel = self.dimension = mi.UInt32(0)
        self.wavefront = 1

    @classmethod
    def name(cls):
        return cls.plugin or cls.sequence

    def _properties(self):
        """Fresh Properties with this sampler's parameters (the constructor's are temporary)."""
        props = mi.Properties(self.name())
        props["sample_count"] = int(self.sample_count())
        if self.has_scramble:
            props["scramble"] = bool(self.scramble)
        props["seed"] = int(self.sampler_seed)
        return props

    # ------------------------------------------------------------------ state
    def set_samples_per_wavefront(self, k):
        super().set_samples_per_wavefront(k)     # checks that k divides sample_count
        self.next_per_pixel = int(k)

    def seed(self, seed, wavefront_size=0xFFFFFFFF):
        width = int(wavefront_size) if wavefront_size != 0xFFFFFFFF else 1
        self.per_pixel_told = self.next_per_pixel is not None
        self.per_pixel = self.next_per_pixel or int(self.sample_count())
        self.next_per_pixel, self.passes, self.wavefront = None, 0, width
        self.pixel = dr.arange(mi.UInt32, width) // self.per_pixel
        self._set_sample_index()
        if isinstance(seed, int):
            seed &= 0xFFFFFFFF
        # the render seed and the sampler's `seed` parameter together (seed 0: as without it)
        extra = (self.sampler_seed,) if self.sampler_seed else ()
        self.base_seed = sequences.hash32(mi.UInt32(seed), 0xA511E9B3, *extra)
        dr.make_opaque(self.base_seed)            # a new seed reuses the compiled kernels
        self.dimension = dr.zeros(mi.UInt32, width)

    def _set_sample_index(self):
        # the pass offset is opaque: every pass runs the same kernels
        self.sample_index = (dr.arange(mi.UInt32, self.wavefront) % self.per_pixel
                             + dr.opaque(mi.UInt32, self.passes * self.per_pixel))

    def advance(self):
        if not self.per_pixel_told and self.passes == 0:
            mi.Log(mi.LogLevel.Warn, "%s: advance() after a seed() without set_samples_per_wavefront(): "
                   "each pass is taken as %d samples per pixel (a Python sampler cannot see the samples per "
                   "pass of Mitsuba's C++ renderer)" % (self.name(), self.per_pixel))
        self.passes += 1
        self._set_sample_index()
        self.dimension = dr.zeros(mi.UInt32, self.wavefront)

    def _copy_state(self, other):
        for name in ("next_per_pixel", "per_pixel", "per_pixel_told", "passes", "wavefront"):
            setattr(other, name, getattr(self, name))
        for name in ("base_seed", "sample_index", "pixel", "dimension"):
            setattr(other, name, mi.UInt32(getattr(self, name)))
        return other

    def fork(self):
        other = type(self)(self._properties())
        other.next_per_pixel = self.next_per_pixel
        return other

    def clone(self):
        return self._copy_state(type(self)(self._properties()))

    def schedule_state(self):
        dr.schedule(self.base_seed, self.sample_index, self.pixel, self.dimension)

    # ------------------------------------------------------------------ numbers
    def _value(self, dim):
        """Coordinate ``dim`` (UInt32 per lane) of each lane's point."""
        in_table = dim < self.max_dim
        value = sequences.sample(self.sequence, self.sample_index, dr.select(in_table, dim, 0), scramble=self.scramble,
                           seed=sequences.hash32(self.pixel, self.base_seed))
        fallback = sequences.to_unit(sequences.hash32(self.pixel, self.sample_index, dim, self.base_seed))
        return dr.select(in_table, value, fallback)

    def next_1d(self, active=True):
        x = self._value(self.dimension)
        self.dimension += 1
        return x

    def next_2d(self, active=True):
        x, y = self._value(self.dimension), self._value(self.dimension + 1)
        self.dimension += 2
        return mi.Point2f(x, y)

    def to_string(self):
        return "%s[sample_count=%d, scramble=%s, seed=%d]" % (type(self).__name__, self.sample_count(),
                                                             self.scramble, self.sampler_seed)
