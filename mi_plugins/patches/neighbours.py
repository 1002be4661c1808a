"""Sharing of per-sample estimates between neighbouring pixels (``qmc_lighttrace``'s
``share_neighbors``): camera samples laid out pixel by pixel (``CameraPass``), each
averaged with the samples of the same number in the 3 x 3 neighbourhood that see the same
patch side."""
import drjit as dr
import mitsuba as mi


def share_with_neighbours(gather, tri, cam):
    """Average each gather result with those of the 8 neighbouring pixels (same sample
    number) whose eye ray hit the same side of the same triangle."""
    width, height, spp = cam.grid_width, cam.grid_height, cam.per_pixel
    lane = dr.arange(mi.UInt32, cam.count)
    pixel, s = lane // spp, lane % spp
    x, y = mi.Int32(pixel % width), mi.Int32(pixel // width)
    total, count = dr.zeros(mi.Color3f, dr.width(lane)), dr.zeros(mi.Float, dr.width(lane))
    for dx, dy in ((dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)):   # the 3 x 3 neighbourhood
        nx, ny = x + dx, y + dy
        inside = (nx >= 0) & (nx < width) & (ny >= 0) & (ny < height)
        other = mi.UInt32(dr.select(inside, ny * width + nx, 0)) * spp + s
        same = inside & (dr.gather(mi.UInt32, tri, other, inside) == tri) & (tri != 0xFFFFFFFF)
        total += dr.select(same, dr.gather(mi.Color3f, gather, other, same), 0.0)
        count += dr.select(same, 1.0, 0.0)
    return dr.select(count > 0, total / dr.maximum(count, 1.0), gather)
