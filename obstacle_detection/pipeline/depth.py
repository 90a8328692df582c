"""Depth frame decoding and border cropping (the median filter is :mod:`.median`).

All functions are numpy (no ROS); the lookup of uint16 codes is compiled when numba is there.
Depth images are (H, W) arrays; the pipeline format is float32 metres, C-contiguous, with 0.0
as the one "no return" value.
"""

from __future__ import annotations

import functools
import operator

import numpy as np

from . import jit
from ._compiled import depth as compiled

__all__ = [
    'MM_PER_M',
    'DepthFormatError',
    'check_image',
    'crop_borders',
    'decode_depth',
    'depth_lut',
    'lookup',
    'units_per_metre',
]

#: uint16 depth units per metre when no ``depth_scale`` is given (Kinect v2 / REP 118: mm).
MM_PER_M = 1000.0

_UINT16_LEVELS = 1 << 16


class DepthFormatError(ValueError):
    """A depth image with an unsupported dtype or shape."""


# --------------------------------------------------------------------------- decode / crop


@functools.lru_cache(maxsize=8)
def depth_lut(units_per_m: float, dtype: str = 'float32') -> np.ndarray:
    """Return the read-only table uint16 code -> metres, shape (65536,).

    Entry ``i`` is ``i / units_per_m`` computed in float64 and rounded once to ``dtype``.
    """
    lut = (np.arange(_UINT16_LEVELS, dtype=np.float64) / units_per_m).astype(dtype)
    lut.flags.writeable = False
    return lut


def _reference_lookup(table: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Return ``np.take(table, codes)``: (H, W) uint16 codes, (65536,) table; a new array.

    Compiled when :func:`.jit.enabled`: numpy's take first turns the codes into 64-bit
    indices, which costs about 0.25 ms more per 512 x 424 frame, twice per frame in the
    detector (the raw and the filtered depth): about 6 % of the node's time at K = 5.
    """
    return np.take(table, codes)


lookup = jit.choose(_reference_lookup, compiled.lookup)


def units_per_metre(depth_scale: float | None) -> float:
    """Return the uint16 units per metre of ``depth_scale`` (None: millimetres); ValueError."""
    scale = MM_PER_M if depth_scale is None else float(depth_scale)
    if not (np.isfinite(scale) and scale > 0.0):
        raise ValueError(f'depth_scale must be a finite number > 0, got {depth_scale!r}')
    return scale


def check_image(depth: np.ndarray, what: str) -> np.ndarray:
    """Return ``depth`` as an ndarray after checking it is a non-empty 2-D image."""
    arr = np.asarray(depth)
    if arr.ndim != 2 or arr.size == 0:
        raise DepthFormatError(
            f'{what} must be a non-empty 2-D (H, W) array, got shape {arr.shape} '
            f'(dtype {arr.dtype})')
    return arr


def decode_depth(depth: np.ndarray, *, depth_scale: float | None = None) -> np.ndarray:
    """Convert a raw depth frame to float32 metres.

    Args:
        depth: (H, W) depth image, either uint16 in 1/``depth_scale`` metres (millimetres by
            default, as Kinect v2 / ROS ``16UC1``), or float32/float64 in metres (ROS
            ``32FC1``). Any byte order is accepted.
        depth_scale: uint16 units per metre, e.g. 5000 for the TUM RGB-D data set. None means
            1000 (millimetres). Only valid with uint16 input.

    Returns:
        (H, W) float32 C-contiguous array of depths in metres (a new array). Pixels without a
        return -- 0, NaN, +-inf, negative (and -0.0) -- are exactly 0.0, the only no-return
        value used downstream.

    Raises:
        DepthFormatError: dtype other than uint16/float32/float64 (e.g. int8, uint8, bool,
            complex), not 2-D, or empty; or ``depth_scale`` given with float input.
        ValueError: ``depth_scale`` not a finite number > 0.
    """
    arr = check_image(depth, 'depth image')
    kind, size = arr.dtype.kind, arr.dtype.itemsize
    if kind == 'u' and size == 2:
        scale = units_per_metre(depth_scale)
        # One table lookup per pixel; code 0 maps to 0.0 (no return).
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
    """Blank the image borders, keeping the shape.

    Args:
        depth_m: (H, W) depth image, normally float32 metres (any dtype is kept).
        top: rows to blank at the top border [px], >= 0.
        bottom: rows to blank at the bottom border [px], >= 0.
        left: columns to blank at the left border [px], >= 0.
        right: columns to blank at the right border [px], >= 0.

    Returns:
        A C-contiguous copy of ``depth_m`` (same shape and dtype) whose first ``top`` rows,
        last ``bottom`` rows, first ``left`` and last ``right`` columns are 0 (no return).
        The shape is kept so pixel (v, u) still matches the camera intrinsics. Margins that
        cover the whole image give an all-zero image.

    Raises:
        DepthFormatError: ``depth_m`` not a non-empty 2-D array.
        ValueError: a negative margin. TypeError: a margin that is not an integer.
    """
    arr = check_image(depth_m, 'depth image')
    margins = {'top': top, 'bottom': bottom, 'left': left, 'right': right}
    for name, value in margins.items():
        margins[name] = operator.index(value)
        if margins[name] < 0:
            raise ValueError(f'crop margin {name}={value} must be >= 0')
    h, w = arr.shape
    out = np.array(arr, order='C', copy=True)
    out[:min(margins['top'], h)] = 0
    out[max(h - margins['bottom'], 0):] = 0
    out[:, :min(margins['left'], w)] = 0
    out[:, max(w - margins['right'], 0):] = 0
    return out
