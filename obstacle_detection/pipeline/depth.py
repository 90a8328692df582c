"""Depth frame decoding and border cropping: (H, W) float32 metres, 0.0 = no return."""

from __future__ import annotations

import functools

import numpy as np

from . import jit
from ._compiled import depth as compiled

#: uint16 depth units per metre when no ``depth_scale`` is given (Kinect v2 / REP 118: mm).
MM_PER_M = 1000.0

_UINT16_LEVELS = 1 << 16


class DepthFormatError(ValueError):
    """The pipeline's input error: a depth image or refiner model file it cannot use."""


@functools.lru_cache(maxsize=8)
def depth_lut(units_per_m: float, dtype: str = 'float32') -> np.ndarray:
    """Return the read-only (65536,) table uint16 code -> metres (float64, rounded once)."""
    lut = (np.arange(_UINT16_LEVELS, dtype=np.float64) / units_per_m).astype(dtype)
    lut.flags.writeable = False
    return lut


def _reference_lookup(table: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Return ``np.take(table, codes)``: (H, W) uint16 codes, (65536,) table; a new array."""
    return np.take(table, codes)


lookup = jit.choose(_reference_lookup, compiled.lookup)


def units_per_metre(depth_scale: float | None) -> float:
    """Return the uint16 units per metre of ``depth_scale`` (None: millimetres); ValueError."""
    scale = MM_PER_M if depth_scale is None else float(depth_scale)
    if not (np.isfinite(scale) and scale > 0.0):
        raise ValueError(f'depth_scale must be a finite number > 0, got {depth_scale!r}')
    return scale


def decode_depth(depth: np.ndarray, *, depth_scale: float | None = None) -> np.ndarray:
    """Convert a raw (H, W) depth frame to a new C-contiguous float32 array in metres.

    depth: uint16 in 1/``depth_scale`` m (None: mm) or float32/64 in m; no return becomes 0.0.
    Raises DepthFormatError for another dtype or shape, or a scale with float input.
    """
    arr = np.asarray(depth)
    if arr.ndim != 2 or arr.size == 0:
        raise DepthFormatError(f'depth image must be a non-empty 2-D (H, W) array, got shape '
                               f'{arr.shape} (dtype {arr.dtype})')
    kind, size = arr.dtype.kind, arr.dtype.itemsize
    if kind == 'u' and size == 2:
        scale = units_per_metre(depth_scale)
        return lookup(depth_lut(scale), arr.astype(np.uint16, copy=False))
    if kind == 'f' and size in (4, 8):
        if depth_scale is not None:
            raise DepthFormatError(
                f'depth_scale applies to uint16 depth only; got dtype {arr.dtype} (metres)')
        with np.errstate(over='ignore'):   # float64 beyond float32 range -> inf -> 0
            out = np.array(arr, dtype=np.float32, order='C', copy=True)
        # NaN fails both comparisons.
        np.copyto(out, np.float32(0.0), where=~((out > 0.0) & (out < np.inf)))
        return out
    raise DepthFormatError(
        f'unsupported depth dtype {arr.dtype} (shape {arr.shape}); expected uint16 '
        f'(1/depth_scale m, mm by default) or float32/float64 (m)')


def crop_borders(depth_m: np.ndarray, top: int, bottom: int, left: int,
                 right: int) -> np.ndarray:
    """Return a C-contiguous copy of ``depth_m`` with its border rows/columns (>= 0) set to 0."""
    h, w = depth_m.shape
    out = np.array(depth_m, order='C', copy=True)
    out[:min(top, h)] = 0
    out[max(h - bottom, 0):] = 0
    out[:, :min(left, w)] = 0
    out[:, max(w - right, 0):] = 0
    return out
