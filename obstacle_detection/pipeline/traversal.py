"""Robot-level traversability (not in the seed): connectivity, step height, drops.

The seed calls a voxel ground when its normal is within theta of vertical. A robot cannot drive
onto a box top, a table or a curb, however flat, nor off a drop; it can cross a door sill and
climb a passable ramp to its landing. After the normals, :func:`traversable_ground` decides:

1. A 2.5-D grid of cells (twice the voxel size) over the voxels. The *surface* of a cell is its
   lowest voxel that passed the slope test (under a table the floor, where it is seen). A
   cell is *passable* when it has a surface held by at least ``MIN_SURFACE_VOXELS`` flat
   voxels within one voxel height (flying or stray voxels make no floor) and its voxels span
   no more than ``max_step_height_m`` in height (no step, wall foot or curb face inside it).
2. Seeds: passable cells whose surface lies on the floor plane, within ``[-max_step_down_m,
   max_step_height_m]`` of z = 0 (the floor plane refined per frame, :mod:`.floor`).
3. Ground is grown from the seeds to the 8 neighbouring passable cells through steps of at most
   ``max_step_height_m`` up and ``max_step_down_m`` down (a directed graph, one breadth-first
   search in scipy): ramps no steeper than theta and their landings are reached, box and table
   tops, curbs and the floor beyond a drop are not.
4. The local ground of a reached cell is its surface; the others take it from the reached
   cells, grown outward layer by layer (the largest of the neighbours filled before); a
   voxel's height is taken above its cell's local ground. Obstacle: higher than
   ``max_step_height_m`` and not above ``robot_height_m`` (a wall, but not its foot; a box top),
   or lower than ``-max_step_down_m`` (the floor beyond a drop). Above the robot: not an
   obstacle.

:func:`ledges` marks the open side of a raised traversable surface (a ramp or landing more than
a step above the floor beside it, both reached: issue 22), kept through the N1 validation.

:func:`drop_edges` marks a drop whose lower floor is out of view or out of range: a pixel whose
ray passed the floor plane (its point lies more than the step down below it) right above pixels
that see the floor marks the cell where that floor ends, when it lies within the range.
All vectorised, or compiled (:mod:`.jit_traversal`, same results); no per-point Python loop.
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
from .geometry import GroundRays, rays_at
from .params import DetectorParams

#: The 8 neighbours of a cell as (dx, dy); the search adds both directions of each pair.
_HALF_NEIGHBOURHOOD = ((1, 0), (0, 1), (1, 1), (1, -1))
#: Flat voxels a cell's surface needs within one voxel height (of the 4 a 2 x 2 voxel cell
#: holds) to pass the robot on: a few stray or flying voxels do not make a floor.
MIN_SURFACE_VOXELS = 3
#: Rows below an over-the-edge pixel searched for the floor it passed [px].
DROP_EDGE_ROWS = 3
#: A pixel this share of its depth away from both the nearest and the farthest depth of its
#: window is a mixed (flying) pixel, unless it lies on a plane with its neighbours (a floor
#: seen 0.6 m up at 4 m changes ~2 % a row: such planes are kept, see _planar).
FLYING_JUMP = 0.03
#: Largest second difference of the inverse depth, as a share of it, of a pixel on a plane.
PLANAR_TOLERANCE = 0.02
#: Cells searched beyond an open side for the lower ground in its shadow (the floor beside
#: a platform 18 cm up, seen from 0.6 m, is hidden over 0.4 x the side's distance) [cells].
LEDGE_SHADOW_CELLS = 12
#: The 8 directions of the search across an edge, as (dx, dy) cell steps.
_DIRECTIONS = np.array(((1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)))
#: Voxels below a marked one in which the foot of an object is looked for (:func:`feet`).
FOOT_VOXELS = 3
#: Window of the flying-pixel test [px]: time-of-flight mixed pixels lie up to two pixels
#: from the depth edge.
FLYING_WINDOW_PX = 5


@dataclass(frozen=True)
class Traversal:
    """Robot-level decision per voxel.

    is_obstacle: (V,) bool before the seed's N1 validation; above_robot: (V,) bool;
    height_m: (V,) float32 height above the local ground [m]; reached: (V,) bool, the voxel's
    cell was reached from the floor; cell_size_m: the grid's cell size [m]; ledge: (V,) bool,
    the voxel lies on a ledge (:func:`ledges`), an obstacle that the N1 validation keeps.
    """

    is_obstacle: np.ndarray
    above_robot: np.ndarray
    height_m: np.ndarray
    reached: np.ndarray
    cell_size_m: float
    ledge: np.ndarray | None = None


def cell_size(params: DetectorParams) -> float:
    """Cell size of the traversability grid [m]: twice the larger horizontal voxel size."""
    return 2.0 * max(params.voxel_x_m, params.voxel_y_m)


def traversable_ground(points: np.ndarray, steep: np.ndarray,
                       params: DetectorParams) -> Traversal:
    """Decide obstacles at robot level.

    points: (V, 3) float32 voxel centroids, ground frame [m]; steep: (V,) bool, the seed's
    slope test (True = steeper than theta). Compiled when :func:`.jit.enabled` (same result).
    """
    size = cell_size(params)
    if points.shape[0] == 0:
        empty = np.zeros(0, bool)
        return Traversal(empty, empty, np.zeros(0, np.float32), empty, size, empty)
    out = _traverse(points, steep, size, params.max_step_height_m, params.max_step_down_m,
                    params.robot_height_m, params.voxel_z_m, MIN_SURFACE_VOXELS)
    edge = ledges(points, steep, out[3], out[1], size, params.max_step_height_m,
                  params.max_step_down_m)
    return Traversal(*out, size, edge)


def _reference_lone_voxels(points: np.ndarray, vx: float, vy: float, vz: float) -> np.ndarray:
    """(V,) bool: no other voxel lies in the 26 voxels around the voxel (numpy)."""
    ijk = np.floor(points / np.array((vx, vy, vz), np.float32)).astype(np.int64)
    ijk += 1 - ijk.min(axis=0)
    grid = np.zeros(tuple(ijk.max(axis=0) + 2), bool)
    grid[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    lone = np.ones(points.shape[0], bool)
    for d in np.ndindex(3, 3, 3):
        if d != (1, 1, 1):
            lone &= ~grid[ijk[:, 0] + d[0] - 1, ijk[:, 1] + d[1] - 1, ijk[:, 2] + d[2] - 1]
    return lone


def lone_voxels(points: np.ndarray, vx: float, vy: float, vz: float) -> np.ndarray:
    """(V,) bool: voxels with no other voxel among their 26 neighbours (issue 22).

    points: (V, 3) float32 voxel centroids [m]; vx, vy, vz: the voxel size [m]. A lone
    voxel in the robot's band is a time-of-flight mixed pixel that the flying-pixel test kept
    (its window's near surface missing in a dropout blob, or within 3 % of a surface): mixed
    depths scatter along the rays, while a surface, a leg or a board fills neighbouring
    voxels. Such candidates are not obstacles. Compiled when :func:`.jit.enabled`.
    """
    if points.shape[0] == 0:
        return np.zeros(0, bool)
    return _lone_voxels(points, vx, vy, vz)


_lone_voxels = jit.choose(_reference_lone_voxels, jit_ledges.lone_voxels)


def _reference_feet(points: np.ndarray, candidates: np.ndarray, marked: np.ndarray, vx: float,
                    vy: float, vz: float, reach: int) -> np.ndarray:
    """(V,) bool: candidates, not marked, with a marked voxel 1 to reach voxels above (numpy)."""
    ijk = np.floor(points / np.array((vx, vy, vz), np.float32)).astype(np.int64)
    ijk += 1 - ijk.min(axis=0)
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
    """(V,) bool: the feet of marked obstacles, candidates the N1 validation let go (issue 22).

    An obstacle candidate (above the step height) right under a marked voxel of the same
    column, 1 to ``FOOT_VOXELS`` voxels below it, is the bottom of that object: its
    neighbours include the floor, which fails the seed's validation, while the voxels above
    it passed. points: (V, 3) float32 voxel centroids [m]; candidates, marked: (V,) bool;
    vx, vy, vz: the voxel size [m]. Compiled when :func:`.jit.enabled`.
    """
    if points.shape[0] == 0:
        return np.zeros(0, bool)
    return _feet(points, candidates, marked, vx, vy, vz, FOOT_VOXELS)


_feet = jit.choose(_reference_feet, jit_ledges.feet)


def ledges(points: np.ndarray, steep: np.ndarray, reached: np.ndarray, above: np.ndarray,
           size_m: float, step_up_m: float, step_down_m: float) -> np.ndarray:
    """(V,) bool: voxels on the side of a raised traversable surface (issue 22).

    Where two reached surfaces, a ramp or a landing and the floor beside it, differ by more
    than a step (its open side, which the reach from the floor does not stop at: both are
    reached), the robot falls off the higher one or meets a wall from the lower one. On the
    cell grid of :func:`_reference_traverse` (same cells); a cell's surface is its lowest flat
    voxel, where it was reached:

    - a reached cell whose *lower ground* lies more than ``step_down_m`` below its surface:
      its voxels, the edge of the higher surface. Its lower ground is the lowest reached
      surface among its 8 neighbours or, across the edge (the floor right beyond an open
      side lies in its shadow), the lowest of the first cells with voxels beyond a gap of
      cells without (up to ``LEDGE_SHADOW_CELLS``) in the 8 directions whose x and y steps
      both lead away from the camera (or are 0), where reached;
    - a cell not reached whose reached neighbours' surfaces differ by more than
      ``step_up_m``: its voxels more than ``step_up_m`` above the lowest (the side face seen
      from the floor, which the local ground, the highest neighbour's, calls ground).

    Two surfaces that both lie within the floor's band (``[-step_down_m, step_up_m]`` of
    z = 0, where the reach starts) are both floor, never a ledge: range noise on a far floor
    (a real Kinect v1 frame's floor cells 2.3 m away spread over 8 cm) is no open side.

    Never a voxel above the robot (``above``). points: (V, 3) float32 ground frame, the
    camera over its origin [m]; steep, reached, above: (V,) bool. Numpy on the cells (a few
    thousand), or compiled (:mod:`._compiled.ledges`, the same flags) when
    :func:`.jit.enabled`. The marks are obstacles that the seed's N1 validation keeps (a
    ledge is a band one cell wide, as a drop edge).
    """
    if points.shape[0] == 0:
        return np.zeros(0, bool)
    if jit.enabled():
        return jit_ledges.ledges(points, steep, reached, above, size_m, step_up_m, step_down_m,
                                 LEDGE_SHADOW_CELLS)
    size = np.float32(size_m)
    ix = np.floor(points[:, 0] / size).astype(np.int64)
    iy = np.floor(points[:, 1] / size).astype(np.int64)
    ox, oy = int(ix.min()), int(iy.min())
    ix -= ox
    iy -= oy
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    key = ix * ny + iy
    z = points[:, 2].astype(np.float64)
    flat = reached & ~steep
    surface = np.full(nx * ny, np.inf)
    np.minimum.at(surface, key[flat], z[flat])
    surface = surface.reshape(nx, ny)
    low = minimum_filter(surface, size=3, mode='constant', cval=np.inf)
    top = np.where(np.isfinite(surface), surface, -np.inf)
    high = maximum_filter(top, size=3, mode='constant', cval=-np.inf)
    # across the edge, where the lower ground right beyond it lies in the edge's shadow:
    # from a reached cell with an empty neighbour, over empty cells in the 8 directions that
    # lead away from the camera, to the first cell with voxels
    seen = np.zeros(nx * ny, bool)
    seen[key] = True
    seen = seen.reshape(nx, ny)
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
    for k in range(1, LEDGE_SHADOW_CELLS + 1):
        wx = wx + sx
        wy = wy + sy
        inside = (wx >= 0) & (wx < nx) & (wy >= 0) & (wy < ny)
        wx, wy, sx, sy, owner = wx[inside], wy[inside], sx[inside], sy[inside], owner[inside]
        if wx.size == 0:
            break
        hit = seen[wx, wy]
        if k > 1:   # the first cell beyond a gap (next to it, the 8 neighbours decide)
            np.minimum.at(beyond, owner[hit], surface[wx[hit], wy[hit]])
        gap = ~hit
        wx, wy, sx, sy, owner = wx[gap], wy[gap], sx[gap], sy[gap], owner[gap]
    low[cx, cy] = np.minimum(low[cx, cy], beyond)
    with np.errstate(invalid='ignore'):
        # two surfaces within the floor's band (the seeds') are both floor: no ledge
        floor_low = (low >= -step_down_m) & (low <= step_up_m)
        raised = (surface - low > step_down_m)                    # a reached cell's
        raised &= ~(floor_low & (surface >= -step_down_m) & (surface <= step_up_m))
        face = (high - low > step_up_m) & ~(floor_low & (high >= -step_down_m)
                                            & (high <= step_up_m))
        raised = raised.reshape(-1)[key]
        low = low.reshape(-1)[key]
        face = face.reshape(-1)[key] & (z - low > step_up_m)
    return np.where(reached, raised, face) & ~above




def _reference_traverse(points: np.ndarray, steep: np.ndarray, size_m: float, step_up_m: float,
                        step_down_m: float, robot_height_m: float, layer_m: float,
                        min_support: int = MIN_SURFACE_VOXELS,
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(obstacle, above, height float32, reached) per voxel, in numpy (the reference)."""
    size = np.float32(size_m)
    ix = np.floor(points[:, 0] / size).astype(np.int64)
    iy = np.floor(points[:, 1] / size).astype(np.int64)
    ix -= ix.min()
    iy -= iy.min()
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    key = ix * ny + iy
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


def _neighbour_views(arr: np.ndarray, fill: float | bool) -> list[np.ndarray]:
    """Return the 8 neighbours' values of every cell (views of a padded copy)."""
    nx, ny = arr.shape
    pad = np.full((nx + 2, ny + 2), fill, dtype=arr.dtype)
    pad[1:-1, 1:-1] = arr
    return [pad[1 + dx:1 + dx + nx, 1 + dy:1 + dy + ny]
            for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]


def _local_ground(surface: np.ndarray, reached: np.ndarray) -> np.ndarray:
    """Ground height (nx, ny) of every cell: its surface where reached, else grown outward.

    Layer by layer (8 neighbours), a cell gets the largest ground among its neighbours filled
    in the previous layers. No reached cell: the floor plane, 0.
    """
    if not reached.any():
        return np.zeros(surface.shape)
    ground = np.where(reached, surface, 0.0)
    done = reached.copy()
    while not done.all():
        filled = [np.where(d, g, -np.inf) for d, g in zip(_neighbour_views(done, False),
                                                          _neighbour_views(ground, 0.0))]
        best = np.max(filled, axis=0)
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


def depth_window_range(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest and farthest measured depth (H, W) float32 in each pixel's 5 x 5 window [m].

    raw: 0 = no return (as :func:`.depth.decode_depth` gives; no NaN). Pixels without a
    return take no part (a window without any gives inf / 0). OpenCV's erode/dilate, shared
    by the numpy and the compiled path.
    """
    kernel = np.ones((FLYING_WINDOW_PX, FLYING_WINDOW_PX), np.uint8)
    holes_far = _holes_to_inf(raw)
    near = np.empty(raw.shape, np.float32)
    far = np.empty(raw.shape, np.float32)
    cv2.erode(holes_far, kernel, dst=near, borderType=cv2.BORDER_REPLICATE)
    cv2.dilate(raw, kernel, dst=far, borderType=cv2.BORDER_REPLICATE)   # no return is 0
    return near, far


def _reference_holes_to_inf(raw: np.ndarray) -> np.ndarray:
    """Return ``np.where(raw > 0, raw, inf)`` (float32)."""
    return np.where(raw > 0.0, raw, np.float32(np.inf))


_holes_to_inf = jit.choose(_reference_holes_to_inf, jit_traversal.holes_to_inf)


def _planar(raw: np.ndarray, tolerance: float = PLANAR_TOLERANCE) -> np.ndarray:
    """(H, W) bool: the pixel lies on a plane with its row and column neighbours.

    A plane's inverse depth is affine in the pixel coordinates, so its second differences
    vanish (a floor or a table's underside seen at a grazing angle); a mixed pixel's do not.
    Within ``tolerance`` of the pixel's inverse depth, all four neighbours measured.
    """
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
    """Undo what the median filter smeared across depth edges; drop what is no surface.

    filtered, raw: (H, W) float32 [m], the median-filtered and the measured depth (0 = no
    return, as :func:`.depth.decode_depth` gives). A pixel
    whose filtered depth differs from its measured one by more than ``max_shift`` times the
    filtered depth got its value from across a depth edge (it would fatten the near object
    into free space, or erase a thin one such as a table's edge): it takes its measured depth
    back. Dropped (set to 0, no return):

    - a pixel without a measured depth (0 or NaN) that the filter filled, unless it has a
      measured 4-neighbour and all of them lie within ``max_shift`` of the filled depth (a
      dropout inside a surface is filled; a hole at a depth edge, where the filter could only
      guess, is not: no return never marks anything);
    - a mixed ("flying") pixel: its measured depth lies more than ``FLYING_JUMP`` of it away
      from both the nearest and the farthest depth of its 5 x 5 window, between the two
      surfaces of a depth edge, as a time-of-flight sensor returns up to two pixels from it,
      and not on a plane with its neighbours (a surface seen at a grazing angle is kept).

    Returns ``filtered`` (modified in place); ``max_shift`` <= 0 changes nothing. Compiled
    when numba is there (same result).
    ``raw_no_nan``: the caller knows ``raw`` holds no NaN (the detector's uint16 depth, looked
    up in the depth table: 0 for no return, never NaN), which spares the compiled path a scan.
    """
    if max_shift <= 0.0:
        return filtered
    raw = np.ascontiguousarray(raw, np.float32)
    _drop_smeared(filtered, raw, max_shift, FLYING_JUMP, PLANAR_TOLERANCE, raw_no_nan)
    return filtered


def _reference_drop_smeared(filtered: np.ndarray, raw: np.ndarray, max_shift: float,
                            jump: float, planar_tolerance: float,
                            raw_no_nan: bool = False) -> None:
    """In place: :func:`drop_smeared`'s rules with the flying-pixel ``jump`` (numpy)."""
    near, far = depth_window_range(raw)
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


def _compiled_drop_smeared(filtered: np.ndarray, raw: np.ndarray, max_shift: float,
                           jump: float, planar_tolerance: float,
                           raw_no_nan: bool = False) -> None:
    """:func:`_reference_drop_smeared` compiled: one fused pass, or the window range first.

    The fused pass (the 5 x 5 window range on the way) takes C-contiguous float32 images
    without NaN (OpenCV's window range orders NaN its own way).
    """
    if (FLYING_WINDOW_PX == 5 and filtered.flags.c_contiguous
            and filtered.dtype == np.float32 and filtered.shape == raw.shape
            and (raw_no_nan or not jit_traversal.has_nan(raw))):
        jit_traversal.drop_smeared_fused(filtered, raw, max_shift, jump, planar_tolerance)
    else:
        near, far = depth_window_range(raw)
        jit_traversal.drop_smeared(filtered, raw, near, far, max_shift, jump, planar_tolerance)


_drop_smeared = jit.choose(_reference_drop_smeared, _compiled_drop_smeared)


def drop_edge_mask(depth_m: np.ndarray, rz: np.ndarray, height_m: float, step_down_m: float,
                   step_up_m: float, rows: int = DROP_EDGE_ROWS) -> np.ndarray:
    """Return (H, W) int8: rows down to where the floor ends, for rays that passed it; else 0.

    For a pixel whose ray passed the floor plane right above seen floor: the number of rows
    (1 to ``rows``) down to the floor pixel where the floor ends.

    depth_m (H, W) float32 [m] (0/NaN no return: never marks); rz (H*W,) or (H, W) float32,
    the z component of the ground rays; height_m: camera height. A pixel passed the floor when
    its point lies more than ``step_down_m`` below z = 0; it is an edge when one of the
    ``rows`` pixels below it sees the floor (z within ``[-step_down_m, step_up_m]``) more than
    ``step_down_m`` above its own point (the nearest such row is given). float32 arithmetic,
    as the compiled kernel.
    """
    return _drop_edge_mask(depth_m, rz, height_m, step_down_m, step_up_m, rows)


def _reference_drop_edge_mask(depth_m: np.ndarray, rz: np.ndarray, height_m: float,
                              step_down_m: float, step_up_m: float, rows: int) -> np.ndarray:
    """:func:`drop_edge_mask` in numpy."""
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


_drop_edge_mask = jit.choose(_reference_drop_edge_mask, jit_traversal.drop_edge_mask)


def _reference_drop_pixels(depth_m: np.ndarray, rz: np.ndarray | None, height_m: float,
                           step_down_m: float, step_up_m: float, rows: int,
                           model: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(flat pixel indices int64, offsets int8) of :func:`drop_edge_mask`'s marks, in order.

    rz: (H*W,) or (H, W) float32, the z of the ground rays; or None and model: (ru, rv, rot)
    float32 of :class:`.geometry.GroundRays`.
    """
    if model is not None:
        rz = GroundRays(*model).table()[2]
    edge = _reference_drop_edge_mask(depth_m, rz, height_m, step_down_m, step_up_m, rows)
    pixels = np.flatnonzero(edge)
    return pixels, edge.reshape(-1)[pixels]


_drop_pixels = jit.choose(_reference_drop_pixels, jit_traversal.drop_pixels)


def drop_edges(depth_m: np.ndarray, rays: np.ndarray | GroundRays, height_m: float,
               params: DetectorParams) -> tuple[np.ndarray, np.ndarray]:
    """Where the floor ends at a drop: the last floor seen below the rays that passed it.

    depth_m: (H, W) float32 [m]; rays: the (3, H*W) ground rays of the frame's mount, or its
    :class:`.geometry.GroundRays` (the same values; the compiled path then computes them row
    by row, no table); height_m: the camera height of that mount. Returns
    ``(points, pixels)``: (D, 3) float32 ground points of the floor pixels where the floor
    ends (:func:`drop_edge_mask`), inside the forward range and lateral limit [m] (the cells
    the costmap marks), and (D,) int64 the flat indices of the pixels that saw past the edge
    (the lower floor, or anything beyond it).
    """
    down, up = params.max_step_down_m, params.max_step_height_m
    if isinstance(rays, GroundRays):   # the compiled path computes them row by row
        rz, model = None, (rays.ru, rays.rv, rays.rot)
    else:
        rz, model = rays[2], None
    pixels, offsets = _drop_pixels(depth_m, rz, height_m, down, up, DROP_EDGE_ROWS, model)
    if pixels.size == 0:
        return np.zeros((0, 3), np.float32), pixels
    floor_px = pixels + offsets.astype(np.int64) * depth_m.shape[1]
    d = depth_m.reshape(-1)[floor_px]
    ray = rays_at(rays, floor_px)
    x = d * ray[0]
    y = d * ray[1]
    z = d * ray[2] + np.float32(height_m)
    keep = (x >= np.float32(params.min_range_m)) & (x <= np.float32(params.max_range_m))
    keep &= np.abs(y) <= np.float32(params.lateral_limit_m)
    pts = np.stack((x[keep], y[keep], z[keep]), axis=1)
    return pts.astype(np.float32), pixels[keep]


def warm_up() -> None:
    """Compile (or load from the disk cache) the robot-level kernels, if they run."""
    if jit.enabled():
        jit_traversal.warm_up()
        pts = np.zeros((2, 3), np.float32)
        flags = np.zeros(2, bool)
        jit_ledges.ledges(pts, flags, flags, flags, 0.05, 0.05, 0.05, LEDGE_SHADOW_CELLS)
        jit_ledges.lone_voxels(pts, 0.025, 0.025, 0.025)
        jit_ledges.feet(pts, flags, flags, 0.025, 0.025, 0.025, FOOT_VOXELS)
