"""Furniture and textures of the interior benchmark scenes (`interiors.py`), in metres, z up.

Each builder returns {material group: triangles (T, 3, 3)} (see `interior_geometry.py`),
merged by :func:`merge`; the scenes give each group a material. Groups: ``wood`` (table
tops: rough plastic), ``dark`` (chairs), ``metal`` (legs, handles: rough aluminium),
``fabric`` (sofa), ``shelf``, ``books0`` .. ``books4``, ``trim`` (skirting, frames),
``door``. Textures are small generated bitmaps (linear RGB, albedo 0.15-0.55).
"""
import numpy as np

import interior_geometry as ig

BOOK_COLOURS = 5


def merge(*parts):
    """{group: triangles} of several builders' outputs, concatenated per group."""
    out = {}
    for part in parts:
        for group, tris in part.items():
            out.setdefault(group, []).append(np.asarray(tris, np.float64).reshape(-1, 3, 3))
    return {group: np.concatenate(t) for group, t in out.items()}


def table(centre, size=(1.6, 0.9), height=0.75, top=0.04, leg=0.025):
    """Rectangular table: a top (``wood``) on four round legs (``metal``)."""
    (cx, cy), (sx, sy) = centre, size
    lo, hi = [cx - sx / 2, cy - sy / 2, height - top], [cx + sx / 2, cy + sy / 2, height]
    inset = 0.08
    legs = [[cx + a * (sx / 2 - inset), cy + b * (sy / 2 - inset), 0.0] for a in (-1, 1) for b in (-1, 1)]
    return {"wood": ig.boxes(lo, hi), "metal": ig.cylinders(legs, leg, height - top, 12)}


def chair(position, facing):
    """A chair at (x, y) whose sitter faces ``facing`` (a unit (dx, dy) along x or y):
    seat and back (``dark``), four thin legs (``metal``)."""
    x, y = position
    dx, dy = facing
    h = 0.22
    seat = ig.boxes([x - h, y - h, 0.44], [x + h, y + h, 0.48])
    bx, by = x - dx * (h - 0.015), y - dy * (h - 0.015)       # the back, behind the sitter
    half = np.abs([dy, dx]) * h + np.abs([dx, dy]) * 0.015
    back = ig.boxes([bx - half[0], by - half[1], 0.48], [bx + half[0], by + half[1], 0.92])
    legs = [[x + a * (h - 0.03), y + b * (h - 0.03), 0.0] for a in (-1, 1) for b in (-1, 1)]
    return {"dark": np.concatenate([seat, back]), "metal": ig.cylinders(legs, 0.012, 0.44, 8)}


def sofa(lo, hi, back_side):
    """A sofa filling the floor box [lo, hi] (x, y), its back along the side ``back_side``
    ('x0', 'x1', 'y0' or 'y1' of the box), arms at both ends."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    axis, end = ("xy".index(back_side[0]), int(back_side[1]))
    base = ig.boxes(np.append(lo, 0.0), np.append(hi, 0.42))
    back_lo, back_hi = lo.copy(), hi.copy()
    if end:
        back_lo[axis] = hi[axis] - 0.25
    else:
        back_hi[axis] = lo[axis] + 0.25
    other = 1 - axis
    arm_lo, arm_hi = np.array([lo, lo]), np.array([hi, hi])
    arm_hi[0, other], arm_lo[1, other] = lo[other] + 0.15, hi[other] - 0.15
    back = ig.boxes(np.append(back_lo, 0.42), np.append(back_hi, 0.85))
    arms = ig.boxes(np.concatenate([arm_lo, [[0.42], [0.42]]], 1), np.concatenate([arm_hi, [[0.62], [0.62]]], 1))
    return {"fabric": np.concatenate([base, back, arms])}


def bookshelf(x0, x1, wall_y, into, height=2.0, depth=0.36, shelves=5, seed=0):
    """Shelves against the wall y = ``wall_y`` (the room on the side ``into`` = +1 or -1):
    sides, boards and back (``shelf``), rows of books of random size (``books0`` ..)."""
    y_wall, y_front = wall_y, wall_y + into * depth
    ya, yb = min(y_wall, y_front), max(y_wall, y_front)
    t = 0.02
    levels = np.linspace(0.0, height - t, shelves + 1)
    frame = ig.boxes([[x0, ya, 0.0], [x1 - t, ya, 0.0]], [[x0 + t, yb, height], [x1, yb, height]])
    boards = ig.boxes(np.stack([np.full(shelves + 1, x0 + t), np.full(shelves + 1, ya), levels], 1),
                      np.stack([np.full(shelves + 1, x1 - t), np.full(shelves + 1, yb), levels + t], 1))
    back_y = (y_wall, y_wall + into * 0.01)
    back = ig.boxes([x0, min(back_y), 0.0], [x1, max(back_y), height])
    rng = np.random.default_rng(seed)
    books = {}
    for level in levels[:-1]:
        widths = rng.uniform(0.02, 0.05, 64)
        xs = x0 + t + 0.01 + np.concatenate([[0.0], np.cumsum(widths + 0.003)])[:-1]
        n = int(np.sum(xs + widths < x1 - t - 0.15 * rng.uniform()))
        xs, widths = xs[:n], widths[:n]
        hgt = np.minimum(rng.uniform(0.17, 0.3, n), levels[1] - levels[0] - t - 0.02)
        dep = rng.uniform(0.18, 0.28, n)
        yf = y_wall + into * 0.012
        lo = np.stack([xs, np.minimum(yf, yf + into * dep), np.full(n, level + t)], 1)
        hi = np.stack([xs + widths, np.maximum(yf, yf + into * dep), level + t + hgt], 1)
        colour = rng.integers(0, BOOK_COLOURS, n)
        for c in range(BOOK_COLOURS):
            if np.any(colour == c):
                books.setdefault("books%d" % c, []).append(ig.boxes(lo[colour == c], hi[colour == c]))
    return merge({"shelf": np.concatenate([frame, boards, back])},
                 {k: np.concatenate(v) for k, v in books.items()})


def skirting(x0, y0, x1, y1, height=0.08, thickness=0.015, gaps=()):
    """Skirting boards (``trim``) along the four walls of the floor rectangle, except
    along the wall intervals ``gaps`` [(axis 'x' or 'y', wall coordinate, a, b)] (doors)."""
    out = []
    for axis, wall, a, b, into in (("y", y0, x0, x1, 1), ("y", y1, x0, x1, -1), ("x", x0, y0, y1, 1),
                                   ("x", x1, y0, y1, -1)):
        cuts = sorted((g[2], g[3]) for g in gaps if g[0] == axis and abs(g[1] - wall) < 1e-9)
        edges = [a] + [e for c in cuts for e in c] + [b]
        for s, e in zip(edges[0::2], edges[1::2]):
            if e - s < 1e-6:
                continue
            w = sorted((wall, wall + into * thickness))
            lo, hi = ([s, w[0], 0.0], [e, w[1], height]) if axis == "y" else ([w[0], s, 0.0], [w[1], e, height])
            out.append(ig.boxes(lo, hi))
    return {"trim": np.concatenate(out)}


def door(axis, wall, into, a, width=0.9, height=2.05):
    """A door leaf (``door``) standing 3 cm out of the wall at coordinate ``wall`` (normal
    along ``axis`` 'x' or 'y', the room on the side ``into``), from ``a`` along the wall;
    a frame (``trim``) and a lever handle (``metal``)."""
    def box(s0, s1, d0, d1, z0, z1):          # s: along the wall, d: out of it
        d = sorted((wall + into * d0, wall + into * d1))
        return ig.boxes([s0, d[0], z0], [s1, d[1], z1]) if axis == "y" else ig.boxes([d[0], s0, z0], [d[1], s1, z1])
    leaf = box(a, a + width, 0.0, 0.03, 0.0, height)
    frame = np.concatenate([box(a - 0.06, a, 0.0, 0.045, 0.0, height + 0.06),
                            box(a + width, a + width + 0.06, 0.0, 0.045, 0.0, height + 0.06),
                            box(a, a + width, 0.0, 0.045, height, height + 0.06)])
    handle = np.concatenate([box(a + width - 0.1, a + width - 0.08, 0.03, 0.09, 1.0, 1.02),
                             box(a + width - 0.22, a + width - 0.08, 0.07, 0.09, 1.0, 1.02)])
    return {"door": leaf, "trim": frame, "metal": handle}


def plant(x, y, seed, k=20, height=0.9):
    """A pot (``pot``, rough plastic) holding a 'scanned' leafy blob (``leaves``, 20 k^2 triangles)."""
    pot = ig.lathe([0.14, 0.18, 0.17], [0.0, 0.32, 0.34], (x, y, 0.0), 32)
    leaves = ig.scanned(k, 0.3, (x, y, 0.3), seed=seed, stretch=(1.0, 1.0, (height - 0.3) / 0.6))
    return {"pot": pot, "leaves": leaves}


# ---------------------------------------------------------------------------- textures
def wood_planks(seed=0, size=256, planks=8):
    """Floor boards along u: per-plank tone, grain along v, dark joints (linear RGB, about 0.15-0.45)."""
    rng = np.random.default_rng(seed)
    v, u = np.meshgrid(np.linspace(0, 1, size, endpoint=False), np.linspace(0, 1, size, endpoint=False),
                       indexing="ij")
    plank = np.floor(u * planks).astype(int)
    tone = rng.uniform(0.7, 1.0, planks)[plank]
    offset = rng.uniform(0, 1, planks)[plank]
    grain = 0.85 + 0.15 * np.sin(2 * np.pi * (6 * (v + offset) + 0.8 * np.sin(2 * np.pi * 3 * u * planks)))
    joint = np.where((u * planks) % 1.0 < 0.04, 0.45, 1.0) * np.where(((v + offset) * 2) % 1.0 < 0.01, 0.5, 1.0)
    base = np.array([0.45, 0.30, 0.17])
    return (base * (tone * grain * joint)[..., None]).astype(np.float32)


def floor_tiles(seed=1, size=256, tiles=4):
    """Linoleum tiles: two greys in a checker, speckles, dark joints (linear RGB, about 0.2-0.5)."""
    rng = np.random.default_rng(seed)
    v, u = np.meshgrid(np.linspace(0, 1, size, endpoint=False), np.linspace(0, 1, size, endpoint=False),
                       indexing="ij")
    checker = ((np.floor(u * tiles) + np.floor(v * tiles)) % 2)[..., None]
    base = np.where(checker > 0, [0.46, 0.45, 0.42], [0.36, 0.36, 0.35])
    speckle = 1.0 + 0.12 * (rng.random((size, size, 1)) - 0.5)
    joint = np.where(((u * tiles) % 1.0 < 0.02) | ((v * tiles) % 1.0 < 0.02), 0.55, 1.0)[..., None]
    return (base * speckle * joint).astype(np.float32)
