"""Display modes of a view-independent solution (``mi_plugins.solution.solution.Solution``), shared
by ``ray_bundle`` and ``qmc_lighttrace``: the image of any camera from one solve.

Every camera ray follows mirrors and glass (``camera.specular_chain``) to its visible
point x. Where x is *purely diffuse* (``qmc_surfaces``), the mode decides what x sends
toward the eye, with no gather ray:

- ``smooth``: x's direct light by next-event estimation (exact at shadow boundaries:
  one light sample, and near emitting shapes also a BSDF sample, MIS;
  ``sampling.near_emitters``) plus rho(x) / pi times the solution's irradiance
  interpolated at x from its vertex values (``mi_plugins.solution.patchfield``);
- ``patches``: rho(x) / pi times the flat irradiance of x's patch side, direct light
  included (the solution as it is, for inspection);
- ``baked``: the reflected radiance interpolated from the vertex values of the patches'
  flat radiance (what :meth:`Solution.to_ply` exports and a mesh viewer shows).

Elsewhere (glossy, mixed, bump-mapped x, and x on a patch at the mouth of a narrow gap,
whose one value mixes the gap's trapped light with the open side's: ``mi_plugins.patches.gaps``)
the pixel falls back to the gather of
``qmc_gather``: one light sample and BSDF samples whose paths continue to the next
purely diffuse surface y, which adds its direct light and reads the solution there
(interpolated for ``smooth`` and ``baked``, flat for ``patches``). The emission seen
along the camera path is added as it is. With a finite ``max_depth`` every read takes
the table of the segments the path has left (:class:`ReadTables`).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base.arrays import jit
from mi_plugins.base import seeds
from mi_plugins.render.camera import emission_edges, lattice_rays, seen_emission
from mi_plugins.render.core import run_steps
from mi_plugins.render.frame import coverage
from mi_plugins.render.pass_numbers import PixelSobol, pass_numbers
from mi_plugins.solution.gather import CameraPaths, FlatTables, draw_numbers
from mi_plugins.solution.surfaces import patch_side
from mi_plugins.solution.surfaces import Surfaces, reflectance_toward, side_of
from mi_plugins.light.direct import direct_light, needs_bsdf_sample

#: the display modes; 'gather' is each integrator's own estimate
DISPLAYS = ("gather", "smooth", "patches", "baked")
#: camera rays per camera sample for the emission seen directly (``emitter_samples``)
DEFAULT_EMITTER_SAMPLES = 8
#: ``crowd_reach``: patch sizes within which a facing surface makes the smooth display gather
DEFAULT_CROWD_REACH = 1.0
#: ``steep``: a corner of the smooth field this far from its patch's own value (a share of
#: it) makes the smooth display gather there; off by default (mi_plugins.solution.steep)
DEFAULT_STEEP = 0.0
MAX_EMITTER_SAMPLES = 64
#: ``residual``: the share of the camera samples at read points that also gather (0: none)
DEFAULT_RESIDUAL = 0.0
#: camera lanes of one display pass at the most (a render of more is split into passes)
MAX_PASS_LANES = 1 << 22


def _color(values):
    """A Color3f from numpy (..., 3) values (flattened), never of width 1."""
    flat = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    if len(flat) < 2:
        flat = np.concatenate([flat, np.zeros((2 - len(flat), 3))])
    return jit(mi.Color3f, *flat[:, :3].T)


class ReadTables:
    """Which read table a path may read: ``tables`` = T (None: unbounded, one table);
    table t holds the light of 2 + ``offset`` .. t + 2 + ``offset`` ... segments from
    the lights, shifted by ``offset`` = -1 where the tables carry the direct light too."""

    def __init__(self, tables, direct_in_tables=False):
        self.tables, self.shift = tables, 1 if direct_in_tables else 0
        self.carries_direct = bool(direct_in_tables)       # (a read then holds the direct light too)

    def read_table(self, budget):
        """(table index, readable) for paths that may still add ``budget`` segments."""
        budget = mi.Int32(budget) + self.shift
        if self.tables is None:
            return dr.zeros(mi.UInt32, dr.width(budget)), budget >= 2
        top = dr.minimum(budget, self.tables + 1)
        return mi.UInt32(dr.maximum(top - 2, 0)), top >= 2


class SmoothTables:
    """The read tables interpolated from their vertex values ``values`` (Color3f of the
    vertex tables (T, V, 2, 3)); ``flat``: the same tables' patch values (a
    :class:`~mi_plugins.solution.gather.FlatTables`), read instead of the interpolation
    in a colour channel where it is negative and the patch's own value is not.

    The field's corrections toward the patch averages can take a vertex beside a bright
    edge below zero (a dark patch under a lit strip, a small refined patch beside a large
    bright one): light that does not exist, down to -0.0036 on a floor whose truth is
    +0.0014. The patch's value is its own estimate of the average there; a negative
    patch value (negative simulated emission) is the solution's, and stays."""

    def __init__(self, table, field, values, flat=None):
        self.table, self.field = table, field
        self.vertices = max(field.vertex_count, 1)
        self.values, self.flat = values, flat

    def __call__(self, hit, index, active):
        patch, element, mesh, a, b = self.table.locate(hit, active)
        ids, w = self.field.weights(element, mesh, a, b, active)
        base = index * self.vertices
        side = side_of(hit)
        value = sum((w[k] * dr.gather(mi.Color3f, self.values, (base + ids[k]) * 2 + side, active)
                     for k in range(4)), mi.Color3f(0.0))
        if self.flat is None:
            return value
        own = self.flat.at(patch * 2 + side, index, active & dr.any(value < 0))
        return dr.select((value < 0) & (own >= 0), own, value)


class View:
    """A solution read by one render: ``mode`` (one of DISPLAYS but 'gather'), the
    scene's patch ``table`` (the solution's patch numbering); ``crowd_reach``, ``steep``:
    the smooth display gathers at the crowded patches (``mi_plugins.patches.crowding``) and
    at the patches of ``steep`` (numpy bool per front patch, or None:
    ``mi_plugins.solution.steep``; the other modes show what the solution stores)."""

    def __init__(self, solution, table, mode, crowd_reach=0.0, steep=None):
        self.mode, self.table, self.solution = mode, table, solution
        smooth = mode == "smooth"
        self.surfaces = Surfaces(table.scene, table, crowd_reach if smooth else 0.0, steep if smooth else None)
        # the gathers' paths read on at the patches the smooth display reads in every mode:
        # a gather reaching a crowded patch (a panel's foot, a corner) goes on, as the smooth
        # display's own camera paths do, instead of reading the light interpolated there
        self.gather_surfaces = self.surfaces if smooth or not crowd_reach else Surfaces(table.scene, table,
                                                                                      crowd_reach)
        self.all_diffuse = bool(np.all(self.surfaces.diffuse_np)) and not self.surfaces.any_unread
        t = solution.tables.shape[0]
        self.read = ReadTables(None if solution.unbounded else t, solution.direct_in_tables)
        self.adds_direct = not solution.direct_in_tables
        flat = FlatTables(table, solution.array("tables", lambda: _color(solution.tables)))
        if mode == "patches":
            self.stored = flat
            # the patches' direct light, where the tables do not carry it already (else none:
            # a gather from a stand-in array read past its end, NaN and 1e35 pixels)
            if self.adds_direct and solution.direct is None:
                raise ValueError("display 'patches': the solution has no direct light of its patches "
                                 "(Solution.complete(scene, table) computes it)")
            self.direct = solution.array("direct", lambda: _color(solution.direct)) if self.adds_direct else None
        else:
            self.stored = SmoothTables(table, solution.field, solution.array(
                "vertex tables", lambda: _color(solution.vertex_values("tables"))), flat)
        if mode == "baked":
            self.baked = SmoothTables(table, solution.field, solution.array("vertex reflected", lambda: _color(
                solution.vertex_values("radiance") - solution.vertex_values("emission"))), FlatTables(
                table, solution.array("reflected", lambda: _color(solution.radiance - solution.emission))))

    def visible(self, scene, si, bsdf, budget, active, numbers):
        """What purely diffuse visible points ``si`` reflect toward the eye (their emission
        comes with the camera path); ``budget``: the segments the path may still add;
        ``numbers``: what draws the light sample and the BSDF sample
        (``mi_plugins.render.pass_numbers``)."""
        f = reflectance_toward(bsdf, si, active)
        if self.mode == "baked":
            return self.baked(si, mi.UInt32(0), active)
        index, readable = self.read.read_table(budget)
        irradiance = dr.select(readable, self.stored(si, index, active & readable), 0.0)
        if self.mode == "patches":
            if self.adds_direct:
                irradiance += dr.gather(mi.Color3f, self.direct, patch_side(self.table, si), active)
            return f * irradiance
        value = f * irradiance
        if self.adds_direct:       # a light sample, and near emitters a BSDF sample too (MIS)
            light_sample = numbers.next_2d()
            value += direct_light(scene, si, bsdf, light_sample, active, (numbers.next_1d(), numbers.next_2d()),
                                  mis=needs_bsdf_sample(scene, si, bsdf))
        return value


def gather_elsewhere(paths, seed, gather_samples, chain, used, lanes, numbers=None):
    """The gather of ``qmc_gather`` at the visible points of ``lanes`` only (the points the
    display does not read: glossy, mixed, bump-mapped), run on those lanes alone: their
    rays (``chain.ray``) found again there, so that no surface interaction of every lane
    is ever stored. ``numbers``: what draws the gather's numbers for every lane (a camera
    pass's, ``mi_plugins.render.pass_numbers``), else a stream of ``seed``."""
    # a sampler's numbers are drawn for every lane, the Sobol points of the gathering lanes alone
    drawn = draw_numbers(numbers, gather_samples) if numbers is not None and not isinstance(
        numbers, PixelSobol) else None
    dr.eval(chain.ray, used, lanes, drawn)
    index = dr.compress(lanes)
    total = dr.zeros(mi.Color3f, dr.width(lanes))
    if dr.width(index) == 0:
        return total
    if drawn is not None:
        drawn = [dr.gather(mi.Point2f, drawn[0], index)] + [
            (dr.gather(mi.Float, u1, index), dr.gather(mi.Point2f, u2, index)) for u1, u2 in drawn[1:]]
    elif numbers is not None:
        drawn = draw_numbers(numbers.subset(index), gather_samples)
    ray = dr.gather(mi.Ray3f, chain.ray, index)
    at = paths.scene.ray_intersect(ray)
    light, gathered = paths.gather(None, seed, gather_samples, at, at.bsdf(ray), dr.gather(mi.UInt32, used, index),
                                   dr.full(mi.Bool, True, dr.width(index)), drawn)
    dr.scatter(total, light + gathered, index)
    return total


def with_residual(paths, seed, gather_samples, chain, used, read, value, share):
    """``value`` at the read points ``read`` (the display's reading of the solution) made
    unbiased against the gather: a random ``share`` of those lanes also gathers
    (:func:`gather_elsewhere`, on a stream of their own) and adds (gather - value) / share.
    The expected value of every lane is then the gather's, whatever the solution's
    reconstruction error there; the price is the gather's noise over ``share``."""
    pick = seeds.pcg(dr.width(read), seed, "residual")
    check = read & (pick.next_float32(read) < share)
    gathered = gather_elsewhere(paths, seeds.stream(seed, "residual", 1), gather_samples, chain, used, check)
    return value + dr.select(check, (gathered - value) / share, 0.0)


def pass_layout(spp, pixels):
    """(camera samples per pixel and pass, passes): spp = their product, one pass at
    most MAX_PASS_LANES lanes (the largest divisor of spp that fits)."""
    fit = max(1, MAX_PASS_LANES // max(pixels, 1))
    per_pixel = max(d for d in range(1, min(spp, fit) + 1) if spp % d == 0)
    return per_pixel, spp // per_pixel


def lattice(count):
    """``count`` points of the unit square, the first (0, 0): the rank-1 lattice
    (i / count, i g / count mod 1) of the generator g nearest count / golden ratio that is
    prime to count (a Fibonacci lattice where count is a Fibonacci number: no two points
    share a row or a column, so a lamp's straight edge cuts them evenly); shifted by a
    uniform point, each point is uniform and together they stratify the pixel."""
    if count == 1:
        return [(0.0, 0.0)]
    g = min((k for k in range(1, count) if np.gcd(k, count) == 1), key=lambda k: abs(k - count / 1.6180339887))
    return [(i / count, (i * g % count) / count) for i in range(count)]


def emission_shares(frame, cam, chain, edges, state, block="camera"):
    """The emission seen directly by the camera samples in the pixels of ``edges``
    (:func:`edge_pixels`), from further rays: each such sample's own first segment gives
    way to a lattice of ``len(shifts)`` rays through its pixel (``camera.lattice_rays``,
    the lattice at a uniform shift drawn for the sample: every ray is uniform in the pixel,
    together they stratify it), each weighing 1 / len(shifts). The lattice rays run in a
    kernel of their own over the edge pixels' samples only (``state``: the seed of their
    streams), so the other lanes trace nothing. Returns the correction of the lanes'
    camera value. With a box filter every ray of a sample lands in the sample's pixel with
    the same filter weight: the rays' emission is added to the camera block at weight 0.
    Any other filter weighs the rays by their own positions: the emission then goes into a
    block of its own, every camera sample weighing in (weight 1, or 1 / len(shifts) per
    ray of the edge pixels), so that its normalisation is the camera samples'. ``cam``: a
    camera pass (``box``, ``pos``, ``weight``, ``sensor``, ``grid_pixel``, ``per_pixel``);
    ``block``: its camera block."""
    shifts, mask, pixels = edges
    share = 1.0 / len(shifts)
    on = dr.gather(mi.Bool, mask, cam.grid_pixel)
    if not cam.box:
        frame.put_emission(cam.pos, chain.first * cam.weight, dr.select(on, 0.0, 1.0))
    for ray, weight, pos, corner in lattice_rays(cam.sensor, pixels, cam.per_pixel, shifts, state):
        seen = seen_emission(frame.scene, ray) * weight
        if cam.box:
            frame.put_camera_share(corner, seen * share, dr.any(seen != 0.0), block)
        else:
            frame.put_emission(pos, seen, share)
    return dr.select(on, -chain.first, 0.0) if cam.box else -chain.first


def edge_pixels(frame, max_depth, hide_emitters, emitter_samples):
    """(shifts, mask, pixels): the lattice of ``emitter_samples`` points and the grid
    pixels whose camera samples take further rays for the emission they see (Bool per grid
    pixel, and their indices: the pixels whose rays through a centred copy of the lattice
    see different emission, and their neighbours: ``camera.emission_edges``); None where no
    pixel does, the sensor's rays ignore the film position or ``emitter_samples`` is 1. The
    pixels on a lamp's edge see it or not by chance: the stratified rays cut that noise
    more than their number, at the cost of a camera ray each (the full surface interaction
    only where they hit an emitting shape); elsewhere nothing is traced."""
    scene = frame.scene
    if emitter_samples < 2 or max_depth == 0 or hide_emitters or not (
            scene.environment() is not None or any(e.get_shape() is not None for e in scene.emitters())):
        return None
    shifts = lattice(emitter_samples)
    half = 0.5 / emitter_samples
    mask = emission_edges(frame, [((x + half) % 1.0, (y + half) % 1.0) for x, y in shifts])
    if mask is None or not mask.any():
        return None
    return shifts, jit(mi.Bool, mask), jit(mi.UInt32, np.flatnonzero(mask))


def with_edges(frame, cam, chain, edges, value, state, block="camera"):
    """A camera pass's ``value`` (before the sensor's weight; ``block``: its camera block)
    with the emission that its first segment sees averaged with further rays in the pixels
    of ``edges`` (:func:`emission_shares`, :func:`edge_pixels`; None: ``value`` as it is);
    ``state``: the seed of the further rays' streams, an opaque UInt64, or an int (the pass's
    seed, whose stream it then takes)."""
    if edges is None or not cam.film_rays:
        return value
    if not isinstance(state, mi.UInt64):
        state = dr.opaque(mi.UInt64, seeds.stream(int(state), "camera_path", 4))
    return value + emission_shares(frame, cam, chain, edges, state, block)


def render(frame, view, max_depth, mirror_depth, hide_emitters, gather_samples, steps=None, emitter_samples=1,
           residual=0.0):
    """The image of ``frame`` from ``view`` (spp camera samples per pixel, in passes);
    ``steps``: the render's step driver (one step per pass), or None; ``emitter_samples``:
    camera rays per camera sample for the emission seen directly (:func:`edge_pixels`);
    ``residual``: the share of the camera samples at read points that also gather
    (:func:`with_residual`; 0: none)."""
    scene, table = frame.scene, view.table
    edges = edge_pixels(frame, max_depth, hide_emitters, emitter_samples)
    paths = CameraPaths(scene, table, view.gather_surfaces, view.read, view.stored, max_depth, mirror_depth,
                        hide_emitters)
    per_pixel, passes = pass_layout(frame.spp, frame.sample_pixels())
    frame.camera_passes(per_pixel, passes)
    def step(k):
        cam = frame.camera_pass()
        seed = seeds.stream(frame.seed, "display", k)
        chain, si, bsdf, used, active = paths.visible_points(cam, seed, evaluate=False)
        diffuse = view.surfaces.readable(si, active)       # (elsewhere: gathered)
        numbers = pass_numbers(cam, seeds.stream(frame.seed, "display"), k)
        value = view.visible(scene, si, bsdf, paths.depth - mi.Int32(used), diffuse, numbers)
        if residual > 0:
            value = with_residual(paths, seeds.stream(frame.seed, "residual", k), gather_samples, chain, used,
                                  diffuse, value, residual)
        if not view.all_diffuse:     # (purely diffuse surfaces, no gap's mouth: nothing to gather)
            value += gather_elsewhere(paths, seed, gather_samples, chain, used, active & ~diffuse, numbers)
        value = chain.emission + chain.throughput * value
        value = with_edges(frame, cam, chain, edges, value, seed)
        frame.put_camera(cam, value, coverage=coverage(scene, chain.surface, hide_emitters))

    run_steps(frame, steps, step, stage=range(passes) if steps is None else steps.second_stage(passes))
