"""Exact K x K median filter of depth images, equal to scipy's (``docs/median.md``)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from . import jit
from ._compiled import _numba
from ._compiled import median as compiled
from .depth import lookup

#: Border mode of :func:`median_filter`: edge pixels repeated (no fake zeros = no return).
MEDIAN_MODE = 'nearest'


def reference_median(image: np.ndarray, k: int) -> np.ndarray:
    """Return ``scipy.ndimage.median_filter(image, size=k, mode='nearest')``: the definition."""
    return ndimage.median_filter(image, size=k, mode=MEDIAN_MODE)


#: The exact median for any K and dtype: the compiled sliding histogram, or scipy.
_exact_median = jit.choose(reference_median, compiled.median_filter)


def median_filter(image: np.ndarray, k: int, threads: int = 1) -> np.ndarray:
    """Exact K x K median filter (k odd), :func:`reference_median` to the bit; a new array.

    K = 3, 5 on uint16 or float32 run ``cv2.medianBlur``, larger K the compiled kernel.
    """
    arr = np.ascontiguousarray(image)
    if k == 1:
        return arr.copy()
    if arr.dtype.kind == 'f' and np.isnan(arr).any():
        return reference_median(arr, k)
    if k <= 5 and arr.dtype in (np.uint16, np.float32):
        return _opencv_median(arr, k)
    _numba.set_threads(threads)
    return _exact_median(arr, k)


def median_of_codes(codes: np.ndarray, k: int, table: np.ndarray,
                    threads: int = 1) -> np.ndarray:
    """Return ``median_filter(table[codes], k)``: the median commutes with a sorted table."""
    codes = np.ascontiguousarray(codes, np.uint16)
    return lookup(table, median_filter(codes, k, threads))


def _opencv_median(image: np.ndarray, k: int) -> np.ndarray:
    """Run ``cv2.medianBlur`` (K = 3, 5; uint16 or float32; borders replicated)."""
    h, w = image.shape
    if min(h, w) < k:   # OpenCV needs the window inside the image: pad as 'nearest' does
        r = k // 2
        padded = cv2.copyMakeBorder(image, r, r, r, r, cv2.BORDER_REPLICATE)
        return np.ascontiguousarray(cv2.medianBlur(padded, k)[r:r + h, r:r + w])
    return cv2.medianBlur(image, k)


def warm_up() -> None:
    """Compile (or load from numba's disk cache) the exact median of K > 5, if it runs.

    The default K = 5 runs OpenCV, so without this a node on the default never compiles the
    kernel and its start-up check (jit.cache_filled) would call numba's cache empty for ever.
    """
    if jit.enabled():
        for dtype in (np.uint16, np.float32):
            median_filter(np.arange(64, dtype=dtype).reshape(8, 8), 7)
