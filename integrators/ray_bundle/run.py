"""One ``ray_bundle`` render: set-up, the iterations (frozen steps), the convergence
check that may extend the burn-in, and the final gathering.

Every iteration runs two frozen steps (:mod:`.frozen`): *advance* (the bundles' transfer,
the diffuse averages and the power trace of an averaged iteration, the reflection into
the next direction) and, where the iterations image, *image* (one camera pass of a group
of chains). The final gathering replays *image* with the averages as its source. A
camera pass covers the chains of one group (:func:`.limits.camera_group`), so that its
samples fit in memory whatever the film's size.
"""
import warnings
import weakref
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from mi_plugins.base import seeds, errors
from mi_plugins.integrators.ray_bundle import power_trace, memory
from mi_plugins.render.burn_in import EXTENSION_CAP, verdict
from mi_plugins.integrators.ray_bundle.average import DiffuseAverage
from mi_plugins.solution.display import edge_pixels
from mi_plugins.integrators.ray_bundle.directions import DirectionStream, chain_directions
from mi_plugins.integrators.ray_bundle.estimators import ESTIMATORS, AveragedSources, ChainSources
from mi_plugins.integrators.ray_bundle.frozen import FrozenStep, fingerprint, freezable, jit_leaves, own_arrays
from mi_plugins.integrators.ray_bundle.irradiance import IrradianceAverage
from mi_plugins.integrators.ray_bundle.transfer import ChainLayout, Transport


@dataclass
class Cam:
    """One camera pass's samples as a frozen step's input (``camera.CameraPass``'s; with
    further rays on emitters' edges also what ``display.emission_shares`` reads)."""
    ray: mi.Ray3f
    weight: mi.Color3f
    pos: mi.Vector2f
    sampler: mi.Sampler
    count: int
    per_pixel: int
    sensor: mi.Sensor = None
    grid_pixel: mi.UInt32 = None
    box: bool = True
    film_rays: bool = True


@dataclass
class ChainDirections:
    """The part of an iteration state the final gathering needs: the directions."""
    dirs: mi.Vector3f
    L: list = None


def touch(block):
    """Make ``block``'s (zero) contents an evaluated array instead of a literal: the first
    frozen step would do it, and its successors see a different input (one more recording)."""
    block.put(mi.Point2f(0.0), [mi.Float(0.0)] * block.channel_count(), mi.Bool(False))
    dr.eval(block.tensor())


class Run:
    """The state of one render of ``integ`` into ``frame``; ``available``: bytes of memory.
    ``table``: the scene's patches; ``solve_only``: the iterations of a view-independent
    solution (``irradiance``), no camera pass."""

    def __init__(self, integ, frame, available, default_chains, table, solve_only=False, children=False,
                 chains=None, counts=None):
        self.integ, self.frame, split = integ, frame, frame.task
        scene, spp = frame.scene, 1 if solve_only else frame.spp
        self.solve_only = solve_only
        self.after = None            # after(run, iterations so far): a preview, called after every step
        self.gather_only = split is not None and split.mode == "gather"
        memory.check_sizes(integ.iterations, spp, integ.resolution, integ.max_depth)
        sides, orders = 2 if integ.bidirectional else 1, integ.orders()
        per_chain = 0 if solve_only else frame.sample_pixels()
        chains = chains or (split.chains if split is not None and split.chains else
                  integ.chains or memory.default_chains(default_chains, sides * table.count, integ.resolution,
                                                        available, orders))
        self.layout = layout = ChainLayout(table, chains, sides, orders)
        self.group = chains if solve_only else memory.sampler_group(frame.sensor.sampler(), chains,
                                                                    memory.camera_group(chains, per_chain, available))
        if not self.gather_only:
            memory.check(layout, integ.resolution, per_chain, self.group, available)
        self.transport = Transport(scene, layout, integ.resolution, integ.first_shot, frame.seed, integ.max_depth >= 0,
                                   integ.point_sources, children, integ.share_diffuse)
        self.estimator = None if solve_only else ESTIMATORS[integ.estimate](self.transport, integ.hide_emitters,
                                                                            integ.max_depth)
        if self.estimator is not None:
            self.estimator.group = integ.camera_group = self.group
            # the pixels on an emitter's edge (further camera rays for the emission seen there)
            self.estimator.edges = edge_pixels(frame, integ.max_depth, integ.hide_emitters, integ.emitter_samples)
        self.average = (DiffuseAverage(layout, integ.estimate, self.transport.weight, orders)
                        if integ.average_diffuse and not solve_only else None)
        # (chains that share their diffuse patches are not independent groups: no error)
        self.irradiance = (IrradianceAverage(layout, self.transport.weight, seeds.pcg(layout.slots, frame.seed,
                                                                                     "patches", 1),
                                             independent=self.transport.sharing is None)
                           if solve_only else None)
        self.total, self.burn_in = counts if counts is not None else integ.counts(spp)
        self.window = self.total - self.burn_in
        # a finite depth is exact once every order is there: no growth to watch
        self.trace = power_trace.PowerTrace(layout, self.window) if integ.max_depth < 0 else None
        # without averaging, every averaged iteration images everything; with it, the
        # iterations image only the patches that are not averaged (none to image when all
        # are) and the final gathering the averaged ones
        self.image_iterations = not solve_only and (self.average is None or not self.average.covers_all)
        self.sources = {"chain": ChainSources(layout, skip=self.average)}
        if self.average is not None:
            lo = 0 if integ.max_depth < 0 or (integ.first_shot and not integ.gather_nee) else 1
            self.sources["averaged"] = AveragedSources(self.average, integ.gather_nee, lo)
        self.seed = frame.seed
        for name in (["iterations"] if self.image_iterations else []) + (["final"] if self.average else []):
            touch(frame.camera_block(name))   # made now: a frozen step must find them among its inputs
        if self.estimator is not None and self.estimator.edges is not None and not frame.film.rfilter().is_box_filter():
            touch(frame.camera_block(frame.EMISSION))   # (the emission's own block: display.emission_shares)
        own_arrays(table, self.transport.direct, self.average, self.estimator, self.irradiance)
        # the frame's blocks (not its committed copies, which change; nor the film, whose
        # storage, untouched until the end, would be made opaque by the first step)
        self.leaves = jit_leaves(self.transport, self.estimator, self.average, self.trace, self.irradiance,
                                 frame._blocks)
        # the camera sampler is used inside a step only by the hand-off of delta lobes
        self.uses_sampler = self.estimator is not None and self.estimator.handoff is not None
        self.key = self._key(integ, frame, table)
        steps = integ.step_cache.get(self.key, freezable(scene, frame.sensor) or not self.uses_sampler)
        # held weakly: the cache keeps the steps, and a frozen step keeps the run it last ran
        # (Dr.Jit holds a frozen function's inputs), so holding them here would be a reference
        # cycle that keeps the scene until a garbage collection (mi_plugins.base.collection)
        self._advance_step, self._image_step = (weakref.ref(step) for step in steps)
        # the steps' inputs as every step leaves them (evaluated, literals made opaque, e.g. in
        # the scene's plugins): a step whose first call saw them otherwise records twice
        FrozenStep("_nothing", self.advance.frozen is not None)(self)

    @property
    def advance(self):
        """The frozen advance step (see :class:`FrozenStep`)."""
        return self._advance_step()

    @property
    def image(self):
        """The frozen image step."""
        return self._image_step()

    def _key(self, integ, frame, table):
        """Every Python value the frozen steps read (see FrozenStep)."""
        t, film, avg = self.transport, frame.film, self.average
        return (id(frame.scene), fingerprint(frame.scene), table.count, table.front_count, self.layout.chains,
                self.layout.sides, self.layout.orders, t.resolution, tuple(t.center), t.radius, t.first_shot,
                t.finite, t.environment is not None, t.direct.covers_all if t.direct else None,
                t.direct.any if t.direct else None, avg is not None and (avg.covers_all, avg.estimate),
                self.trace is not None, self.group, integ.hide_emitters, integ.max_depth, integ.gather_nee,
                integ.estimate, integ.point_sources, self.uses_sampler, int(film.flags()), frame.width,
                frame.height, tuple(sorted(frame._blocks)), self.image_iterations, self.solve_only,
                t.children is not None, t.sharing is not None,
                None if self.estimator is None or self.estimator.edges is None else len(self.estimator.edges[0]))

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, Run) and other.key == self.key

    def _nothing(self):
        pass

    # ------------------------------------------------------------------ frozen steps
    def _advance(self, state, new_dirs, averaged, index, early=False):
        transport, average = self.transport, self.average
        incoming, from_sky = transport.transfer(state)
        if early and self.irradiance is not None:     # a burn-in step whose irradiance a preview shows
            self.irradiance.add(state.dirs, incoming)
        if averaged:
            if average is not None:
                average.add(state.dirs, self.integ._averaged_radiance(state), incoming)
            if self.trace is not None:
                self.trace.record(state, index)
            if self.irradiance is not None:
                self.irradiance.add(state.dirs, incoming)
        new = transport.reflect(state, incoming, new_dirs, from_sky)
        dr.eval(new, incoming, transport.mutable(), average.state if average is not None else None,
                self.trace.state if self.trace is not None else None,
                self.irradiance.state if self.irradiance is not None else None)
        return new, incoming

    def _image(self, cam, state, incoming, sources, chain_offset, rng_seed, block):
        self.estimator.put(self.frame, cam, state, incoming, self.sources[sources], rng_seed, block, chain_offset)
        dr.eval([b.tensor() for b, _ in self.frame._blocks.values()])

    def camera_passes(self, count):
        """``count`` camera passes of every chain: one per group of chains each."""
        self.frame.camera_passes(self.group, count * (self.layout.chains // self.group))

    def image_pass(self, state, incoming, sources, pass_index, block):
        """One camera pass of every chain (a pass per group of chains)."""
        for g in range(self.layout.chains // self.group):
            cam = self.frame.camera_pass()
            seed = seeds.stream(self.seed, "camera_path", pass_index * 65537 + g)
            sampler = cam.sampler if self.uses_sampler else None
            cam.sampler.schedule_state()                # the camera's samples, not how they were drawn
            edges = self.estimator.edges is not None
            dr.eval(cam.ray, cam.weight, cam.pos, cam.grid_pixel if edges else None)
            self.image(self, Cam(cam.ray, cam.weight, cam.pos, sampler, cam.count, cam.per_pixel,
                                 self.frame.sensor if edges else None, cam.grid_pixel if edges else None, cam.box,
                                 cam.film_rays),
                       state, incoming, sources, dr.opaque(mi.UInt32, g * self.group), dr.opaque(mi.UInt64, seed),
                       block)

    # ------------------------------------------------------------------ iterations
    def run(self, steps, directions, state=None):
        """Burn-in and averaged iterations (from ``state``, e.g. a coarser run's mapped onto
        refined patches, or the source term); while the chains still converge (``adaptive``)
        the burn-in goes on, up to the cap (``self.extended``: the iterations added).
        ``self.state``: the last state."""
        integ, frame, window = self.integ, self.frame, self.window
        passes = window * (int(self.image_iterations) + int(self.average is not None))
        if passes:
            self.camera_passes(passes)
        if state is None:
            state = self.transport.initial(chain_directions(directions.next()))
        dr.make_opaque(state, self.transport.mutable())   # as every later step's: one recording
        cap = max(integ.max_iterations or EXTENSION_CAP * self.total, self.total)
        used, burn_in, self.extended = 0, self.burn_in, 0
        while True:
            state = self.state = self._iterations(steps, directions, state, burn_in)
            used += burn_in + window
            if state is None or self.trace is None:
                return
            v = verdict(*self.trace.numpy(window), used - window)
            if v is None or v.converged:
                return
            if not integ.adaptive:
                warnings.warn("ray_bundle: not converged after a burn-in of %d iterations: %s. Raise iterations "
                              "and burn_in (the burn-in must exceed the number of bounces that carry most of the "
                              "light), or set adaptive=true." % (used - window, v.text()), RuntimeWarning,
                              stacklevel=4)
                return
            # the window becomes burn-in, followed by the further burn-in the measured growth
            # asks for; then a new window is averaged. Beyond max_iterations: refused, before
            # the work, instead of an image darker than the prediction allows
            burn_in = v.burn_in_needed()
            if used + burn_in + window > cap:
                raise errors.NotConverged(
                    integ.plugin, "after a burn-in of %d iterations %s" % (used - window, v.text()),
                    used + burn_in + window, cap, "render this scene with 'qmc_lighttrace', whose particles need no "
                                                  "burn-in")
            self.extended += burn_in + window
            steps.next_window(used, burn_in, window)
            for reset in (self.average, self.trace, self.irradiance):
                if reset is not None:
                    reset.reset()
            if self.image_iterations:
                frame.camera_block("iterations").clear()
                touch(frame.camera_block("iterations"))
            frame.commit()
            if passes:
                self.camera_passes(passes)

    def _iterations(self, steps, directions, state, burn_in):
        """Run ``steps``' iterations, the first ``burn_in`` of them not averaged; returns
        the last state, or None when the render was stopped."""
        last = [state]
        # with previews, the burn-in's irradiance is averaged too (the first images); it is
        # forgotten when the averaged iterations begin, and its patch points' stream starts
        # again, so that the solution is the one a render without previews makes
        early = self.after is not None and self.irradiance is not None
        start = type(self.irradiance.state.rng)(self.irradiance.state.rng) if early else None

        def step(m):
            averaged = m >= burn_in
            if early and m == burn_in and m > 0:
                self.irradiance.reset()
                self.irradiance.state.rng = start
            index = dr.opaque(mi.UInt32, max(m - burn_in, 0))
            new, incoming = self.advance(self, last[0], chain_directions(directions.next()), averaged, index,
                                         early and not averaged)
            if averaged and self.image_iterations:
                self.image_pass(last[0], incoming, "chain", m, "iterations")
            last[0] = new

        after = (lambda m: self.after(self, m + 1)) if self.after else None
        return last[0] if self.integ.run_steps(self.frame, steps, step, after) else None

    def final_gathering(self, steps, count):
        """The image of the averaged diffuse patches, the direct light and the seen
        emission (``average_diffuse``): ``count`` passes with fresh stratified global
        directions. Ctrl-C (or the progress callback) ends it after the current pass."""
        integ = self.integ
        directions = DirectionStream(integ.direction_sequence, self.layout.chains,
                                     seeds.numpy_rng(self.seed, "gather"), integ.stratify_chains,
                                     integ.bidirectional, count)
        def step(k):
            self.image_pass(ChainDirections(chain_directions(directions.next())), None, "averaged", (1 << 20) + k,
                            "final")

        if not self.integ.run_steps(self.frame, steps, step, stage=steps.second_stage(count)) and \
                steps.state.second_stage == 0:
            raise KeyboardInterrupt          # no finished pass: there is no image to keep
