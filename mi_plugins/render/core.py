"""The shared core of the package's integrators.

As Mitsuba's ``ADIntegrator`` serves ``prb``, :class:`CoreIntegrator` owns everything
around the estimator: the sensor and its film, the number of samples per pixel, the
camera samples (drawn from the **sensor's sampler**, so ``sobol``/``halton``/``faure``
or Mitsuba's samplers drive every integrator's camera rays), splatting into Mitsuba
``ImageBlock``s with the film's reconstruction filter, developing the film (or leaving
it undeveloped with ``develop=False``), the progress of the iterations and the named
random streams. A plugin implements :meth:`CoreIntegrator.render_frame`.

A render's estimates go into a :class:`~mi_plugins.render.frame.Frame`.

The package's integrators are not differentiable (they render with gradients
suspended): ``render()`` refuses a scene with a parameter that requires gradients
(:func:`parameter_requiring_gradients`), instead of returning zero derivatives.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.base import collection, errors, fingerprint
from mi_plugins.base.param_docs import Row
from mi_plugins.base.params import Params
from mi_plugins.light import sources
from mi_plugins.render import checks
from mi_plugins.render.frame import Frame, coverage
from mi_plugins.render.progress import Progress, Steps


#: the most iterations an iterative integrator takes (a documented maximum: beyond it a
#: render would run for days)
MAX_ITERATIONS = 1 << 20

SUPPORTED = "a JIT RGB (non-polarized) variant such as 'llvm_ad_rgb' or 'cuda_ad_rgb'"
#: Mitsuba's differentiable integrators, named by the refusal
DIFFERENTIABLE = "Mitsuba's 'prb' or 'prbvolpath'"


def check_variant(plugin):
    """Raise unless the active variant is one the package's integrators run in."""
    variant = mi.variant() or ""
    if variant.startswith("scalar") or "rgb" not in variant or "polarized" in variant:
        raise RuntimeError("%s: variant '%s' is not supported: this integrator is vectorised with Dr.Jit; use %s"
                           % (plugin, variant, SUPPORTED))


def parameter_requiring_gradients(scene):
    """The key (in ``mi.traverse(scene)``) of the first differentiable scene parameter that
    requires gradients, or None. One traversal; valid inside ``dr.suspend_grad()`` too
    (mi.render calls render() there)."""
    with dr.resume_grad():
        params = mi.traverse(scene)
        for key in params.keys():
            if (params.flags(key) & mi.ParamFlags.NonDifferentiable) != 0:
                continue
            try:
                value = params[key]
            except TypeError:   # a parameter Mitsuba exposes without a value (e.g. 'hair')
                continue
            if value is not None and dr.grad_enabled(value):
                return key
    return None


def gradients_error(plugin, key):
    return NotImplementedError("%s: the scene parameter '%s' requires gradients, but %s is not differentiable (it "
                               "renders with gradients suspended: every derivative would be zero); render "
                               "derivatives with %s" % (plugin, key, plugin, DIFFERENTIABLE))


#: ``hide_emitters``, read by every integrator of the package
HIDE_EMITTERS = Row("hide_emitters", "bool", "false",
                    "hide directly visible emitters as Mitsuba does: camera rays pass through area emitters and "
                    "do not see the environment")


def iteration_rows(default, unit):
    """``iterations`` and ``burn_in`` of an iterative plugin (``unit``: what one iteration is)."""
    return (Row("iterations", "int", str(default), ">= 1 %s per unit of ``spp``" % unit),
            Row("burn_in", "int", "min(8, iterations - 1)", "0 .. iterations - 1 first iterations left out of "
                                                            "the image average"))


def run_steps(frame, steps, step, after=None, stage=None):
    """The one step loop of the package's integrators and displays: for each step of
    ``steps`` (its iterations, or the generator ``stage``, e.g. ``steps.second_stage(n)``
    or ``range(n)``), ``step(k)`` returns what to evaluate with the frame's blocks; the
    frame is committed after the evaluation, then ``after(k)`` runs (a check that may
    extend ``steps``). Ctrl-C inside a step, or a progress callback that stops, ends the
    loop: the frame returns to its last commit, the finished steps stay (without a step
    driver, ``steps`` None, the interrupt is raised on). Returns False when the render was
    stopped."""
    try:
        for k in (stage if stage is not None else steps.iterations()):
            dr.eval(step(k), frame.state())
            frame.commit()
            if after is not None:
                after(k)
    except KeyboardInterrupt:
        frame.rollback()
        if steps is None:
            raise
        steps.stop()
    return steps is None or not steps.state.interrupted


class CoreIntegrator(mi.SamplingIntegrator):
    """Base class of the package's integrators: ``render()`` resolves the sensor and the
    samples per pixel, builds a :class:`Frame` and calls :meth:`render_frame`
    (implemented by the plugin), then develops the film. Progress: see
    :mod:`mi_plugins.render.progress`."""

    #: the registered plugin name (set by each plugin)
    plugin = "integrator"
    #: True when render_frame drives its own steps (self.steps); otherwise a render is
    #: one step
    iterative = False

    def __init__(self, props):
        # the package's reader first: the base class reads hide_emitters with its own check
        hide_emitters = Params(props, self.plugin).bool("hide_emitters", False)
        super().__init__(props)
        check_variant(self.plugin)
        self.hide_emitters = hide_emitters
        self.progress = Progress()
        self.progress_callback = None

    def read_iterations(self, p, default):
        """Read ``iterations`` (>= 1) and ``burn_in`` (0 .. iterations - 1, default
        min(8, iterations - 1)) of an iterative plugin with its reader ``p``."""
        self.iterations = p.int("iterations", default, lo=1, hi=MAX_ITERATIONS)
        self.burn_in = p.int("burn_in", min(8, self.iterations - 1), lo=0)
        if self.burn_in > self.iterations - 1:
            raise p.conflict(("burn_in", "iterations"), "burn_in in 0 .. iterations - 1 = %d" % (self.iterations - 1))

    def iteration_count(self, spp):
        """Steps a render with ``spp`` runs (1 for single-pass integrators)."""
        return 1

    def steps(self, iterations, burn_in, total=None):
        """The step driver of one render (see :class:`mi_plugins.render.progress.Steps`)."""
        return Steps(self, iterations, burn_in, total)

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        return self.render_task(scene, None, sensor, seed, spp, develop)

    def render_task(self, scene, task, sensor=0, seed=0, spp=0, develop=True):
        """A render of ``scene`` that does ``task`` (``frame.task``; None: the whole image):
        the entry point of the parts of a distributed render (:meth:`distributed_split`).
        Returns the image, or ``frame.result`` where the task sets one (e.g. per-patch sums).
        No garbage collection meanwhile (:mod:`mi_plugins.base.collection`)."""
        with fingerprint.held(scene), collection.paused():      # a render does not change its scene
            return self._render_task(scene, task, sensor, seed, spp, develop)

    def _render_task(self, scene, task, sensor, seed, spp, develop):
        if isinstance(sensor, int):
            sensors = scene.sensors()
            if not 0 <= sensor < len(sensors):
                raise ValueError("%s: sensor=%d, but the scene has %d sensor(s)" % (self.plugin, sensor, len(sensors)))
            sensor = sensors[sensor]
        spp = int(spp) if spp else int(sensor.sampler().sample_count())
        if spp < 1:
            raise ValueError("%s: spp=%d must be >= 1" % (self.plugin, spp))
        key = parameter_requiring_gradients(scene)
        if key is not None:
            raise gradients_error(self.plugin, key)
        self.prepare(scene, sensor)
        if not isinstance(seed, int):      # a wrapping integrator ('aov') passes its seed as an array
            seed = int(dr.ravel(seed)[0]) if dr.width(seed) else 0
        frame = Frame(scene, sensor, spp, seed, self.plugin)
        frame.task = task
        with dr.suspend_grad():
            if not scene.shapes():
                self.render_empty(frame)
            elif self.iterative:
                self.render_frame(frame)
            else:
                for _ in self.steps(1, 0).iterations():
                    self.render_frame(frame)
            image = frame.develop(develop)
        return frame.result if frame.result is not None else image

    def distributed_split(self, scene, spp):
        """How a distributed render of ``scene`` with ``spp`` splits
        (:mod:`mi_plugins.render.phases`): None (independent passes, the default), or
        a declaration of a first phase whose sums the image's tasks render with."""
        return None

    def run_steps(self, frame, steps, step, after=None, stage=None):
        """:func:`run_steps` of this integrator's render."""
        return run_steps(frame, steps, step, after, stage)

    def render_frame(self, frame):
        raise NotImplementedError

    def render_empty(self, frame):
        """A scene without shapes: the camera sees the environment emitter (unless
        hidden), and nothing else: what every integrator's estimate reduces to."""
        self.steps(0, 0)
        frame.camera_passes(frame.spp, 1)
        cam = frame.camera_pass()
        si = frame.scene.ray_intersect(cam.ray)
        value = mi.Color3f(0.0)
        if not self.hide_emitters and getattr(self, "max_depth", -1) != 0:
            value = mi.Color3f(si.emitter(frame.scene).eval(si))
        frame.put_camera(cam, value, coverage=coverage(frame.scene, si.is_valid(), self.hide_emitters))

    def prepare(self, scene, sensor):
        """Before any work of a render or solve: refuse what the integrator cannot render
        right (:meth:`check_scene`), then have Mitsuba build what it would otherwise build
        while a kernel is traced (:func:`mi_plugins.light.sources.build_parameterizations`)."""
        self.check_scene(scene, sensor)
        sources.build_parameterizations(scene)

    def check_scene(self, scene, sensor):
        """Refuse what the integrator cannot render right, before any work
        (:class:`mi_plugins.base.errors.Unsupported`). Every package integrator refuses
        participating media; a plugin adds its own checks."""
        checks.refuse_media(self.plugin, scene, sensor)

    def render_forward(self, scene, *args, **kwargs):
        """Not differentiable (see :func:`parameter_requiring_gradients`): refused."""
        raise gradients_error(self.plugin, parameter_requiring_gradients(scene) or "given to mi.render")

    render_backward = render_forward

    def to_string(self):
        return "%s[%s]" % (type(self).__name__, self.plugin)

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """Called per camera ray by integrators that wrap another one (``aov``,
        ``moment``): the package's integrators estimate whole images (light paths,
        iterations over the whole scene), not one camera ray at a time."""
        raise errors.Unsupported(
            self.plugin, "aov/moment", "being wrapped by an integrator that calls it once per camera ray ('aov', "
            "'moment')", "%s estimates whole images (light paths and iterations over the whole scene), not the "
            "radiance of one camera ray" % self.plugin,
            "render %s alone with mi.render, and the AOVs or moments with 'aov' / 'moment' around Mitsuba's "
            "'path'" % self.plugin)
