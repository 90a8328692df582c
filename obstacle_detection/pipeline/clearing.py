"""Clearing evidence: every surface the camera saw, as ray ends for Nav2 (``docs/node.md``)."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from . import jit
from ._compiled import clearing as compiled
from .geometry import pixel_rays
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
    """Compile (or load from numba's disk cache) the clearing kernel, if it runs."""
    if jit.enabled():
        clearing_points(np.ones((6, 8), np.float32), Intrinsics(fx=4.0, fy=4.0, cx=4.0, cy=3.0),
                        stride_px=2, range_m=1.0)
