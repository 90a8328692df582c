"""Compiled (numba) exact K x K median: a sliding histogram per row (Huang's algorithm).

The twin of ``scipy.ndimage.median_filter(image, size=k, mode='nearest')``; method:
``docs/median.md``. Rows are cut into one band per thread (``prange``).
"""

from __future__ import annotations

import numpy as np

from ._numba import jit, prange
from ._numba import numba as _numba

#: Keys per block of the histogram walk.
_BLOCK = 64


@jit(parallel=True)
def _histogram_median(keys, k, bands):  # pragma: no cover - compiled
    """Return the exact 'nearest'-mode median of (H, W) integer keys, rows in ``bands``."""
    h, w = keys.shape
    r = k // 2
    rank = k * k // 2             # the median's index in the sorted window
    size = (int(keys.max()) // _BLOCK + 1) * _BLOCK
    out = np.empty((h, w), keys.dtype)
    for band in prange(bands):
        hist = np.zeros(size, np.int32)
        rows = np.empty(k, np.int64)
        m = 0                     # the median of the last window, kept across rows
        below = 0                 # window keys < m
        for y in range(h * band // bands, h * (band + 1) // bands):
            for i in range(k):
                rows[i] = min(max(y - r + i, 0), h - 1)
            for dx in range(-r, r + 1):
                x = min(max(dx, 0), w - 1)
                for i in range(k):
                    v = np.int64(keys[rows[i], x])
                    hist[v] += 1
                    below += v < m
            for x in range(w):
                leaving = max(x - r - 1, 0)
                entering = min(x + r, w - 1)
                if x > 0 and leaving != entering:
                    for i in range(k):
                        v = np.int64(keys[rows[i], leaving])
                        hist[v] -= 1
                        below -= v < m
                        v = np.int64(keys[rows[i], entering])
                        hist[v] += 1
                        below += v < m
                while below > rank:                 # the median is below m
                    if m % _BLOCK == 0:
                        count = hist[m - _BLOCK:m].sum()
                        if below - count > rank:
                            m -= _BLOCK
                            below -= count
                            continue
                    m -= 1
                    below -= hist[m]
                while below + hist[m] <= rank:      # the median is above m
                    if m % _BLOCK == 0:
                        count = hist[m:m + _BLOCK].sum()
                        if below + count <= rank:
                            m += _BLOCK
                            below += count
                            continue
                    below += hist[m]
                    m += 1
                out[y, x] = m
            for dx in range(-r, r + 1):            # empty the histogram for the next row
                x = min(max(w - 1 + dx, 0), w - 1)
                for i in range(k):
                    v = np.int64(keys[rows[i], x])
                    hist[v] -= 1
                    below -= v < m
    return out


def median_filter(image: np.ndarray, k: int) -> np.ndarray:
    """``scipy.ndimage.median_filter(image, size=k, mode='nearest')``: (H, W) no NaN, k odd."""
    bands = _numba.get_num_threads()   # (numba cannot cache a kernel that asks itself)
    if image.dtype == np.uint16:
        return _histogram_median(np.ascontiguousarray(image), k, bands)
    values, ranks = np.unique(image, return_inverse=True)
    return values[_histogram_median(ranks.reshape(image.shape), k, bands)]
