"""Compiled (numba) lookup of uint16 depth codes in a table, for :func:`..depth.lookup`."""

from __future__ import annotations

import numpy as np

from ._numba import jit


@jit
def lookup(table, codes):  # pragma: no cover - compiled
    """Return ``table[codes]``: (H, W) uint16 codes, (65536,) table; a new (H, W) array."""
    h, w = codes.shape
    out = np.empty((h, w), table.dtype)
    for y in range(h):
        for x in range(w):
            out[y, x] = table[codes[y, x]]
    return out
