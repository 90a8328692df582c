"""Compiled (numba) twins of ``clearing._reference_clearing_points`` and ``_ray_scales``."""

from __future__ import annotations

import numpy as np

from ._numba import jit


@jit
def _point(z, x_per_z, y_per_z, range_m, out, row):  # pragma: no cover - compiled
    """Write the point of depth z on ray (x/z, y/z) within range into out[row], in float32."""
    distance = z * np.sqrt(np.float32(1.0) + x_per_z * x_per_z + y_per_z * y_per_z)
    z = z * min(np.float32(1.0), np.float32(range_m) / distance)
    out[row, 0] = x_per_z * z
    out[row, 1] = y_per_z * z
    out[row, 2] = z


@jit
def clearing_points(depth, ru, rv, rows, cols, range_m, fractions):  # pragma: no cover
    """Return the kept pixels' points in image order, then the border points per fraction."""
    width = depth.shape[1]
    kept = 0   # the kept pixels with a return; first / last: each kept row's outermost
    first = np.full(rows.shape[0], -1, np.int64)
    last = np.full(rows.shape[0], -1, np.int64)
    for r in range(rows.shape[0]):
        for c in range(width):
            if np.isfinite(depth[rows[r], c]) and depth[rows[r], c] > 0.0:
                first[r] = c
                break
        for c in range(width - 1, first[r] - 1 if first[r] >= 0 else width, -1):
            if np.isfinite(depth[rows[r], c]) and depth[rows[r], c] > 0.0:
                last[r] = c
                break
        for c in cols:
            z = depth[rows[r], c]
            kept += np.isfinite(z) and z > 0.0
    edges = np.flatnonzero(first >= 0)
    n_edge = 2 * edges.shape[0]
    out = np.empty((kept + n_edge * len(fractions), 3), np.float32)
    row = 0
    for r in range(rows.shape[0]):
        for c in cols:
            z = depth[rows[r], c]
            if np.isfinite(z) and z > 0.0:
                _point(z, ru[c], rv[rows[r]], range_m, out, row)
                row += 1
    edge = np.empty((n_edge, 3), np.float32)
    for e in range(n_edge):
        r = edges[e % edges.shape[0]]
        c = first[r] if e < edges.shape[0] else last[r]
        _point(depth[rows[r], c], ru[c], rv[rows[r]], range_m, edge, e)
    for f in range(len(fractions)):
        out[kept + f * n_edge:kept + (f + 1) * n_edge] = edge * np.float32(fractions[f])
    return out


@jit
def ray_scales(d, origin, lo, hi, window, order, starts, nbx):  # pragma: no cover - compiled
    """Per ray, the fraction of it before any box: the twin of the reference, box by box."""
    scale = np.ones(d.shape[0])
    for b in range(lo.shape[0]):
        for by in range(window[b, 2], window[b, 3]):
            for bx in range(window[b, 0], window[b, 1]):
                cell = by * nbx + bx
                for j in range(starts[cell], starts[cell + 1]):
                    r = order[j]
                    t_in = 0.0
                    t_out = 1.0
                    for axis in range(3):
                        da = d[r, axis]
                        a = lo[b, axis] - origin[axis]
                        c = hi[b, axis] - origin[axis]
                        if da == 0.0:
                            if not (a <= 0.0 and c >= 0.0):
                                t_in = 2.0
                        else:
                            t0 = a / da
                            t1 = c / da
                            t_in = max(t_in, min(t0, t1))
                            t_out = min(t_out, max(t0, t1))
                    if t_in <= t_out and t_in < 1.0 and t_in < scale[r]:
                        scale[r] = t_in
    return scale
