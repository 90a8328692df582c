"""Compiled exact k-nearest neighbours on a uniform grid, normals and validation (numba).

The compiled twins of :mod:`obstacle_detection.pipeline.normals`, with the same results: the
neighbours in (squared distance in float64 as scipy's cKDTree sums it, index) order, the query
itself first; the normals with the same float64 operations. Method: ``docs/method.md``.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import jit as _jit

#: Most cells of the grid's cell table; a grid that would have more is made coarser.
_MAX_CELLS = 1 << 22
#: Target mean number of other points in a point's grid cell, per neighbour asked for.
_CROWDING_PER_NEIGHBOUR = 0.5
#: Most cells along one grid axis, so linear cell keys fit comfortably in int64.
_MAX_AXIS_CELLS = 1 << 20


# --------------------------------------------------------------------------- grid k-NN kernel

@_jit
def _build_grid(pts, lo, cell):  # pragma: no cover - compiled
    """Sort points by cell: (cell_ijk, dims, order, sorted_pts, starts).

    Cell c (linear key) spans the sorted slots ``starts[c]:starts[c + 1]`` (points ``order``).
    """
    n = pts.shape[0]
    cell_ijk = np.empty((n, 3), np.int64)
    dims = np.ones(3, np.int64)
    for i in range(n):
        for a in range(3):
            c = np.int64(math.floor((pts[i, a] - lo[a]) / cell[a]))
            if c < 0:
                c = 0
            cell_ijk[i, a] = c
            if c + 1 > dims[a]:
                dims[a] = c + 1
    keys = np.empty(n, np.int64)
    for i in range(n):
        keys[i] = (cell_ijk[i, 0] * dims[1] + cell_ijk[i, 1]) * dims[2] + cell_ijk[i, 2]

    order = np.empty(n, np.int64)
    ncells = dims[0] * dims[1] * dims[2]
    starts = np.zeros(ncells + 1, np.int64)
    for i in range(n):
        starts[keys[i]] += 1
    total = 0
    for c in range(ncells):
        total += starts[c]
        starts[c] = total          # end of cell c
    starts[ncells] = n
    for i in range(n - 1, -1, -1):  # backwards: stable, starts[c] becomes the beginning
        starts[keys[i]] -= 1
        order[starts[keys[i]]] = i
    sorted_pts = np.empty((n, 3), np.float64)
    for s in range(n):
        for a in range(3):
            sorted_pts[s, a] = pts[order[s], a]
    return cell_ijk, dims, order, sorted_pts, starts


@_jit(inline='always')
def _squared_distance(a0, a1, a2, x0, x1, x2):  # pragma: no cover - compiled
    """Squared distance of (a0, a1, a2) to (x0, x1, x2), summed in scipy's order."""
    d0 = a0 - x0
    d1 = a1 - x1
    d2 = a2 - x2
    return d0 * d0 + d1 * d1 + d2 * d2


@_jit
def _axis_gap(offset, below, above, size, slack):  # pragma: no cover - compiled
    """Return the smallest distance along one axis from the query to a cell ``offset`` away."""
    if offset > 0:
        g = (offset - 1) * size + above - slack
    elif offset < 0:
        g = (-offset - 1) * size + below - slack
    else:
        return 0.0
    return g if g > 0.0 else 0.0


@_jit(inline='always')
def _gather_block(c0, c1, c2, dims, starts, sp, order, block_x, block_y, block_z,
                  block_j):  # pragma: no cover - compiled
    """Copy the points of the 3 x 3 x 3 cells around cell (c0, c1, c2) into the block arrays.

    Returns their number m (block_x/y/z, block_j: coordinates and index).
    """
    m = 0
    for o0 in range(max(c0 - 1, 0), min(c0 + 1, dims[0] - 1) + 1):
        for o1 in range(max(c1 - 1, 0), min(c1 + 1, dims[1] - 1) + 1):
            for o2 in range(max(c2 - 1, 0), min(c2 + 1, dims[2] - 1) + 1):
                key = (o0 * dims[1] + o1) * dims[2] + o2
                for t in range(starts[key], starts[key + 1]):
                    block_x[m] = sp[t, 0]
                    block_y[m] = sp[t, 1]
                    block_z[m] = sp[t, 2]
                    block_j[m] = order[t]
                    m += 1
    return m


@_jit(inline='always')
def _near_points(block_d, block_j, m, i, radius2, near_d, near_j):  # pragma: no cover
    """Keep the block's points within squared distance ``radius2`` of query i; return how many.

    The query itself gets distance -1 (first even among duplicates). Branch-free.
    """
    n_near = 0
    for u in range(m):
        d = block_d[u]
        j = block_j[u]
        near_d[n_near] = -1.0 if j == i else d
        near_j[n_near] = j
        n_near += d <= radius2
    return n_near


@_jit(inline='always')
def _rank_near(near_d, near_j, n_near, k, top, kth2):  # pragma: no cover - compiled
    """Write the k nearest of the n_near (>= k) near points into top[:k]; return the k-th d2.

    Ranks by counting (branch-free, padded to 8); ties among the first k: by (distance, index).
    """
    padded = (n_near + 7) & ~7
    for v in range(n_near, padded):
        near_d[v] = np.inf
    placed = 0
    rank_sum = 0
    for v in range(n_near):
        dv = near_d[v]
        rank = 0
        for w in range(padded):
            rank += np.int64(near_d[w] < dv)
        inside = rank < k
        slot = rank if inside else k
        top[slot] = near_j[v]
        kth2 = dv if rank == k - 1 else kth2
        placed += inside
        rank_sum += rank if inside else 0
    if placed != k or rank_sum != k * (k - 1) // 2:
        for v in range(n_near):
            dv = near_d[v]
            jv = near_j[v]
            rank = 0
            for w in range(n_near):
                rank += (near_d[w] < dv) | ((near_d[w] == dv) & (near_j[w] < jv))
            if rank < k:
                top[rank] = jv
            if rank == k - 1:
                kth2 = dv
    return kth2


@_jit(inline='always')
def _offer_span(begin, end, sp, order, x0, x1, x2, i, best_d, best_i, count, worst,
                k):  # pragma: no cover - compiled
    """Offer the sorted points begin .. end - 1 to query i's insertion-sorted top-k.

    Returns the new (count, worst): worst is the k-th squared distance once count == k.
    """
    last = k - 1
    for t in range(begin, end):
        j = order[t]
        d = _squared_distance(sp[t, 0], sp[t, 1], sp[t, 2], x0, x1, x2)
        if count == k:
            if d > worst or (d == worst and j > best_i[last]) or j == i:
                continue
            pos = last
        else:
            if j == i:
                continue
            pos = count
            count += 1
        while pos > 0 and (best_d[pos - 1] > d or (
                best_d[pos - 1] == d and best_i[pos - 1] > j)):
            best_d[pos] = best_d[pos - 1]
            best_i[pos] = best_i[pos - 1]
            pos -= 1
        best_d[pos] = d
        best_i[pos] = j
        if count == k:
            worst = best_d[last]
    return count, worst


@_jit(inline='always')
def _shell_cells(r, c0, c1, c2, dims):  # pragma: no cover - compiled
    """Return the number of grid cells within Chebyshev radius r of cell (c0, c1, c2)."""
    return ((min(r, dims[0] - 1 - c0) + min(r, c0) + 1)
            * (min(r, dims[1] - 1 - c1) + min(r, c1) + 1)
            * (min(r, dims[2] - 1 - c2) + min(r, c2) + 1))


@_jit(inline='always')
def _search_shells(i, x0, x1, x2, c0, c1, c2, below, above, cell, slack, dims, starts, sp,
                   order, best_d, best_i, k, budget):  # pragma: no cover - compiled
    """Search shells of cells of growing Chebyshev radius around query i's cell.

    Fills best_d / best_i, pruning cells farther than the k-th best. Returns False when more
    than ``budget`` cells would be looked at (the caller scans all points instead).
    """
    best_d[0] = -1.0              # the query itself comes first, even among duplicates
    best_i[0] = i
    count = 1
    worst = np.inf if k > 1 else -1.0   # k-th best squared distance so far
    looked = 0
    r_max = max(max(c0, dims[0] - 1 - c0), max(max(c1, dims[1] - 1 - c1),
                                             max(c2, dims[2] - 1 - c2)))
    for r in range(r_max + 1):
        if r > 0 and count == k:
            # every cell of shell r (Chebyshev radius r) lies at least this far away
            bound = np.inf
            for a in range(3):
                edge = min(below[a], above[a]) + (r - 1) * cell[a] - slack
                bound = min(bound, edge)
            if bound > 0.0 and bound * bound > worst:
                break
        # the grid cells of shell r: within radius r but not r - 1
        looked += _shell_cells(r, c0, c1, c2, dims)
        if r > 0:
            looked -= _shell_cells(r - 1, c0, c1, c2, dims)
        if looked > budget:
            return False
        lo2 = -min(r, c2)
        hi2 = min(r, dims[2] - 1 - c2)
        for o0 in range(-min(r, c0), min(r, dims[0] - 1 - c0) + 1):
            g0 = _axis_gap(o0, below[0], above[0], cell[0], slack)
            g0 = g0 * g0
            if g0 > worst:
                continue
            for o1 in range(-min(r, c1), min(r, dims[1] - 1 - c1) + 1):
                g1 = _axis_gap(o1, below[1], above[1], cell[1], slack)
                g01 = g0 + g1 * g1
                if g01 > worst:
                    continue
                face = o0 == -r or o0 == r or o1 == -r or o1 == r
                # a face of the shell: the whole column; inside: only the two end cells
                for o2 in range(lo2 if face else -r, hi2 + 1, 1 if face else 2 * r):
                    if o2 < lo2:
                        continue
                    g2 = _axis_gap(o2, below[2], above[2], cell[2], slack)
                    if g01 + g2 * g2 > worst:
                        continue
                    key = ((c0 + o0) * dims[1] + (c1 + o1)) * dims[2] + (c2 + o2)
                    count, worst = _offer_span(starts[key], starts[key + 1], sp, order, x0, x1,
                                               x2, i, best_d, best_i, count, worst, k)
    return True


@_jit
def _knn_queries(lo, cell, k, slack, cell_ijk, dims, order, sp, starts,
                 out):  # pragma: no cover - compiled
    """Search every query of a :func:`_build_grid` grid, in sorted (cell) order, into ``out``.

    Per cell, the points of its 3 x 3 x 3 block are gathered once; a query keeps those closer
    than the block's boundary and, if at least k, ranks them (:func:`_rank_near`); else it
    searches shells (:func:`_search_shells`) or scans all points. A query's answer does not
    depend on the others (the previous one's k-th distance only picks the first radius).
    """
    n = order.shape[0]
    best_d = np.empty(k, np.float64)
    best_i = np.empty(k, np.int64)
    below = np.empty(3, np.float64)
    above = np.empty(3, np.float64)
    # the current block's points, gathered once per cell: coordinates and index
    block_x = np.empty(n, np.float64)
    block_y = np.empty(n, np.float64)
    block_z = np.empty(n, np.float64)
    block_j = np.empty(n, np.int64)
    block_d = np.empty(n, np.float64)
    near_d = np.empty(n + 8, np.float64)
    near_j = np.empty(n + 8, np.int64)
    top = np.empty(k + 1, np.int64)
    budget = 2 * n + 512              # cells to look at before a plain scan is cheaper
    rank_limit = 4 * k + 64           # more near points (a crowded cell): insertion is cheaper
    group_end = 0
    m = 0
    kth2_prev = np.inf                # squared k-th distance of the previous query
    for s in range(n):   # queries in cell order: neighbouring cells stay cached
        i = order[s]
        c0 = cell_ijk[i, 0]
        c1 = cell_ijk[i, 1]
        c2 = cell_ijk[i, 2]
        if s == group_end:            # first point of a new cell: gather its block
            group_end = starts[(c0 * dims[1] + c1) * dims[2] + c2 + 1]
            m = _gather_block(c0, c1, c2, dims, starts, sp, order, block_x, block_y, block_z,
                              block_j)
        x0 = sp[s, 0]
        x1 = sp[s, 1]
        x2 = sp[s, 2]
        reach = np.inf                # distance to the block's boundary
        for a in range(3):
            below[a] = sp[s, a] - (lo[a] + cell_ijk[i, a] * cell[a])
            above[a] = cell[a] - below[a]
            reach = min(reach, min(below[a], above[a]) + cell[a] - slack)
        reach2 = reach * reach if reach > 0.0 else -1.0
        # First try a radius a little beyond the previous query's k-th neighbour (queries in
        # cell order are close, so it usually holds k points and fewer others), then reach.
        radius2 = min(reach2, 1.21 * kth2_prev)
        for u in range(m):   # a loop of its own: vectorised
            block_d[u] = _squared_distance(block_x[u], block_y[u], block_z[u], x0, x1, x2)
        n_near = _near_points(block_d, block_j, m, i, radius2, near_d, near_j)
        if n_near < k and radius2 != reach2:
            n_near = _near_points(block_d, block_j, m, i, reach2, near_d, near_j)
        if k <= n_near <= rank_limit:
            kth2_prev = _rank_near(near_d, near_j, n_near, k, top, kth2_prev)
            for col in range(k):
                out[i, col] = top[col]
            continue
        if not _search_shells(i, x0, x1, x2, c0, c1, c2, below, above, cell, slack, dims,
                              starts, sp, order, best_d, best_i, k, budget):
            # far-apart points: a plain scan is the cheaper search
            _offer_span(0, n, sp, order, x0, x1, x2, i, best_d, best_i, 1, np.inf, k)
        kth2_prev = best_d[k - 1]
        for col in range(k):
            out[i, col] = best_i[col]


# ---------------------------------------------------------------------------- grid planning

@_jit
def _crowding(pts, lo, extent, size):  # pragma: no cover - compiled
    """Return the mean number of other points in a point's own cell of a ``size`` grid."""
    n = pts.shape[0]
    dims = (np.floor(extent / size) + 1.0).astype(np.int64)
    keys = np.empty(n, np.int64)
    for i in range(n):
        key = 0
        for a in range(3):
            c = np.int64(math.floor((pts[i, a] - lo[a]) / size))
            c = min(max(c, 0), dims[a] - 1)
            key = key * dims[a] + c
        keys[i] = key
    total = 0
    if np.float64(dims[0]) * dims[1] * dims[2] <= 16.0 * n + 65536.0:
        counts = np.zeros(dims[0] * dims[1] * dims[2], np.int64)
        for i in range(n):
            counts[keys[i]] += 1
        for i in range(n):
            total += counts[keys[i]]
    else:                              # too many cells for a table: count sorted runs
        keys.sort()
        run = 1
        for i in range(1, n + 1):
            if i < n and keys[i] == keys[i - 1]:
                run += 1
            else:
                total += run * run
                run = 1
    return total / n - 1.0


@_jit
def _cell_size(pts, lo, extent, k):  # pragma: no cover - compiled
    """Pick the grid cell [m] so that a point's own cell holds about ``k / 2`` other points.

    The crowding is counted at about n cells and the size scaled as for a surface, whose
    crowding grows as ``size ** 2`` (voxels of surfaces). Only speed depends on it.
    """
    n = pts.shape[0]
    dim = 0
    volume = 1.0
    largest = 0.0
    for a in range(3):
        if extent[a] > 0.0:
            dim += 1
            volume *= extent[a]
        largest = max(largest, extent[a])
    if dim == 0:
        return 1.0                              # all points coincide: one cell
    smallest = largest / (_MAX_AXIS_CELLS - 1)
    size = max((volume / n) ** (1.0 / dim), smallest)     # about n cells
    crowd = _crowding(pts, lo, extent, size)
    if crowd > 0.0:
        size *= min(max((_CROWDING_PER_NEIGHBOUR * k / crowd) ** 0.5, 0.25), 4.0)
    else:
        size *= 2.0                             # every point alone: a very sparse cloud
    return max(size, smallest)


@_jit
def _knn_setup(pts, k):  # pragma: no cover - compiled
    """Plan the grid: (lo, cell, slack) of finite points."""
    n = pts.shape[0]
    lo = np.empty(3, np.float64)
    extent = np.empty(3, np.float64)
    scale = 0.0
    for a in range(3):
        low = np.inf
        high = -np.inf
        for i in range(n):
            x = pts[i, a]
            low = min(low, x)
            high = max(high, x)
        lo[a] = low
        extent[a] = high - low
        scale = max(scale, abs(low) + extent[a])
    size = _cell_size(pts, lo, extent, k)
    while np.prod(np.floor(extent / size) + 1.0) > _MAX_CELLS:   # far-apart points
        size *= 2.0
    # cell membership is computed in float64; this margin covers its rounding
    slack = 1e-9 * (scale + size)
    return lo, np.full(3, size), slack


# ------------------------------------------------------------------------------ public API

def knn_grid(points: np.ndarray, k: int) -> np.ndarray:
    """Return indices (V, k) int64 of the exact k nearest points of every point, nearest first."""
    pts = np.asarray(points)
    n = pts.shape[0]
    k = min(int(k), n)
    if n == 0 or k <= 0:
        return np.zeros((n, max(k, 0)), dtype=np.int64)
    out = np.empty((n, k), dtype=np.int64)
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    lo, cell, slack = _knn_setup(pts, k)
    _knn_queries(lo, cell, k, slack, *_build_grid(pts, lo, cell), out)
    return out


# --------------------------------------------------------------------------- normals kernel

@_jit(inline='always')
def _covariance_row(pts, neighbours, v, n_use):  # pragma: no cover - compiled
    """Six entries (a00, a01, a02, a11, a12, a22) of row v's covariance, float64."""
    count = np.float64(n_use)
    px = np.float64(pts[v, 0])
    py = np.float64(pts[v, 1])
    pz = np.float64(pts[v, 2])
    sx = sy = sz = s00 = s01 = s02 = s11 = s12 = s22 = -0.0   # -0.0 + x is x, to the bit
    for t in range(n_use):
        j = neighbours[v, t]
        rx = np.float64(pts[j, 0]) - px
        ry = np.float64(pts[j, 1]) - py
        rz = np.float64(pts[j, 2]) - pz
        sx += rx
        sy += ry
        sz += rz
        s00 += rx * rx
        s01 += rx * ry
        s02 += rx * rz
        s11 += ry * ry
        s12 += ry * rz
        s22 += rz * rz
    m0 = sx / count
    m1 = sy / count
    m2 = sz / count
    return (s00 / count - m0 * m0, s01 / count - m0 * m1, s02 / count - m0 * m2,
            s11 / count - m1 * m1, s12 / count - m1 * m2, s22 / count - m2 * m2)


@_jit(inline='always')
def _smallest_eigenvalue(a00, a01, a02, a11, a12, a22):  # pragma: no cover - compiled
    """Return (lambda, p2): the smallest eigenvalue (the cubic's trigonometric root), p2."""
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00 = a00 - q
    b11 = a11 - q
    b22 = a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = math.sqrt(p2 / 6.0)
    safe_p = p if p > 0.0 else 1.0
    det_b = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
             + a02 * (a01 * a12 - b11 * a02))
    r = det_b / (2.0 * (safe_p * safe_p * safe_p))
    r = min(max(r, -1.0), 1.0)
    phi = math.acos(r) / 3.0
    return q + 2.0 * p * math.cos(phi + 2.0 * np.pi / 3.0), p2


@_jit(inline='always')
def _eigenvector(a00, a01, a02, a11, a12, a22, lam):  # pragma: no cover - compiled
    """Return (x, y, z, length): the longest cross product of two rows of C - lam I."""
    r00 = a00 - lam
    r11 = a11 - lam
    r22 = a22 - lam
    best_len2 = -1.0
    bx = 0.0
    by = 0.0
    bz = 0.0
    for c in range(3):
        if c == 0:    # row0 x row1
            ux, uy, uz, wx, wy, wz = r00, a01, a02, a01, r11, a12
        elif c == 1:  # row0 x row2
            ux, uy, uz, wx, wy, wz = r00, a01, a02, a02, a12, r22
        else:         # row1 x row2
            ux, uy, uz, wx, wy, wz = a01, r11, a12, a02, a12, r22
        cx = uy * wz - uz * wy
        cy = uz * wx - ux * wz
        cz = ux * wy - uy * wx
        len2 = cx * cx + cy * cy + cz * cz
        if len2 > best_len2:
            best_len2 = len2
            bx = cx
            by = cy
            bz = cz
    return bx, by, bz, math.sqrt(best_len2)


@_jit
def _normals_kernel(pts, neighbours, n_use, normals, cov, bad):  # pragma: no cover
    """Write every row's normal as the numpy twin does; return the number of degenerate rows.

    Degenerate rows are marked in ``bad`` (cov (V, 6) holds every row's covariance: the
    caller asks LAPACK for them, as numpy does).
    """
    v_count = pts.shape[0]
    for v in range(v_count):
        (cov[v, 0], cov[v, 1], cov[v, 2], cov[v, 3], cov[v, 4],
         cov[v, 5]) = _covariance_row(pts, neighbours, v, n_use)
    lam = np.empty(v_count, np.float64)
    p2 = np.empty(v_count, np.float64)
    for v in range(v_count):
        lam[v], p2[v] = _smallest_eigenvalue(cov[v, 0], cov[v, 1], cov[v, 2], cov[v, 3],
                                             cov[v, 4], cov[v, 5])
    tiny = np.finfo(np.float64).tiny
    n_bad = 0
    for v in range(v_count):
        bx, by, bz, length = _eigenvector(cov[v, 0], cov[v, 1], cov[v, 2], cov[v, 3],
                                          cov[v, 4], cov[v, 5], lam[v])
        scale = p2[v] if p2[v] > tiny else tiny
        bad[v] = length * length <= 1e-12 * scale * scale
        if bad[v]:
            n_bad += 1
        else:
            normals[v, 0] = np.float32(bx / length)
            normals[v, 1] = np.float32(by / length)
            normals[v, 2] = np.float32(bz / length)
    return n_bad


def normals_from_neighbours(points: np.ndarray, neighbours: np.ndarray, n: int) -> np.ndarray:
    """Return unit normals (V, 3) float32 of the first n neighbours (V, >= n) of each point."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    nb = np.asarray(neighbours).astype(np.int64, copy=False)
    v_count = pts.shape[0]
    normals = np.empty((v_count, 3), dtype=np.float32)
    cov_bad = np.empty((v_count, 6), dtype=np.float64)    # every row's covariance
    bad = np.empty(v_count, dtype=np.bool_)
    if _normals_kernel(pts, nb, int(n), normals, cov_bad, bad):   # degenerate: LAPACK, as numpy
        cov = cov_bad[bad][:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
        normals[bad] = np.linalg.eigh(cov)[1][:, :, 0]
    return normals


@_jit
def _validate_kernel(is_obstacle, neighbours, n1):  # pragma: no cover - compiled
    """(V,) bool: is_obstacle[v] and its n1 neighbours'."""
    v_count = is_obstacle.shape[0]
    out = np.empty(v_count, np.bool_)
    for v in range(v_count):
        keep = is_obstacle[v]
        for t in range(1, n1 + 1):
            keep = keep and is_obstacle[neighbours[v, t]]
        out[v] = keep
    return out


def validate(is_obstacle: np.ndarray, neighbours: np.ndarray, n1: int) -> np.ndarray:
    """Return ``normals.validate_obstacles`` for 1 <= n1 < the neighbour columns."""
    return _validate_kernel(np.ascontiguousarray(is_obstacle, np.bool_),
                            neighbours.astype(np.int64, copy=False), int(n1))
