"""The ``ray_bundle`` integrator: parameters and the iteration loop."""
import warnings

import drjit as dr
import mitsuba as mi

from mi_plugins import seeds
from mi_plugins.integrators.core import CoreIntegrator
from mi_plugins.integrators.ray_bundle.average import DiffuseAverage
from mi_plugins.integrators.ray_bundle.directions import SEQUENCES, chain_directions, global_directions
from mi_plugins.integrators.ray_bundle.estimators import ESTIMATORS, AveragedSources, ChainSources
from mi_plugins.integrators.ray_bundle.transfer import ChainLayout, Transport
from mi_plugins.meshtable import MeshTable
from mi_plugins.params import Params


class RayBundleIntegrator(CoreIntegrator):
    r"""
    .. _integrator-ray_bundle:

    Stochastic iteration with global ray bundles (``ray_bundle``)
    -------------------------------------------------------------

    Finite-element stochastic iteration over the triangles of the scene's meshes. Each
    patch :math:`i` keeps only its radiance :math:`L[i]` in the current global direction
    :math:`\omega_m` (and in :math:`-\omega_m` when ``bidirectional``). Every iteration
    transfers all patch radiances along :math:`\omega_m` with a bundle of
    ``resolution`` x ``resolution`` jittered parallel lines across the scene's bounding
    sphere (all successive hits along each line; consecutive hits facing each other
    exchange radiance), picks a new direction :math:`\omega_{m+1}`, and reflects:

    .. math:: L_{new}[i] = L^e_i(\omega_{m+1}) + 4\pi f_i(\omega_m,\omega_{m+1}) \sum_j A(i,j,\omega_m)/A_i\, L[j]

    (with ``bidirectional`` both :math:`\pm\omega` are used and each gets weight
    :math:`2\pi`). Emission and BSDF are evaluated at a uniformly random point of each
    patch every iteration, so textures are averaged without bias. Memory is
    O(chains x (triangles + resolution^2)).

    .. list-table::
       * - Parameter, type, default, range: meaning
       * - ``iterations``, int, 64, >= 1: global directions (transfers) per render pass
       * - ``burn_in``, int, 8, 0 .. iterations-1: iterations left out of the image average
       * - ``resolution``, int, 128, >= 1: lines per side of the bundle
       * - ``chains``, int, 1, >= 1: chains (own direction sequence, own
           patch radiances) run in lockstep, one kernel per iteration for all of them;
           the image averages the chains. 1 is the paper's algorithm; more chains use the
           cores better when ``resolution^2`` or the triangle count is small
       * - ``bidirectional``, bool, true: use every line in both directions
       * - ``first_shot``, bool, false: direct light by next-event estimation (one
           visibility-tested light sample per patch point and per camera sample, as in
           the "first shot" of radiosity); the bundles then carry only reflected
           radiance. Unbiased like the default; much less noise where direct light
           dominates (small lights). false is the paper's algorithm
       * - ``estimate``, string, 'gather': 'gather' (per pixel, reflect the stored radiance
           arriving along the bundle direction(s) at the visible point toward the eye) or
           'patch' (per pixel, the patch-averaged incoming radiance of the visible patch)
       * - ``direction_sequence``, string, 'independent': 'independent' | 'halton' |
           'hammersley' | 'pi'. Only 'independent' is correct: the others are 1-uniform
           sequences and bias the result (paper section 6.1).
       * - ``stratify_chains``, bool, true with 'independent': every iteration, the
           directions of the chains form one evenly spread set (a spherical Fibonacci
           set, over the hemisphere when ``bidirectional``), freshly randomly rotated and
           dealt to the chains in a fresh random order. Each chain's directions stay
           independent and uniform (unbiased, as the paper requires) while the image,
           which averages the chains, has less noise (RMSE halved on the furnace
           sphere mesh with 64 chains). false: independent directions in every
           chain. No effect with one chain; only with 'independent'
       * - ``average_diffuse``, bool, false: final gathering from averaged diffuse
           patches. A patch with a purely diffuse BSDF reflects the same radiance in
           every direction, so all chains' values in all averaged iterations estimate
           the same number: their average (O(triangles) memory) replaces the current
           chain's value in the image. The image is then made after the iterations, one
           pass per averaged iteration (same camera samples and directions; with
           ``first_shot`` the gathered point's direct light by next-event estimation).
           Unbiased like the default for the patch-averaged problem; far less noise
           (furnace sphere mesh: 6x lower RMSE at equal time than first shot alone). Non-diffuse patches
           keep the paper's per-chain estimate. false is the paper's algorithm
       * - ``gather_nee``, bool, true: with ``first_shot`` and ``average_diffuse``, the
           direct light of each gathered point by next-event estimation (exact where it
           varies within a patch, e.g. near lights). false: the direct light is part of
           the patch average (no extra rays). true is exact where the reflected
           radiance minus the direct light is constant per patch; where only their
           sum is (neighbouring patches emitting differently, e.g. the Bekaert box:
           0.6 % low) use false
       * - ``hide_emitters``, bool, false: do not show directly visible emitters

    ``mi.render(scene, spp=k)`` runs ``iterations * k`` global iterations of every chain;
    every averaged iteration traces one fresh camera sample per pixel and chain (work
    linear in ``k`` and in ``chains``). With ``average_diffuse`` those camera samples are
    traced after the iterations (the final gathering), and again during the iterations
    when the scene also has non-diffuse patches.

    Progress: ``integrator.progress_callback = f``; ``f(done, total)`` after every
    iteration, return ``False`` to stop early; Ctrl-C also stops early; the finished
    iterations make the image. With ``average_diffuse`` the steps also count the final
    gathering's passes (``integrator.iteration_count(spp)``); stopping during the
    iterations still runs one final-gathering pass per finished averaged iteration
    (stop again to cut it short: the finished passes, at least one, make the image).

    With ``first_shot`` the stored radiance is the reflected part
    :math:`L_r = L - L^e` and the iteration is
    :math:`L_r^{new}[i] = (T L^e)_i(\omega_{m+1}) + 4\pi f_i \sum_j A(i,j,\omega_m)/A_i\, L_r[j]`
    with :math:`T L^e` (direct light) estimated by one light sample at the patch point;
    the image adds the directly seen emission, the direct light at the visible point
    (one light sample) and the gathered or patch-averaged reflected radiance.

    Caveats: only triangle meshes (other shapes: ``NonMeshShapeError``). The radiance is
    constant per patch, so non-constant radiance over a patch is averaged (bias of order
    of the radiance variation within a triangle; zero in the furnace and constant-radiance
    cases). Transport through delta (mirror/glass) surfaces cannot be captured by random
    global directions: such surfaces only reflect the camera rays (a warning is issued).
    """
    plugin = "ray_bundle"
    iterative = True

    def __init__(self, props=mi.Properties()):
        p = Params(props, "ray_bundle")
        hide_emitters = p.bool("hide_emitters", False)   # before the base class reads it with its own check
        super().__init__(props)
        self.hide_emitters = hide_emitters
        self.iterations = p.int("iterations", 64, lo=1)
        self.burn_in = p.int("burn_in", min(8, self.iterations - 1), lo=0)
        if self.burn_in > self.iterations - 1:
            raise p.conflict(("burn_in", "iterations"), "burn_in in 0 .. iterations - 1 = %d" % (self.iterations - 1))
        self.resolution = p.int("resolution", 128, lo=1)
        self.chains = p.int("chains", 1, lo=1)
        self.bidirectional = p.bool("bidirectional", True)
        self.first_shot = p.bool("first_shot", False)
        self.estimate = p.choice("estimate", "gather", tuple(ESTIMATORS))
        self.direction_sequence = p.choice("direction_sequence", "independent", SEQUENCES)
        independent = self.direction_sequence == "independent"
        self.stratify_chains = p.bool("stratify_chains", independent)
        if self.stratify_chains and not independent:
            raise p.conflict(("stratify_chains", "direction_sequence"),
                             "stratify_chains=true needs direction_sequence='independent' (the other sequences "
                             "give every chain its own sequence)")
        self.average_diffuse = p.bool("average_diffuse", False)
        self.gather_nee = p.bool("gather_nee", True)

    def iteration_count(self, spp):
        """Steps of a render with ``spp``: ``iterations * spp`` global iterations (each
        advances every chain), plus with ``average_diffuse`` the final gathering's passes
        (one per averaged iteration)."""
        total = self.iterations * int(spp)
        return total + (total - self.burn_in if self.average_diffuse else 0)

    def _warn_delta(self, scene):
        names = [s.id() for s in scene.shapes()
                 if s.bsdf() is not None and mi.has_flag(s.bsdf().flags(), mi.BSDFFlags.Delta)]
        if names:
            warnings.warn("ray_bundle: shape(s) %s have delta (mirror/glass) BSDF lobes; light transport "
                          "through delta surfaces cannot be captured by random global directions, only "
                          "camera rays are reflected by them. The result is biased where transport depends "
                          "on them; use stochastic_ray or path for such scenes." % ", ".join(names),
                          RuntimeWarning, stacklevel=3)

    def render_frame(self, frame):
        scene, seed = frame.scene, frame.seed
        layout = ChainLayout(MeshTable(scene, "ray_bundle"), self.chains, 2 if self.bidirectional else 1)
        self._warn_delta(scene)
        transport = Transport(scene, layout, self.resolution, self.first_shot, seed)
        total, burn_in = self.iterations * frame.spp, self.burn_in
        directions = global_directions(self.direction_sequence, total + 1, self.chains,
                                       seeds.numpy_rng(seed, "directions"), self.stratify_chains, self.bidirectional)
        estimator = ESTIMATORS[self.estimate](transport, self.hide_emitters, seed)
        average = DiffuseAverage(layout, self.estimate, transport.weight) if self.average_diffuse else None
        # without averaging, every averaged iteration images everything; with it, the
        # iterations image only the patches that are not averaged (none to image when all
        # are) and the final gathering the averaged ones
        sources = ChainSources(layout, skip=average)
        image_iterations = average is None or not average.covers_all
        frame.camera_passes(self.chains, (total - burn_in) * (int(image_iterations) + int(average is not None)))
        state = transport.initial(chain_directions(directions[0]))
        dr.eval(state, transport.state())
        steps = self.steps(total, burn_in, self.iteration_count(frame.spp))
        try:
            for m in steps.iterations():
                incoming = transport.transfer(state)
                if m >= burn_in:
                    if average is not None:
                        average.add(state.dirs, self._averaged_radiance(state), incoming)
                    if image_iterations:
                        estimator.put(frame, frame.camera_pass(), state, incoming, sources, m, "iterations")
                state = transport.reflect(state, incoming, chain_directions(directions[m + 1]))
                dr.eval(state, transport.state(), frame.state(), average.state() if average is not None else None)
                frame.commit()
        except KeyboardInterrupt:
            steps.stop()               # Ctrl-C: keep the finished iterations
            frame.rollback()
        if average is not None and self.progress.averaged > 0:
            self._final_gathering(frame, estimator, steps, directions, AveragedSources(average, self.gather_nee))

    def _averaged_radiance(self, state):
        """What the diffuse averages hold: what the gathered point does not add itself (the
        reflected part R; with first_shot and gather_nee=false all of L but the emission,
        which then is the direct light)."""
        return state.L if self.first_shot and not self.gather_nee else state.R

    def _final_gathering(self, frame, estimator, steps, directions, sources):
        """The image of the averaged diffuse patches, the direct light and the seen
        emission: one pass per averaged iteration that finished, with that iteration's
        directions. Ctrl-C (or the progress callback) ends it after the current pass."""
        for k in steps.second_stage(self.progress.averaged):
            m = self.burn_in + k
            try:
                state = ChainDirections(chain_directions(directions[m]))
                estimator.put(frame, frame.camera_pass(), state, None, sources, m, "final")
                dr.eval(frame.state())
                frame.commit()
            except KeyboardInterrupt:
                frame.rollback()
                if k == 0:
                    raise          # no finished pass: there is no image to keep
                steps.stop()
                break


class ChainDirections:
    """The part of an iteration state the final gathering needs: the directions."""

    def __init__(self, dirs):
        self.dirs, self.L = dirs, None
