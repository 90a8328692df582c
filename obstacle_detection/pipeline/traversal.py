"""Robot-level traversability (not in the seed): reach from the floor, steps, ledges, drops.

The rules: docs/method.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order

from . import jit
from ._compiled import ledges as jit_ledges
from ._compiled import traversal as jit_traversal
from .geometry import GroundRays
from .params import DetectorParams

#: The 8 neighbours of a cell as (dx, dy); the search adds both directions of each pair.
_HALF_NEIGHBOURHOOD = ((1, 0), (0, 1), (1, 1), (1, -1))
#: Flat voxels a cell's surface needs within one voxel height (of the 4 a 2 x 2 voxel cell
#: holds) to pass the robot on: a few stray or flying voxels do not make a floor.
MIN_SURFACE_VOXELS = 3
#: Rows below an over-the-edge pixel searched for the floor it passed [px].
DROP_EDGE_ROWS = 3
#: A pixel this share of its depth away from both the nearest and the farthest depth of its
#: window is a mixed (flying) pixel, unless it lies on a plane with its neighbours (_planar).
FLYING_JUMP = 0.03
#: Largest second difference of the inverse depth, as a share of it, of a pixel on a plane.
PLANAR_TOLERANCE = 0.02
#: Cells searched beyond an open side for the lower ground in its shadow [cells].
LEDGE_SHADOW_CELLS = 12
#: The 8 directions of the search across an edge, as (dx, dy) cell steps.
_DIRECTIONS = np.array(((1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)))
#: Voxels below a marked one in which the foot of an object is looked for (:func:`feet`).
FOOT_VOXELS = 3
#: Window of the flying-pixel test [px] (the compiled smear pass computes 5 x 5 only).
FLYING_WINDOW_PX = 5
#: A pixel whose median window is at least this share no return keeps its measured depth,
#: and a hole there stays one (docs/method.md).
MEDIAN_HOLE_SHARE = 0.2


@dataclass(frozen=True)
class Traversal:
    """Robot-level decision per voxel, (V,) arrays; height_m above the local ground [m]."""

    is_obstacle: np.ndarray
    above_robot: np.ndarray
    height_m: np.ndarray
    ledge: np.ndarray


def traversable_ground(points: np.ndarray, steep: np.ndarray,
                       params: DetectorParams) -> Traversal:
    """Decide obstacles at robot level: points (V, 3) float32 ground frame, steep (V,) bool."""
    size = 2.0 * max(params.voxel_x_m, params.voxel_y_m)   # cells of 2 x 2 voxels
    if points.shape[0] == 0:
        empty = np.zeros(0, bool)
        return Traversal(empty, empty, np.zeros(0, np.float32), empty)
    out = _traverse(points, steep, size, params.max_step_height_m, params.max_step_down_m,
                    params.robot_height_m, params.voxel_z_m, MIN_SURFACE_VOXELS)
    edge = ledges(points, steep, out[3], out[1], size, params.max_step_height_m,
                  params.max_step_down_m, LEDGE_SHADOW_CELLS)
    return Traversal(out[0], out[1], out[2], edge)


def _voxel_ijk(points: np.ndarray, vx: float, vy: float, vz: float) -> np.ndarray:
    """(V, 3) int64 voxel indices from 1: ``floor(p / v) + 1 - min`` (the kernels' layout)."""
    ijk = np.floor(points / np.array((vx, vy, vz), np.float32)).astype(np.int64)
    return ijk + (1 - ijk.min(axis=0))


def _reference_lone_voxels(points: np.ndarray, vx: float, vy: float, vz: float) -> np.ndarray:
    """(V,) bool: no other voxel lies in the 26 voxels around the voxel (numpy)."""
    ijk = _voxel_ijk(points, vx, vy, vz)
    grid = np.zeros(tuple(ijk.max(axis=0) + 2), bool)
    grid[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    lone = np.ones(points.shape[0], bool)
    for d in np.ndindex(3, 3, 3):
        if d != (1, 1, 1):
            lone &= ~grid[ijk[:, 0] + d[0] - 1, ijk[:, 1] + d[1] - 1, ijk[:, 2] + d[2] - 1]
    return lone


def lone_voxels(points: np.ndarray, vx: float, vy: float, vz: float) -> np.ndarray:
    """(V,) bool: voxels (centroids (V, 3) [m]) with no other among their 26 neighbours."""
    if points.shape[0] == 0:
        return np.zeros(0, bool)
    return _lone_voxels(points, vx, vy, vz)


_lone_voxels = jit.choose(_reference_lone_voxels, jit_ledges.lone_voxels)


def _reference_feet(points: np.ndarray, candidates: np.ndarray, marked: np.ndarray, vx: float,
                    vy: float, vz: float, reach: int) -> np.ndarray:
    """(V,) bool: candidates, not marked, with a marked voxel 1 to reach voxels above (numpy)."""
    ijk = _voxel_ijk(points, vx, vy, vz)
    top = ijk.max(axis=0) + 1
    top[2] += reach
    grid = np.zeros(tuple(top), bool)
    grid[ijk[marked, 0], ijk[marked, 1], ijk[marked, 2]] = True
    foot = np.zeros(points.shape[0], bool)
    for up in range(1, reach + 1):
        foot |= grid[ijk[:, 0], ijk[:, 1], ijk[:, 2] + up]
    return foot & candidates & ~marked


def feet(points: np.ndarray, candidates: np.ndarray, marked: np.ndarray, vx: float, vy: float,
         vz: float) -> np.ndarray:
    """(V,) bool: candidates 1 to ``FOOT_VOXELS`` voxels under a marked voxel."""
    if points.shape[0] == 0:
        return np.zeros(0, bool)
    return _feet(points, candidates, marked, vx, vy, vz, FOOT_VOXELS)


_feet = jit.choose(_reference_feet, jit_ledges.feet)


def _cells(points: np.ndarray, size_m: float) -> tuple[np.ndarray, int, int, int, int]:
    """(key (V,) int64, nx, ny, ox, oy): each point's cell ``floor(p / size) - (ox, oy)``."""
    size = np.float32(size_m)
    ix = np.floor(points[:, 0] / size).astype(np.int64)
    iy = np.floor(points[:, 1] / size).astype(np.int64)
    ox, oy = int(ix.min()), int(iy.min())
    ix -= ox
    iy -= oy
    ny = int(iy.max()) + 1
    return ix * ny + iy, int(ix.max()) + 1, ny, ox, oy


def _reference_ledges(points: np.ndarray, steep: np.ndarray, reached: np.ndarray,
                      above: np.ndarray, size_m: float, step_up_m: float, step_down_m: float,
                      shadow_cells: int) -> np.ndarray:
    """(V,) bool: voxels on the open side of a raised traversable surface (docs/method.md)."""
    if points.shape[0] == 0:
        return np.zeros(0, bool)
    key, nx, ny, ox, oy = _cells(points, size_m)
    z = points[:, 2].astype(np.float64)
    flat = reached & ~steep
    surface = np.full(nx * ny, np.inf)
    np.minimum.at(surface, key[flat], z[flat])
    surface = surface.reshape(nx, ny)
    low = minimum_filter(surface, size=3, mode='constant', cval=np.inf)
    top = np.where(np.isfinite(surface), surface, -np.inf)
    high = maximum_filter(top, size=3, mode='constant', cval=-np.inf)
    seen = np.zeros(nx * ny, bool)
    seen[key] = True
    seen = seen.reshape(nx, ny)
    lowest = np.full(nx * ny, np.inf)
    np.minimum.at(lowest, key[~steep], z[~steep])
    _lower_beyond_gaps(surface, lowest.reshape(nx, ny), seen, low, ox, oy, shadow_cells)
    with np.errstate(invalid='ignore'):
        # two surfaces within the floor's band (the seeds') are both floor: no ledge
        floor_low = (low >= -step_down_m) & (low <= step_up_m)
        raised = (surface - low > step_down_m)                    # a reached cell's
        raised &= ~(floor_low & (surface >= -step_down_m) & (surface <= step_up_m))
        face = (high - low > step_up_m) & ~(floor_low & (high >= -step_down_m)
                                            & (high <= step_up_m))
        raised = raised.reshape(-1)[key]
        low = low.reshape(-1)[key]
        floor_low = floor_low.reshape(-1)[key]
        # a cell the edge crosses holds both surfaces: its raised voxels, by their own z
        raised |= flat & (z - low > step_down_m) & ~(floor_low & (z >= -step_down_m)
                                                     & (z <= step_up_m))
        face = face.reshape(-1)[key] & (z - low > step_up_m)
    return np.where(reached, raised, face) & ~above


def _lower_beyond_gaps(surface: np.ndarray, lowest: np.ndarray, seen: np.ndarray,
                       low: np.ndarray, ox: int, oy: int, shadow_cells: int) -> None:
    """In place: ``low`` of a cell beside a gap, to the lowest surface beyond it (away)."""
    nx, ny = surface.shape
    empty_nb = minimum_filter(seen, size=3, mode='constant', cval=True) == 0
    cx, cy = np.nonzero(np.isfinite(surface) & empty_nb)
    # every (cell, direction) pair at once, walked k cells out
    sx = np.repeat(_DIRECTIONS[:, 0][None, :], cx.size, axis=0).reshape(-1)
    sy = np.repeat(_DIRECTIONS[:, 1][None, :], cx.size, axis=0).reshape(-1)
    wx = np.repeat(cx, 8)
    wy = np.repeat(cy, 8)
    owner = np.repeat(np.arange(cx.size), 8)
    # the gap lies behind the edge, seen from the camera: each step component leads away
    going = (sx * (wx + ox + 0.5) >= 0.0) & (sy * (wy + oy + 0.5) >= 0.0)
    wx, wy, sx, sy, owner = wx[going], wy[going], sx[going], sy[going], owner[going]
    beyond = np.full(cx.size, np.inf)
    for k in range(1, shadow_cells + 1):
        wx = wx + sx
        wy = wy + sy
        inside = (wx >= 0) & (wx < nx) & (wy >= 0) & (wy < ny)
        wx, wy, sx, sy, owner = wx[inside], wy[inside], sx[inside], sy[inside], owner[inside]
        if wx.size == 0:
            break
        hit = seen[wx, wy]
        if k > 1:   # the first cell beyond a gap (next to it, the 8 neighbours decide)
            np.minimum.at(beyond, owner[hit], lowest[wx[hit], wy[hit]])
        gap = ~hit
        wx, wy, sx, sy, owner = wx[gap], wy[gap], sx[gap], sy[gap], owner[gap]
    low[cx, cy] = np.minimum(low[cx, cy], beyond)


ledges = jit.choose(_reference_ledges, jit_ledges.ledges)


def _reference_traverse(points: np.ndarray, steep: np.ndarray, size_m: float, step_up_m: float,
                        step_down_m: float, robot_height_m: float, layer_m: float,
                        min_support: int = MIN_SURFACE_VOXELS,
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(obstacle, above, height float32, reached) per voxel, in numpy (the reference)."""
    key, nx, ny, _, _ = _cells(points, size_m)
    z = points[:, 2].astype(np.float64)

    surface = np.full(nx * ny, np.inf)
    flat = ~steep
    np.minimum.at(surface, key[flat], z[flat])
    low = np.full(nx * ny, np.inf)
    high = np.full(nx * ny, -np.inf)
    np.minimum.at(low, key, z)
    np.maximum.at(high, key, z)
    # a cell can be driven through when it has a surface, well supported (not a few stray
    # or flying voxels), and no step inside it
    on_surface = flat & (z <= surface[key] + layer_m)
    support = np.bincount(key[on_surface], minlength=nx * ny)
    passable = np.isfinite(surface) & (high - low <= step_up_m)
    passable &= support >= min_support
    seeds = passable & (surface >= -step_down_m) & (surface <= step_up_m)
    reached = _grow(surface.reshape(nx, ny), passable.reshape(nx, ny), seeds, step_up_m,
                    step_down_m)
    ground = _local_ground(surface.reshape(nx, ny), reached.reshape(nx, ny)).reshape(-1)
    height = (z - ground[key]).astype(np.float32)
    above = height > np.float32(robot_height_m)
    obstacle = (height > np.float32(step_up_m)) & ~above
    obstacle |= height < -np.float32(step_down_m)
    return obstacle, above, height, reached[key]


_traverse = jit.choose(_reference_traverse, jit_traversal.traverse)


def _local_ground(surface: np.ndarray, reached: np.ndarray) -> np.ndarray:
    """Ground height (nx, ny): the surface where reached, else the highest neighbour's, grown."""
    if not reached.any():
        return np.zeros(surface.shape)
    ground = np.where(reached, surface, 0.0)
    done = reached.copy()
    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    while not done.all():   # layer by layer: the largest ground of the 8 neighbours filled
        best = maximum_filter(np.where(done, ground, -np.inf), footprint=ring, mode='constant',
                              cval=-np.inf)
        new = ~done & (best > -np.inf)
        ground[new] = best[new]
        done |= new
    return ground


def _grow(surface: np.ndarray, has: np.ndarray, seeds: np.ndarray, step_up: float,
          step_down: float) -> np.ndarray:
    """Cells (nx * ny,) bool reachable from the seeds through allowed steps (8-connected)."""
    nx, ny = surface.shape
    index = np.arange(nx * ny).reshape(nx, ny)
    src, dst = [], []
    for dx, dy in _HALF_NEIGHBOURHOOD:
        xs = slice(0, nx - dx)
        ys = slice(max(0, -dy), ny - max(0, dy))
        xt = slice(dx, nx)
        yt = slice(max(0, dy), ny - max(0, -dy))
        a_has, b_has = has[xs, ys], has[xt, yt]
        with np.errstate(invalid='ignore'):               # inf - inf where no surface
            rise = surface[xt, yt] - surface[xs, ys]      # a -> b
        both = a_has & b_has
        a_idx, b_idx = index[xs, ys], index[xt, yt]
        forward = both & (rise <= step_up) & (-rise <= step_down)
        backward = both & (-rise <= step_up) & (rise <= step_down)
        src += [a_idx[forward], b_idx[backward]]
        dst += [b_idx[forward], a_idx[backward]]
    source = nx * ny                                      # a virtual node linked to the seeds
    seed_idx = np.flatnonzero(seeds)
    src.append(np.full(seed_idx.size, source))
    dst.append(seed_idx)
    rows, cols = np.concatenate(src), np.concatenate(dst)
    graph = csr_matrix((np.ones(rows.size, np.int8), (rows, cols)),
                       shape=(source + 1, source + 1))
    order = breadth_first_order(graph, source, directed=True, return_predecessors=False)
    reached = np.zeros(source + 1, bool)
    reached[order] = True
    return reached[:source]


def _planar(raw: np.ndarray, tolerance: float = PLANAR_TOLERANCE) -> np.ndarray:
    """(H, W) bool: inverse-depth second differences within ``tolerance`` of it (a plane)."""
    with np.errstate(divide='ignore', invalid='ignore'):
        inv = np.where(raw > 0.0, np.float32(1.0) / raw, np.float32(np.nan))
    tol = np.float32(tolerance) * inv
    out = np.zeros(raw.shape, bool)
    with np.errstate(invalid='ignore'):
        row = np.abs(inv[:, :-2] + inv[:, 2:] - np.float32(2.0) * inv[:, 1:-1])
        col = np.abs(inv[:-2, :] + inv[2:, :] - np.float32(2.0) * inv[1:-1, :])
        out[1:-1, 1:-1] = (row[1:-1] <= tol[1:-1, 1:-1]) & (col[:, 1:-1] <= tol[1:-1, 1:-1])
    return out


def drop_smeared(filtered: np.ndarray, raw: np.ndarray, max_shift: float, *,
                 raw_no_nan: bool = False) -> np.ndarray:
    """In place: undo what the median smeared across depth edges (rules: docs/method.md).

    filtered, raw: (H, W) float32 [m], filtered and measured; raw_no_nan: raw holds no NaN.
    """
    if max_shift <= 0.0:
        return filtered
    raw = np.ascontiguousarray(raw, np.float32)
    # the compiled pass's window range orders NaN its own way: raw with NaN takes numpy's
    smear = _drop_smeared if raw_no_nan or not np.isnan(raw).any() else _drop_smeared.reference
    smear(filtered, raw, max_shift, FLYING_JUMP, PLANAR_TOLERANCE)
    return filtered


def unbias_holes(filtered: np.ndarray, raw: np.ndarray, kernel: int) -> np.ndarray:
    """Undo the median (window ``kernel``) where ``MEDIAN_HOLE_SHARE`` of it was no return."""
    area = kernel * kernel
    most = area - int(np.ceil(MEDIAN_HOLE_SHARE * area))   # returns in a window still biased
    return _unbias_holes(filtered, np.ascontiguousarray(raw, np.float32), kernel, most)


def _reference_unbias_holes(filtered: np.ndarray, raw: np.ndarray, kernel: int,
                            most: int) -> np.ndarray:
    """:func:`unbias_holes` where at most ``most`` pixels of the window returned (numpy, cv2)."""
    returned = cv2.compare(raw, 0.0, cv2.CMP_GT)   # 255 or 0 (NaN: 0)
    count = cv2.boxFilter(returned, cv2.CV_32F, (kernel, kernel), normalize=False,
                          borderType=cv2.BORDER_REPLICATE)
    biased = count <= np.float32(255 * most)
    returned = returned != 0
    back = (biased & returned & (filtered > 0.0)).view(np.uint8)
    hole = (biased & ~returned).view(np.uint8)
    filtered = cv2.copyTo(raw, back, filtered)   # np.copyto with a mask is 15 times slower
    return cv2.copyTo(np.zeros_like(raw), hole, filtered)


# compiled: one pass with a sliding window count, instead of six image-sized passes
_unbias_holes = jit.choose(_reference_unbias_holes, jit_traversal.unbias_holes)


def _reference_drop_smeared(filtered: np.ndarray, raw: np.ndarray, max_shift: float,
                            jump: float, planar_tolerance: float) -> None:
    """In place: :func:`drop_smeared`'s rules with the flying-pixel ``jump`` (numpy)."""
    kernel = np.ones((FLYING_WINDOW_PX, FLYING_WINDOW_PX), np.uint8)   # nearest, farthest
    near = cv2.erode(np.where(raw > 0.0, raw, np.float32(np.inf)), kernel,
                     borderType=cv2.BORDER_REPLICATE)
    far = cv2.dilate(raw, kernel, borderType=cv2.BORDER_REPLICATE)   # no return is 0
    ratio = np.float32(max_shift)
    h, w = raw.shape
    with np.errstate(invalid='ignore'):
        hole = ~(raw > 0.0)
        moved = ~hole & (np.abs(filtered - raw) > ratio * filtered)
        lim = ratio * filtered
        seen = np.zeros((h, w), bool)
        agree = np.ones((h, w), bool)
        pad = np.zeros((h + 2, w + 2), np.float32)
        pad[1:-1, 1:-1] = raw
        for nb in (pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]):
            valid = nb > 0.0
            seen |= valid
            agree &= ~valid | (np.abs(nb - filtered) <= lim)
        bad = hole & ~(seen & agree)
        lim = np.float32(jump) * raw
        between = ~hole & (raw - near > lim) & (far - raw > lim)
        bad |= between & ~_planar(raw, planar_tolerance)
    filtered[moved] = raw[moved]
    filtered[bad] = 0.0


_drop_smeared = jit.choose(_reference_drop_smeared, jit_traversal.drop_smeared)


def drop_edge_mask(depth_m: np.ndarray, rz: np.ndarray, height_m: float, step_down_m: float,
                   step_up_m: float, rows: int = DROP_EDGE_ROWS) -> np.ndarray:
    """Return (H, W) int8: rows (1 to ``rows``) down to where the floor ends, else 0.

    For a pixel whose ray passed the floor plane right above seen floor; rz: the rays' z.
    """
    h, w = depth_m.shape
    d = depth_m.astype(np.float32, copy=False)
    valid = d > 0.0
    with np.errstate(invalid='ignore'):
        z = np.where(valid, d * rz.reshape(h, w) + np.float32(height_m), np.float32(np.nan))
    down = np.float32(step_down_m)
    passed = z < -down                                   # NaN (no return) compares false
    floor = (z >= -down) & (z <= np.float32(step_up_m))
    edge = np.zeros((h, w), np.int8)
    for k in range(1, rows + 1):
        if k >= h:
            break
        hit = passed[:-k] & floor[k:] & (z[k:] - z[:-k] > down) & (edge[:-k] == 0)
        edge[:-k][hit] = k
    return edge


def _reference_drop_pixels(depth_m: np.ndarray, ru: np.ndarray, rv: np.ndarray, rot: np.ndarray,
                           height_m: float, step_down_m: float, step_up_m: float, rows: int,
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(flat pixels, int8 offsets) of :func:`drop_edge_mask`'s marks under GroundRays' factors."""
    edge = drop_edge_mask(depth_m, GroundRays(ru, rv, rot).table()[2], height_m, step_down_m,
                          step_up_m, rows)
    pixels = np.flatnonzero(edge)
    return pixels, edge.reshape(-1)[pixels]


drop_pixels = jit.choose(_reference_drop_pixels, jit_traversal.drop_pixels)


def drop_edges(depth_m: np.ndarray, rays: GroundRays, height_m: float,
               params: DetectorParams) -> tuple[np.ndarray, np.ndarray]:
    """Where the floor ends at a drop: ((D, 3) float32 floor points, (D,) edge pixels)."""
    pixels, offsets = drop_pixels(depth_m, rays.ru, rays.rv, rays.rot, height_m,
                                   params.max_step_down_m, params.max_step_height_m,
                                   DROP_EDGE_ROWS)
    if pixels.size == 0:
        return np.zeros((0, 3), np.float32), pixels
    floor_px = pixels + offsets.astype(np.int64) * depth_m.shape[1]
    d = depth_m.reshape(-1)[floor_px]
    ray = rays.at(floor_px)
    x = d * ray[0]
    y = d * ray[1]
    z = d * ray[2] + np.float32(height_m)
    keep = (x >= np.float32(params.min_range_m)) & (x <= np.float32(params.max_range_m))
    keep &= np.abs(y) <= np.float32(params.lateral_limit_m)
    pts = np.stack((x[keep], y[keep], z[keep]), axis=1)
    return pts.astype(np.float32), pixels[keep]
