"""Clearing evidence: every surface the camera saw, as ray ends for Nav2 (``docs/node.md``)."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from . import jit
from ._compiled import clearing as compiled
from .geometry import OPTICAL_TO_BODY, pixel_rays
from .params import Intrinsics

#: Points added along the rays of the outermost valid pixels of each row, as fractions of the
#: ray's length to its surface (or to the range).
BORDER_FRACTIONS = (0.55, 0.7, 0.85)


def clearing_points(depth_m: np.ndarray, intrinsics: Intrinsics, *, stride_px: int,
                    range_m: float) -> np.ndarray:
    """Return (N, 3) float32 optical-frame clearing ray ends: every stride_px-th pixel, borders.

    A surface farther than range_m gives the point at that distance.
    """
    ru, rv, rows, cols = _rays_and_samples(depth_m.shape, intrinsics, int(stride_px))
    return _clearing_points(depth_m, ru, rv, rows, cols, range_m, BORDER_FRACTIONS)


def clearing_cloud(result: Any, *, stride_px: int, range_m: float) -> np.ndarray:
    """Return a frame's clearing cloud (N, 3) float32 as the node publishes it (optical frame).

    Re-expressed through the frame's pose (``result.pose``): Nav2, placing the camera by the
    nominal mount, puts every point where the frame's marks put the same surface.
    """
    points = clearing_points(result.depth_m, result.intrinsics, stride_px=stride_px,
                             range_m=range_m)
    return result.pose.to_nominal_optical(points)


# once per camera and stride, not per frame: a third of the clearing cloud's time in the node
@functools.lru_cache(maxsize=4)
def _rays_and_samples(shape: tuple[int, int], intrinsics: Intrinsics, stride_px: int,
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return the pixel rays (ru, rv) and the kept rows and columns of a frame size."""
    ru, rv = pixel_rays(shape, intrinsics)
    height, width = shape
    rows = np.unique(np.append(np.arange(0, height, stride_px), height - 1))   # and the last
    cols = np.unique(np.append(np.arange(0, width, stride_px), width - 1))
    return ru, rv, rows, cols


def _reference_clearing_points(depth: np.ndarray, ru: np.ndarray, rv: np.ndarray,
                               rows: np.ndarray, cols: np.ndarray, range_m: float,
                               fractions: tuple[float, ...]) -> np.ndarray:
    """Points of the kept pixels (rows x cols) on rays ru, rv, then the border points."""
    width = depth.shape[1]
    band = depth[rows]                                   # (R, W): the kept rows, all columns
    with np.errstate(invalid='ignore'):
        valid = np.isfinite(band) & (band > 0.0)
    kept_r, kept_c = np.nonzero(valid[:, cols])
    points = [_points(band[kept_r, cols[kept_c]], ru[cols[kept_c]], rv[rows[kept_r]],
                      range_m)]
    has = valid.any(axis=1)
    first = np.argmax(valid, axis=1)[has]
    last = width - 1 - np.argmax(valid[:, ::-1], axis=1)[has]
    edge_r = np.concatenate((np.flatnonzero(has), np.flatnonzero(has)))
    edge_c = np.concatenate((first, last))
    edge = _points(band[edge_r, edge_c], ru[edge_c], rv[rows[edge_r]], range_m)
    points += [edge * np.float32(fraction) for fraction in fractions]
    return np.concatenate(points).astype(np.float32, copy=False)


# compiled: one pass over the kept rows instead of a dozen numpy calls (0.7 -> 0.1 ms)
_clearing_points = jit.choose(_reference_clearing_points, compiled.clearing_points)


def _points(z: np.ndarray, x_per_z: np.ndarray, y_per_z: np.ndarray,
            range_m: float) -> np.ndarray:
    """(N, 3) float32 optical-frame points of depths z [m] on rays (x/z, y/z), within range."""
    z = z.astype(np.float32)
    # distance to the camera: depth times the ray's length per metre of depth
    distance = z * np.sqrt(np.float32(1.0) + x_per_z * x_per_z + y_per_z * y_per_z)
    z = z * np.minimum(np.float32(1.0), np.float32(range_m) / distance)
    return np.stack((x_per_z * z, y_per_z * z, z), axis=1)


def warm_up() -> None:
    """Compile (or load from numba's disk cache) the clearing kernels, if they run."""
    if jit.enabled():
        points = clearing_points(np.ones((6, 8), np.float32),
                                 Intrinsics(fx=4.0, fy=4.0, cx=4.0, cy=3.0), stride_px=2,
                                 range_m=1.0)
        guarded(points, np.array([[1.0, 0.0, 0.5]]), OPTICAL_TO_BODY, np.array([0.0, 0.0, 0.5]),
                cell_m=0.05, voxel_m=0.1)



# --- what the node sends Nav2's VoxelLayer (issue 29; docs/node.md, "Marks and rays for Nav2")

def nav2_clouds(marks: np.ndarray, points: np.ndarray, rotation: np.ndarray,
                translation: np.ndarray, *, cell_m: float, voxel_m: float,
                ) -> tuple[np.ndarray, np.ndarray]:
    """Return (marks (M', 3), clearing points (N', 3)) float32 for a voxel layer like Nav2's.

    marks: the frame's obstacle points, base frame; points: its clearing cloud, optical frame;
    rotation (3, 3), translation (3,): the optical frame in the base frame as the consumer
    places the cloud (the nominal mount); cell_m, voxel_m: the consumer's cell and voxel size.
    Nav2 raytraces between whole cells (up to a cell beside the true ray) and clears whole
    voxels, then frees a column whose voxels are all clear. So: marks less than a cell inside
    the outermost clearing rays are not sent (no ray could clear them once their obstacle left),
    and the rays stop before those marks' columns (they are obstacles the camera still sees);
    a column whose marks span less than a voxel (a box top seen alone) is filled two voxels
    down, so that a ray grazing its voxel does not free it.
    """
    keep = reachable_marks(marks, points, rotation, translation, margin_m=cell_m)
    if not keep.all():
        points = guarded(points, marks[~keep], rotation, translation, cell_m=cell_m,
                         voxel_m=voxel_m)
    return filled_marks(marks[keep], cell_m=cell_m, voxel_m=voxel_m), points


def reachable_marks(marks: np.ndarray, points: np.ndarray, rotation: np.ndarray,
                    translation: np.ndarray, *, margin_m: float) -> np.ndarray:
    """(M,) bool: the marks at least margin_m inside the outermost clearing rays (left, right).

    marks (M, 3): base frame; points (N, 3): the clearing cloud, optical frame; rotation,
    translation: the optical frame in the base frame. Without clearing points no mark is.
    """
    m = np.asarray(marks, np.float64).reshape(-1, 3)
    if m.shape[0] == 0 or points.shape[0] == 0:
        return np.zeros(m.shape[0], bool)
    slope = points[:, 0] / points[:, 2]          # optical x / z: left-right in the image
    q = (m - np.asarray(translation, np.float64)) @ np.asarray(rotation, np.float64)
    ahead = q[:, 2] > 0.0
    qs = np.where(ahead, q[:, 0] / np.where(ahead, q[:, 2], 1.0), 0.0)
    inside = np.minimum(qs - slope.min(), slope.max() - qs) * q[:, 2]
    return ahead & (inside >= margin_m)


def filled_marks(marks: np.ndarray, *, cell_m: float, voxel_m: float,
                 depth_voxels: int = 2) -> np.ndarray:
    """Return the marks, those of thin columns also copied lower: (M', 3) float32.

    A column (cell_m square cells) whose marks span less than voxel_m gets copies of each of
    its marks above z = 0 at half-voxel steps down to depth_voxels voxels lower (not below 0).
    """
    m = np.asarray(marks, np.float32).reshape(-1, 3)
    if m.shape[0] == 0:
        return m
    _, inverse, z_lo, z_hi = _columns(m, cell_m)
    src = m[(z_hi - z_lo < voxel_m)[inverse] & (m[:, 2] > 0.0)]
    if src.shape[0] == 0:
        return m
    steps = np.arange(1, 2 * depth_voxels + 1, dtype=np.float32) * np.float32(voxel_m / 2)
    fill = np.repeat(src, steps.size, axis=0)
    fill[:, 2] = np.maximum(fill[:, 2] - np.tile(steps, src.shape[0]), np.float32(0.0))
    return np.concatenate((m, fill))


#: Bins [rad of tan] of the ray directions: a column's image footprint picks its rays by bin.
_BIN = 0.01


def _cell_keys(points: np.ndarray, cell_m: float) -> np.ndarray:
    """(N,) int64: one key per cell_m cell of the points' x, y (within +-2^31 cells)."""
    cells = np.floor(points[:, :2] / cell_m).astype(np.int64)
    return (cells[:, 0] << 32) + cells[:, 1]


def _columns(points: np.ndarray, cell_m: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Group points by cell_m column: (first point, each point's column, lowest z, highest z).

    One entry per column in the first and the heights, which keep the points' dtype.
    """
    _, first, inverse = np.unique(_cell_keys(points, cell_m), return_index=True,
                                  return_inverse=True)
    inverse = inverse.reshape(-1)
    z_lo = np.full(first.size, np.inf, points.dtype)
    z_hi = np.full(first.size, -np.inf, points.dtype)
    np.minimum.at(z_lo, inverse, points[:, 2])
    np.maximum.at(z_hi, inverse, points[:, 2])
    return first, inverse, z_lo, z_hi


def guarded(points: np.ndarray, marks: np.ndarray, rotation: np.ndarray,
            translation: np.ndarray, *, cell_m: float, voxel_m: float) -> np.ndarray:
    """Return the clearing points, each ray ending where it enters a column of ``marks``.

    A column: the cell_m cell of marks grown by a cell on each side (a consumer's line may run
    a cell beside the true one), from its lowest to its highest mark, and a voxel more below
    and above when they span less than a voxel (a ray within that voxel frees it whole; over
    a taller column it clears the top voxel only). points (N, 3) optical frame; marks (M, 3)
    base frame. A ray starting inside one is dropped.
    """
    pts = np.asarray(points, np.float64)
    m = np.asarray(marks, np.float64).reshape(-1, 3)
    if pts.shape[0] == 0 or m.shape[0] == 0:
        return points
    rot = np.asarray(rotation, np.float64)
    origin = np.asarray(translation, np.float64)
    first, inverse, z_lo, z_hi = _columns(m, cell_m)
    keys = np.floor(m[first, :2] / cell_m)
    grow = cell_m
    # a ray over a thick column clears its top voxel only; a thin one it frees within a voxel
    dz = np.where(z_hi - z_lo < voxel_m, voxel_m, 0.0)
    lo = np.column_stack((keys * cell_m - grow, z_lo - dz))
    hi = np.column_stack(((keys + 1) * cell_m + grow, z_hi + dz))
    # each column's footprint in the image plane (tangents), from its 8 corners
    corners = np.stack([np.stack([np.where(c & 1, hi[:, 0], lo[:, 0]),
                                  np.where(c & 2, hi[:, 1], lo[:, 1]),
                                  np.where(c & 4, hi[:, 2], lo[:, 2])], axis=1)
                        for c in range(8)], axis=1)                       # (B, 8, 3)
    optical = (corners - origin) @ rot                                     # R^T (c - t)
    ahead = (optical[..., 2] > 1e-3).all(axis=1)
    z = np.where(ahead[:, None], optical[..., 2], 1.0)
    tx, ty = optical[..., 0] / z, optical[..., 1] / z
    # the rays' bins; a column reaching behind the camera covers them all
    rx = np.floor(pts[:, 0] / pts[:, 2] / _BIN).astype(np.int64)
    ry = np.floor(pts[:, 1] / pts[:, 2] / _BIN).astype(np.int64)
    rx0, ry0 = int(rx.min()), int(ry.min())
    nbx, nby = int(rx.max()) - rx0 + 1, int(ry.max()) - ry0 + 1
    bins = (ry - ry0) * nbx + (rx - rx0)
    order = np.argsort(bins, kind='stable')
    starts = np.zeros(nbx * nby + 1, np.int64)
    np.cumsum(np.bincount(bins, minlength=nbx * nby), out=starts[1:])
    window = np.stack([
        np.where(ahead, np.clip(np.floor(tx.min(axis=1) / _BIN) - rx0, 0, nbx), 0),
        np.where(ahead, np.clip(np.floor(tx.max(axis=1) / _BIN) - rx0 + 1, 0, nbx), nbx),
        np.where(ahead, np.clip(np.floor(ty.min(axis=1) / _BIN) - ry0, 0, nby), 0),
        np.where(ahead, np.clip(np.floor(ty.max(axis=1) / _BIN) - ry0 + 1, 0, nby), nby),
    ], axis=1).astype(np.int64)
    scale = _ray_scales(pts @ rot.T, origin, lo, hi, window, order, starts, nbx)
    keep = scale > 0.0
    return (pts[keep] * scale[keep, None]).astype(np.float32)


def _reference_ray_scales(d: np.ndarray, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                          window: np.ndarray, order: np.ndarray, starts: np.ndarray,
                          nbx: int) -> np.ndarray:
    """Per ray (d: its end minus origin, base frame), the fraction of it before any box.

    The boxes [lo, hi] are tested against the rays of the bins in their window (x0, x1, y0,
    y1); a ray that enters one before its end is cut there (0: it starts inside).
    """
    w = window[:, 1] - window[:, 0]
    n = np.maximum(w, 0) * np.maximum(window[:, 3] - window[:, 2], 0)
    box = np.repeat(np.arange(len(n)), n)
    k = np.arange(box.size) - np.repeat(np.cumsum(n) - n, n)
    wb = np.maximum(w[box], 1)
    bin_id = (window[box, 2] + k // wb) * nbx + window[box, 0] + k % wb
    count = starts[bin_id + 1] - starts[bin_id]
    pair_box = np.repeat(box, count)
    k = np.arange(pair_box.size) - np.repeat(np.cumsum(count) - count, count)
    pair_ray = order[np.repeat(starts[bin_id], count) + k]
    t_in = np.zeros(pair_ray.size)
    t_out = np.ones(pair_ray.size)
    for axis in range(3):
        da = d[pair_ray, axis]
        a, b = lo[pair_box, axis] - origin[axis], hi[pair_box, axis] - origin[axis]
        flat = da == 0.0
        safe = np.where(flat, 1.0, da)
        t0, t1 = a / safe, b / safe
        t_in = np.where(flat, np.where((a <= 0.0) & (b >= 0.0), t_in, 2.0),
                        np.maximum(t_in, np.minimum(t0, t1)))
        t_out = np.where(flat, t_out, np.minimum(t_out, np.maximum(t0, t1)))
    hit = (t_in <= t_out) & (t_in < 1.0)
    scale = np.ones(d.shape[0])
    np.minimum.at(scale, pair_ray[hit], t_in[hit])
    return scale


_ray_scales = jit.choose(_reference_ray_scales, compiled.ray_scales)
