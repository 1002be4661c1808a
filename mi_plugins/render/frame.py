"""The state of one render: a :class:`Frame` collects the estimates of one render in
named blocks, each developed on its own and summed:

- *camera* estimates (``frame.camera_block(name)``): one value per camera sample, put
  with weight 1; developing divides by the accumulated filter weight, so the block holds
  the average of all its camera samples whatever the number of passes finished;
- *light* estimates (``frame.light_block(name, scale)``): splats of light paths at their
  film position (``DirectionSample3f.uv``), put with weight 0 into a normalising block
  and multiplied by ``scale`` (as Mitsuba's particle tracer does).

``frame.commit()`` (after an iteration's ``dr.eval``) marks the state an interrupted
render returns to, so a Ctrl-C between an iteration's splats and its evaluation never
keeps half an iteration. The camera samples are drawn from the sensor's sampler.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import errors, queries, seeds
from mi_plugins.render.camera import CameraPass

#: scatter-adds into small arrays (per-triangle sums) from many lanes: on the LLVM
#: backend, per-core copies of the target instead of contended atomics
SPLAT_MODE = dr.ReduceMode.Expand


def coverage(scene, surface, hide_emitters):
    """The film's alpha of camera rays, as Mitsuba's integrators make it: 1 where the ray
    shows a surface (``surface``, Bool per ray; hidden emitters are passed through), and
    everywhere when the scene has an environment emitter that is not hidden."""
    if scene.environment() is not None and not hide_emitters:
        return dr.full(mi.Bool, True, dr.width(surface))
    return mi.Bool(surface)


class Frame:
    """The state of one render (see the module docstring)."""

    def __init__(self, scene, sensor, spp, seed, plugin="integrator"):
        self.scene, self.sensor, self.spp, self.seed, self.plugin = scene, sensor, int(spp), int(seed), plugin
        self.film = sensor.film()
        self.film.prepare([])
        size = self.film.crop_size()
        self.width, self.height = int(size[0]), int(size[1])
        self.pixels = self.width * self.height
        self._blocks = {}        # name -> (block, light scale or None)
        self._committed = {}
        self._sampler = None
        self._seed_per_pass = False
        self._coverage = None    # see _edge_coverage
        self._alpha_block = None  # the camera block that carries the film's alpha (put_camera)
        self.task = None          # a part of a distributed render (CoreIntegrator.render_task), or None
        self.result = None        # what such a task returns instead of an image

    # ------------------------------------------------------------------ camera samples
    def camera_passes(self, per_pixel, passes):
        """Prepare ``passes`` passes of ``per_pixel`` camera samples per pixel: the sensor's
        sampler is cloned with sample_count = per_pixel x passes and seeded once, so a
        low-discrepancy sampler gives every pixel one well-distributed sample set over all
        the passes."""
        sampler = self.sensor.sampler().clone()
        per_pixel, passes = int(per_pixel), max(int(passes), 1)
        sampler.set_sample_count(per_pixel * passes)
        if sampler.sample_count() != per_pixel * passes:
            # the sampler rounds the count (stratified, multijitter: to squares; orthogonal:
            # to squares of primes): one pass takes the rounded count, as Mitsuba's own
            # integrators do; several passes are seeded one by one (camera_pass)
            rounded = int(sampler.sample_count())
            if passes == 1:
                per_pixel = rounded
            else:
                sampler.set_sample_count(per_pixel)
                if sampler.sample_count() != per_pixel:
                    raise errors.Unsupported(
                        self.plugin, queries.plugin_name(sampler),
                        "the sensor's sampler '%s' with %d camera samples per pixel and pass"
                        % (queries.plugin_name(sampler), per_pixel),
                        "it rounds the count to %d, and this integrator needs exactly %d per pass (one per chain)"
                        % (int(sampler.sample_count()), per_pixel),
                        "use a count this sampler keeps (e.g. a square for 'stratified'), or the 'independent', "
                        "'multijitter' or 'ldsampler' sampler")
                self._seed_per_pass = True
        sampler.set_samples_per_wavefront(per_pixel)
        lanes = self.sample_pixels() * per_pixel
        if lanes >= 1 << 32:
            raise ValueError("%d camera samples per pass exceed 2^32: use fewer samples per pixel" % lanes)
        sampler.seed(seeds.stream(self.seed, "camera"), lanes)
        self._sampler, self._per_pixel, self._passes_begun, self._lanes = sampler, per_pixel, 0, lanes

    def sample_pixels(self):
        """Pixels a pass of one camera sample per pixel covers: the crop window, with the
        filter's border where the film samples it."""
        film = self.film
        border = film.rfilter().border_size() if film.sample_border() else 0
        return (self.width + 2 * border) * (self.height + 2 * border)

    def camera_pass(self):
        """The next pass of camera samples (after :meth:`camera_passes`)."""
        if self._passes_begun > 0 and self._seed_per_pass:
            self._sampler.seed(seeds.stream(self.seed, "camera", self._passes_begun), self._lanes)
        elif self._passes_begun > 0:
            self._sampler.advance()
        self._passes_begun += 1
        return CameraPass(self, self._sampler, self._per_pixel)

    # ------------------------------------------------------------------ blocks
    def camera_block(self, name="camera"):
        if name not in self._blocks:
            block = self.film.create_block()
            block.set_coalesce(False)
            self._blocks[name] = (block, None)
        return self._blocks[name][0]

    def light_block(self, name="light", scale=1.0):
        """A normalising block for light-path splats; ``scale`` multiplies it when developed
        (a Python float, or a callable evaluated then, e.g. 1 / steps finished)."""
        if name not in self._blocks:
            block = self.film.create_block(normalize=True)
            block.set_offset(self.film.crop_offset())
            block.set_coalesce(False)
            self._blocks[name] = (block, scale)
        return self._blocks[name][0]

    def _put(self, block, pos, rgb, alpha, weight, active=True):
        """Splat RGB values into ``block`` in the film's channel layout (as Mitsuba's
        ADIntegrator does: films with special channels prepare their own samples)."""
        film = self.film
        if dr.all(mi.has_flag(film.flags(), mi.FilmFlags.Special)):
            values = film.prepare_sample(rgb, dr.zeros(mi.Color0f), block.channel_count(), weight=weight, alpha=alpha)
        elif mi.has_flag(film.flags(), mi.FilmFlags.Alpha):
            values = [rgb.x, rgb.y, rgb.z, mi.Float(alpha), mi.Float(weight)]
        else:
            values = [rgb.x, rgb.y, rgb.z, mi.Float(weight)]
        block.put(pos, values, active)

    def put_camera(self, cam, value, name="camera", coverage=None):
        """Average ``value`` (Color3f per camera sample of ``cam``) into a camera block
        (every sample counts, with weight 1). ``coverage`` (Bool per sample: the camera
        ray hit a surface) makes the film's alpha channel, as in Mitsuba's integrators;
        only the first block given it carries alpha (the others put 0), so that the
        developed blocks sum to one alpha."""
        if coverage is not None and self._alpha_block in (None, name):
            self._alpha_block = name
            alpha = dr.select(coverage, 1.0, 0.0)
        else:
            alpha = 0.0
        self._put(self.camera_block(name), cam.pos, mi.Color3f(value) * cam.weight, alpha, 1.0)

    def put_camera_share(self, pos, value, active=True, name="camera"):
        """Add ``value`` at film positions ``pos`` to a camera block with weight 0: a share of
        the camera samples put there (their further rays), which leaves the block's
        normalisation and alpha as they are."""
        self._put(self.camera_block(name), pos, mi.Color3f(value), 0.0, 0.0, active)

    #: the camera block of :meth:`put_emission`
    EMISSION = "emission"

    def put_emission(self, pos, value, weight, active=True):
        """Put camera rays' ``value`` (Color3f, the emission they see) at film positions
        ``pos`` with sample weight ``weight`` into the camera block ``EMISSION`` (developed
        on its own and added: its own normalisation, no alpha)."""
        self._put(self.camera_block(self.EMISSION), pos, mi.Color3f(value) * weight, 0.0, weight, active)

    def put_light(self, uv, value, name="light", scale=1.0, active=True):
        """Splat ``value`` at film positions ``uv`` into a light block (weight 0)."""
        block = self.light_block(name, scale)
        self._put(block, uv + mi.Vector2f(block.offset()), mi.Color3f(value), 0.0, 0.0, active)

    def block_total(self, name):
        """The sum of every channel of block ``name`` (a Float of width 1, not evaluated)."""
        return dr.sum(self._blocks[name][0].tensor().array)

    def clear(self, name):
        """Empty block ``name`` (and its committed contents)."""
        block = self._blocks[name][0]
        block.clear()
        self._committed.pop(name, None)

    def state(self):
        """What an iteration's dr.eval must evaluate: the blocks, and the camera sampler's
        state (scheduled: otherwise every pass's kernel would recompute its history)."""
        if self._sampler is not None:
            self._sampler.schedule_state()
        return [block.tensor() for block, _ in self._blocks.values()]

    def commit(self):
        """Remember the blocks' current contents (after the iteration's dr.eval)."""
        self._committed = {name: mi.TensorXf(block.tensor()) for name, (block, _) in self._blocks.items()}

    def rollback(self):
        """Return every block to its last committed contents (empty if never committed)."""
        for name in list(self._blocks):
            block, scale = self._blocks[name]
            if name in self._committed:
                block.clear()
                block.put_block(mi.ImageBlock(self._committed[name], block.offset(), None, False,
                                              block.normalize()))
            else:
                del self._blocks[name]

    # ------------------------------------------------------------------ develop
    def _edge_coverage(self):
        """Per-pixel share of a uniform density of light splats that a normalising block
        keeps (1 inside, less within the filter's radius of the film's edge, where the
        part of each footprint beyond the edge is dropped and no splats arrive from beyond
        it; the sensor returns splats inside the crop window only, so "edge" is the crop
        window's). Dividing a light block by it gives the pixel the filter-weighted average of
        the radiance over the film, which is what a camera block holds; without it a
        Gaussian filter darkens the border pixels of light-traced images by up to ~16 %.
        Computed by splatting an n x n grid per pixel with the film's own filter."""
        film = self.film
        if film.rfilter().radius() <= 0.5 + 1e-6:
            return 1.0
        if self._coverage is None:
            n = 8
            block = self.film.create_block(normalize=True)
            block.set_offset(film.crop_offset())
            block.set_coalesce(False)
            idx = dr.arange(mi.UInt32, self.pixels)
            base = mi.Point2f(mi.Float(idx % self.width), mi.Float(idx // self.width)) + mi.Vector2f(film.crop_offset())
            value = [mi.Float(1.0 / (n * n))] * (block.channel_count() - 1) + [mi.Float(0.0)]
            for k in range(n * n):
                shift = mi.Vector2f(dr.opaque(mi.Float, (k % n + 0.5) / n), dr.opaque(mi.Float, (k // n + 0.5) / n))
                block.put(base + shift, value)
                dr.eval(block.tensor())
            self._coverage = mi.TensorXf(block.tensor())[:, :, 0:1]
        return self._coverage
    def develop(self, develop=True):
        """The image (TensorXf (H, W, C)): every block developed with the film and summed.
        With ``develop=False`` the film is left holding the result (call
        ``film.develop()`` or ``film.bitmap()``) and an empty tensor is returned."""
        if not self._blocks:
            self.camera_block()
        images = []
        for block, scale in self._blocks.values():
            self.film.prepare([])
            self.film.put_block(block)
            image = self.film.develop()
            if scale is not None:
                image = image * (scale() if callable(scale) else scale) / self._edge_coverage()
            images.append(image)
        result = images[0]
        for image in images[1:]:
            result = result + image
        if develop:
            return result
        # leave the film holding the result: the one weighted block as it is, or the sum
        # of several as a block of unit weights
        self.film.prepare([])
        if len(self._blocks) == 1 and next(iter(self._blocks.values()))[1] is None:
            self.film.put_block(next(iter(self._blocks.values()))[0])
        else:
            channels = self.film.create_block().channel_count()
            data = np.ones((self.height, self.width, channels), dtype=np.float32)
            developed = np.array(result)
            # the developed channels in the block's order, its weight last (alpha kept);
            # films with special channels (AOVs, spectral) order them otherwise: RGB only
            kept = 3 if mi.has_flag(self.film.flags(), mi.FilmFlags.Special) else min(developed.shape[-1], channels - 1)
            data[..., :kept] = developed[..., :kept]
            self.film.put_block(mi.ImageBlock(mi.TensorXf(data), self.film.crop_offset()))
        return mi.TensorXf()
