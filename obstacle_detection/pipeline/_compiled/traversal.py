"""Compiled (numba) kernels of the robot-level stages and the floor fit.

Each equals its numpy twin ``_reference_<name>`` in :mod:`..traversal`, :mod:`..geometry` or
:mod:`..floor` to the bit (the same float operations in the same order); the tests compare them.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import jit as _jit, scratch


@_jit
def ray_row(ru, rv_i, r0, r1, r2, out):  # pragma: no cover - compiled
    """Fill out (W,) float32 with ``(r0 * ru[j] + r1 * rv_i) + r2`` (GroundRays' order)."""
    t = r1 * rv_i
    for j in range(ru.size):
        out[j] = (r0 * ru[j] + t) + r2


@_jit
def grid_cells(points, size):  # pragma: no cover - compiled
    """(ix, iy, nx, ny, ox, oy): each point's cell ``floor(p / size) - (ox, oy)``, grid nx x ny."""
    n = points.shape[0]
    ix = np.empty(n, np.int64)
    iy = np.empty(n, np.int64)
    for v in range(n):
        ix[v] = np.int64(np.floor(points[v, 0] / size))
        iy[v] = np.int64(np.floor(points[v, 1] / size))
    ox = ix.min()
    oy = iy.min()
    ix -= ox
    iy -= oy
    return ix, iy, ix.max() + 1, iy.max() + 1, ox, oy


@_jit
def _cell(bx, by, nx, ny):  # pragma: no cover - compiled
    """Return the index of cell (bx, by) of an nx x ny grid (x slowest), or -1 outside it."""
    if bx < 0 or bx >= nx or by < 0 or by >= ny:
        return -1
    return bx * ny + by


@_jit
def _passable_cells(points, steep, key, n_cells, step_up, layer,
                    min_support):  # pragma: no cover - compiled
    """(surface, passable) per cell: lowest flat voxel; supported and without a step."""
    n = points.shape[0]
    surface = np.full(n_cells, np.inf)
    low = np.full(n_cells, np.inf)
    high = np.full(n_cells, -np.inf)
    for v in range(n):
        k = key[v]
        z = np.float64(points[v, 2])
        if not steep[v] and z < surface[k]:
            surface[k] = z
        if z < low[k]:
            low[k] = z
        if z > high[k]:
            high[k] = z
    support = np.zeros(n_cells, np.int64)
    for v in range(n):
        k = key[v]
        if not steep[v] and np.float64(points[v, 2]) <= surface[k] + layer:
            support[k] += 1
    return surface, (surface != np.inf) & (high - low <= step_up) & (support >= min_support)


@_jit
def _reach(surface, passable, nx, ny, step_up, step_down):  # pragma: no cover - compiled
    """(reached, order): breadth-first from the floor seeds through allowed steps (8-connected)."""
    n_cells = nx * ny
    reached = np.zeros(n_cells, np.bool_)
    queue = np.empty(n_cells, np.int64)
    tail = 0
    for c in range(n_cells):
        s = surface[c]
        if passable[c] and s >= -step_down and s <= step_up:
            reached[c] = True
            queue[tail] = c
            tail += 1
    head = 0
    while head < tail:
        c = queue[head]
        head += 1
        cx, cy = c // ny, c % ny
        sa = surface[c]
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                if dx == 0 and dy == 0:
                    continue
                b = _cell(cx + dx, cy + dy, nx, ny)
                if b < 0 or reached[b] or not passable[b]:
                    continue
                rise = surface[b] - sa
                if rise <= step_up and -rise <= step_down:
                    reached[b] = True
                    queue[tail] = b
                    tail += 1
    return reached, queue[:tail].copy()


@_jit
def _local_ground(surface, reached, order, nx, ny):  # pragma: no cover - compiled
    """Ground per cell: its surface where reached, else grown layer by layer (largest)."""
    n_cells = nx * ny
    ground = np.zeros(n_cells)
    if order.size == 0:
        return ground
    done = reached.copy()
    for c in range(n_cells):
        if reached[c]:
            ground[c] = surface[c]
    frontier = order
    cand = np.empty(n_cells, np.int64)
    mark = np.zeros(n_cells, np.bool_)
    while frontier.size > 0:
        m = 0
        for c in frontier:
            cx, cy = c // ny, c % ny
            for dx in range(-1, 2):
                for dy in range(-1, 2):
                    b = _cell(cx + dx, cy + dy, nx, ny)
                    if b >= 0 and not done[b] and not mark[b]:
                        mark[b] = True
                        cand[m] = b
                        m += 1
        for i in range(m):
            b = cand[i]
            bx, by = b // ny, b % ny
            best = -np.inf
            for dx in range(-1, 2):
                for dy in range(-1, 2):
                    a = _cell(bx + dx, by + dy, nx, ny)
                    if a >= 0 and done[a] and ground[a] > best:
                        best = ground[a]
            ground[b] = best
        for i in range(m):
            done[cand[i]] = True
            mark[cand[i]] = False
        frontier = cand[:m].copy()
    return ground


@_jit
def _traverse_kernel(points, steep, size, step_up, step_down, robot, layer,
                     min_support):  # pragma: no cover - compiled
    """Run the numpy path of traversal.traversable_ground, cell by cell."""
    ix, iy, nx, ny, _, _ = grid_cells(points, size)
    key = ix * ny + iy
    surface, passable = _passable_cells(points, steep, key, nx * ny, step_up, layer,
                                        min_support)
    reached, order = _reach(surface, passable, nx, ny, step_up, step_down)
    ground = _local_ground(surface, reached, order, nx, ny)
    height = np.empty(points.shape[0], np.float32)
    for v in range(points.shape[0]):
        height[v] = np.float32(np.float64(points[v, 2]) - ground[key[v]])
    above = height > robot
    obstacle = ((height > np.float32(step_up)) & ~above) | (height < -np.float32(step_down))
    return obstacle, above, height, reached[key]


def traverse(points: np.ndarray, steep: np.ndarray, size_m: float, step_up_m: float,
             step_down_m: float, robot_height_m: float, layer_m: float, min_support: int = 3,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(obstacle, above, height float32, reached) per voxel; see traversal.traversable_ground."""
    return _traverse_kernel(np.ascontiguousarray(points, np.float32),
                            np.ascontiguousarray(steep, np.bool_), np.float32(size_m),
                            float(step_up_m), float(step_down_m), np.float32(robot_height_m),
                            float(layer_m), int(min_support))


@_jit
def _z_row(depth_row, rz_row, h, down, out):  # pragma: no cover - compiled
    """Fill out with the row's point heights (NaN: no return); return how many passed the floor."""
    nan = np.float32(np.nan)
    zero = np.float32(0.0)
    passed = 0
    for j in range(out.size):
        d = depth_row[j]
        z = d * rz_row[j] + h
        z = z if d > zero else nan
        out[j] = z
        passed += z < -down
    return passed


@_jit
def _drop_pixels_kernel(depth, ru, rv, rot, h, down, up, rows, zring, rz_row, passed,
                        pix_out, k_out):  # pragma: no cover - compiled
    """Fill pix_out/k_out with drop_edge_mask's marked pixels and offsets; return how many.

    The heights of rows i to i + rows rotate through zring (rows + 1, W), each row's rays
    computed into rz_row; only rows with a pixel below the floor (passed) are searched.
    """
    height, width = depth.shape
    ring = rows + 1
    m = 0
    for i in range(-rows, height):
        r = i + rows                  # the row that enters the ring
        if r < height:
            ray_row(ru, rv[r], rot[2, 0], rot[2, 1], rot[2, 2], rz_row)
            passed[r] = _z_row(depth[r], rz_row, h, down, zring[r % ring])
        if i < 0 or passed[i] == 0:
            continue
        zp = zring[i % ring]
        for j in range(width):
            a = zp[j]
            if not a < -down:
                continue
            for k in range(1, rows + 1):
                if i + k >= height:
                    break
                b = zring[(i + k) % ring, j]
                if b >= -down and b <= up and b - a > down:
                    pix_out[m] = i * width + j
                    k_out[m] = k
                    m += 1
                    break
    return m


def drop_pixels(depth_m: np.ndarray, ru: np.ndarray, rv: np.ndarray, rot: np.ndarray,
                height_m: float, step_down_m: float, step_up_m: float, rows: int,
                ) -> tuple[np.ndarray, np.ndarray]:
    """(flat pixel indices int64, offsets int8) of drop_edge_mask's marks, in order.

    ru, rv, rot: the GroundRays whose z the heights are computed with.
    """
    height, width = depth_m.shape
    pix = scratch('drop_pix', height * width, np.int64)[:height * width]
    offsets = scratch('drop_k', height * width, np.int8)[:height * width]
    ring = (int(rows) + 1) * width
    m = _drop_pixels_kernel(np.ascontiguousarray(depth_m, np.float32), ru, rv, rot,
                            np.float32(height_m), np.float32(step_down_m),
                            np.float32(step_up_m), int(rows),
                            scratch('drop_z', ring, np.float32)[:ring].reshape(-1, width),
                            scratch('drop_rz', width, np.float32)[:width],
                            scratch('drop_passed', height, np.int64)[:height], pix, offsets)
    return pix[:m].copy(), offsets[:m].copy()


@_jit
def _inverse_row(row, out):  # pragma: no cover - compiled
    """Fill out with 1 / row where row > 0 (1 elsewhere: such a pixel is never planar)."""
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for j in range(row.size):
        r = row[j]
        out[j] = one / (r if r > zero else one)


@_jit(inline='always')
def _near(v):  # pragma: no cover - compiled
    """Return the depth v if measured, else inf."""
    return v if v > np.float32(0.0) else np.float32(np.inf)


@_jit(inline='always')
def _far(v):  # pragma: no cover - compiled
    """Return the depth v if measured, else 0."""
    return v if v > np.float32(0.0) else np.float32(0.0)


@_jit(inline='always')
def _min5(a, b, c, d, e):  # pragma: no cover - compiled
    """Return the smallest of five values (no NaN)."""
    ab = a if a < b else b
    cd = c if c < d else d
    m = ab if ab < cd else cd
    return e if e < m else m


@_jit(inline='always')
def _max5(a, b, c, d, e):  # pragma: no cover - compiled
    """Return the largest of five values (no NaN)."""
    ab = a if a > b else b
    cd = c if c > d else d
    m = ab if ab > cd else cd
    return e if e > m else m


@_jit
def _column_range(r0, r1, r2, r3, r4, col_lo, col_hi):  # pragma: no cover - compiled
    """Fill col_lo/col_hi with the nearest (inf: none) and farthest (0) depth of five rows."""
    for j in range(col_lo.size):
        col_lo[j] = _min5(_near(r0[j]), _near(r1[j]), _near(r2[j]), _near(r3[j]), _near(r4[j]))
        col_hi[j] = _max5(_far(r0[j]), _far(r1[j]), _far(r2[j]), _far(r3[j]), _far(r4[j]))


@_jit
def _row_range(col_lo, col_hi, r_row, f_row, jump, near, far):  # pragma: no cover - compiled
    """Row pass of the window range (near, far: min/max of 5 taps, exact in any order).

    Returns (flying, filled): the row's flying candidates and filled holes.
    """
    zero = np.float32(0.0)
    flying = 0
    filled = 0
    for j in range(r_row.size):
        lo = _min5(col_lo[j], col_lo[j + 1], col_lo[j + 2], col_lo[j + 3], col_lo[j + 4])
        hi = _max5(col_hi[j], col_hi[j + 1], col_hi[j + 2], col_hi[j + 3], col_hi[j + 4])
        near[j] = lo
        far[j] = hi
        r = r_row[j]
        lim = jump * r
        flying += (r > zero) & (r - lo > lim) & (hi - r > lim)
        filled += (r <= zero) & (f_row[j] > zero)
    return flying, filled


@_jit
def _planar_row(mid, up, dn, iu, im, idn, tol_ratio, out):  # pragma: no cover - compiled
    """Fill out: the pixel and its 4 neighbours returned, 1/depth affine along row and column.

    mid, im, iu, idn (W + 2,): the row's depths and the inverse depths of it and the rows above
    and below, between pads (a 0 depth pad: no neighbour); up, dn (W,): those rows' depths.
    """
    zero = np.float32(0.0)
    two = np.float32(2.0)
    for j in range(out.size):
        inv = im[j + 1]
        tol = tol_ratio * inv
        row = abs(im[j] + im[j + 2] - two * inv)
        col = abs(iu[j + 1] + idn[j + 1] - two * inv)
        ok = (mid[j] > zero) & (mid[j + 2] > zero) & (up[j] > zero) & (dn[j] > zero)
        ok &= mid[j + 1] > zero
        out[j] = ok & (row <= tol) & (col <= tol)


@_jit
def _keep_row(mid, up, dn, f_row, ratio, out):  # pragma: no cover - compiled
    """Fill out: a filled hole keeps its depth (a measured 4-neighbour, all within ratio)."""
    zero = np.float32(0.0)
    for j in range(out.size):
        f = f_row[j]
        lim = ratio * f
        a = mid[j]
        b = mid[j + 2]
        c = up[j]
        d = dn[j]
        seen = (a > zero) | (b > zero) | (c > zero) | (d > zero)
        bad = ((a > zero) & ~(abs(a - f) <= lim)) | ((b > zero) & ~(abs(b - f) <= lim))
        bad |= ((c > zero) & ~(abs(c - f) <= lim)) | ((d > zero) & ~(abs(d - f) <= lim))
        out[j] = seen & ~bad


@_jit
def _decide_row(r_row, f_row, near, far, planar, keep, ratio, jump,
                ):  # pragma: no cover - compiled
    """Apply drop_smeared's rule along a row, in place, the masks of the row given."""
    zero = np.float32(0.0)
    for j in range(r_row.size):
        r = r_row[j]
        f = f_row[j]
        lim = jump * r
        fly = (r - near[j] > lim) & (far[j] - r > lim) & ~planar[j]
        moved = abs(f - r) > ratio * f
        v = f
        v = r if moved else v
        v = zero if fly else v
        w = f if keep[j] else zero
        f_row[j] = v if r > zero else w


@_jit
def _smear_kernel(filtered, raw, ratio, jump, tol_ratio, rows, planar,
                  keep):  # pragma: no cover - compiled
    """drop_smeared, row by row, with the 5 x 5 window range (clipped to the image) on the way.

    rows (9, W + 4) float32: the column pass's range between neutral pads (inf, 0) for the
    row pass's 5 taps, the row's range, row i between 0 pads, the inverse depths of rows
    i - 1 to i + 1 (a ring, computed for rows with flying candidates), zeros. Branch-free.
    """
    height, width = raw.shape
    col_lo, col_hi, near, far, mid, zeros = rows[0], rows[1], rows[2], rows[3], rows[4], rows[8]
    rows[:] = 0.0
    col_lo[:] = np.inf
    rows[5:8] = 1.0
    inv_of = np.full(3, -1, np.int64)   # the row whose inverse depths each ring row holds
    for i in range(height):
        # the window clipped to the image: its rows clamped (min and max are idempotent)
        _column_range(raw[max(i - 2, 0)], raw[max(i - 1, 0)], raw[i],
                      raw[min(i + 1, height - 1)], raw[min(i + 2, height - 1)],
                      col_lo[2:width + 2], col_hi[2:width + 2])
        rr = raw[i]
        fr = filtered[i]
        flying, filled = _row_range(col_lo, col_hi, rr, fr, jump, near, far)
        up = raw[i - 1] if i > 0 else zeros
        dn = raw[i + 1] if i + 1 < height else zeros
        mid[1:width + 1] = rr
        if flying:   # else planar is not looked at (nor the inverse depths)
            for k in range(max(0, i - 1), min(height, i + 2)):
                if inv_of[k % 3] != k:
                    _inverse_row(raw[k], rows[5 + k % 3, 1:width + 1])
                    inv_of[k % 3] = k
            _planar_row(mid, up, dn, rows[5 + (i - 1) % 3], rows[5 + i % 3],
                        rows[5 + (i + 1) % 3], tol_ratio, planar)
        if filled:
            _keep_row(mid, up, dn, fr, ratio, keep)
        else:        # no hole was filled: each hole stays empty
            keep[:] = False
        _decide_row(rr, fr, near, far, planar, keep, ratio, jump)


def drop_smeared(filtered: np.ndarray, raw: np.ndarray, max_shift: float, jump: float,
                 planar_tolerance: float) -> None:
    """In place: traversal's drop_smeared, its 5 x 5 window range computed on the way.

    filtered, raw: (H, W) float32 C-contiguous; raw without NaN (OpenCV's window range, the
    numpy path's, orders NaN its own way).
    """
    width = raw.shape[1]
    rows = scratch('smear_rows', 9 * (width + 4), np.float32)[:9 * (width + 4)]
    flags = scratch('smear_flags', 2 * width, np.bool_)[:2 * width].reshape(2, width)
    _smear_kernel(filtered, raw, np.float32(max_shift), np.float32(jump),
                  np.float32(planar_tolerance), rows.reshape(9, width + 4), flags[0], flags[1])


@_jit
def _unbias_kernel(filtered, raw, kernel, most, padded, window):  # pragma: no cover - compiled
    """In place: traversal's unbias_holes, the window's returns counted on the way.

    padded (W + kernel - 1,) int16: the returns of each column in the window's rows, slid down
    row by row, its ends replicated; window (W,) int16: their sums along the row.
    """
    height, width = raw.shape
    before = kernel // 2
    after = kernel - 1 - before
    zero = np.float32(0.0)
    one = np.int16(1)
    nil = np.int16(0)
    most = np.int16(most)
    columns = padded[before:before + width]
    columns[:] = 0
    for d in range(kernel):
        rd = raw[min(max(d - before, 0), height - 1)]
        for j in range(width):
            columns[j] += one if rd[j] > zero else nil
    for i in range(height):
        gone = min(max(i - 1 - before, 0), height - 1)
        come = min(i + after, height - 1)
        if i > 0 and gone != come:
            rg = raw[gone]
            rc = raw[come]
            for j in range(width):
                columns[j] += (one if rc[j] > zero else nil) - (one if rg[j] > zero else nil)
        padded[:before] = columns[0]
        padded[before + width:] = columns[width - 1]
        window[:] = padded[:width]
        for d in range(1, kernel):
            for j in range(width):
                window[j] += padded[j + d]
        rr = raw[i]
        fr = filtered[i]
        for j in range(width):
            r = rr[j]
            f = fr[j]
            back = r if f > zero else f      # its measured depth back (dropped stays so)
            new = back if r > zero else zero   # a hole the median filled: dropped
            fr[j] = new if window[j] <= most else f


def unbias_holes(filtered: np.ndarray, raw: np.ndarray, kernel: int, most: int) -> np.ndarray:
    """In place, returned: traversal.unbias_holes where at most ``most`` pixels returned.

    filtered, raw: (H, W) float32 C-contiguous; kernel <= 181 (its counts fit int16).
    """
    if raw.size:
        width = raw.shape[1]
        size = width + kernel - 1
        _unbias_kernel(filtered, raw, int(kernel), int(most),
                       scratch('unbias_padded', size, np.int16)[:size],
                       scratch('unbias_window', width, np.int16)[:width])
    return filtered


@_jit
def _floor_samples_kernel(depth, step, rays, height, tan_tilt, band0, min_x, max_x, max_y,
                          facing_cos2, out):  # pragma: no cover - compiled
    """Fill out (3, M) float64 with floor.floor_samples' points; return how many.

    depth: (H, W) float32, sampled every ``step`` pixels; rays: (3, gh * gw) of that grid.
    """
    gh = (depth.shape[0] + step - 1) // step
    gw = (depth.shape[1] + step - 1) // step
    nan = np.nan
    m = 0
    for gi in range(gh - 1):
        for gj in range(gw - 1):
            k = gi * gw + gj
            d = np.float64(depth[gi * step, gj * step])
            if not d > 0.0:
                continue
            dr = np.float64(depth[gi * step, (gj + 1) * step])
            dr = dr if dr > 0.0 else nan
            dd = np.float64(depth[(gi + 1) * step, gj * step])
            dd = dd if dd > 0.0 else nan
            x = d * np.float64(rays[0, k])
            y = d * np.float64(rays[1, k])
            z = d * np.float64(rays[2, k]) + height
            kr = k + 1
            kd = k + gw
            du0 = dr * np.float64(rays[0, kr]) - x
            du1 = dr * np.float64(rays[1, kr]) - y
            du2 = (dr * np.float64(rays[2, kr]) + height) - z
            dv0 = dd * np.float64(rays[0, kd]) - x
            dv1 = dd * np.float64(rays[1, kd]) - y
            dv2 = (dd * np.float64(rays[2, kd]) + height) - z
            nx = du1 * dv2 - du2 * dv1
            ny = du2 * dv0 - du0 * dv2
            nz = du0 * dv1 - du1 * dv0
            if not nz * nz >= (nx * nx + ny * ny + nz * nz) * facing_cos2:
                continue
            band = math.hypot(x, y) * tan_tilt
            band += band0
            if abs(z) <= band and x >= min_x and x <= max_x and abs(y) <= max_y:
                out[0, m] = x
                out[1, m] = y
                out[2, m] = z
                m += 1
    return m


@_jit
def _hypotheses(pts, picks, tan_tilt2, offset, planes):  # pragma: no cover - compiled
    """Fill planes (a, b, c) with those through the picked triplets within the tilt and offset.

    pts: (3, M) float64; picks: (3, h) in [0, 1), where in each third of the samples the
    triplet points are taken. Returns how many.
    """
    n = pts.shape[1]
    third = n // 3
    used = 0
    for t in range(picks.shape[1]):
        i0 = np.int64(picks[0, t] * third)
        i1 = np.int64(picks[1, t] * third) + third
        i2 = np.int64(picks[2, t] * third) + 2 * third
        u0 = pts[0, i1] - pts[0, i0]
        u1 = pts[1, i1] - pts[1, i0]
        u2 = pts[2, i1] - pts[2, i0]
        v0 = pts[0, i2] - pts[0, i0]
        v1 = pts[1, i2] - pts[1, i0]
        v2 = pts[2, i2] - pts[2, i0]
        nx = u1 * v2 - u2 * v1
        ny = u2 * v0 - u0 * v2
        nz = u0 * v1 - u1 * v0
        if not abs(nz) > 1e-9:
            continue
        ha = -nx / nz
        hb = -ny / nz
        hc = pts[2, i0] - ha * pts[0, i0] - hb * pts[1, i0]
        if ha * ha + hb * hb <= tan_tilt2 and abs(hc) <= offset:
            planes[used, 0] = ha
            planes[used, 1] = hb
            planes[used, 2] = hc
            used += 1
    return used


@_jit
def _mode_height(pts, offset):  # pragma: no cover - compiled
    """Return the most common sample height within the offset (1 cm bins), or 0."""
    counts = np.zeros(np.int64(np.floor((offset + offset) * 100.0)) + 1, np.int64)
    found = False
    for i in range(pts.shape[1]):
        z = pts[2, i]
        if abs(z) <= offset:
            counts[np.int64(np.floor((z + offset) * 100.0))] += 1
            found = True
    return (np.argmax(counts) + 0.5) * 0.01 - offset if found else 0.0


@_jit
def _scores(pts, planes, score_points, band32):  # pragma: no cover - compiled
    """Return the samples (every stride-th, float32) within band32 of each plane, int64."""
    stride = max(1, pts.shape[1] // score_points)
    sx = pts[0, ::stride].astype(np.float32)
    sy = pts[1, ::stride].astype(np.float32)
    sz = pts[2, ::stride].astype(np.float32)
    score = np.empty(planes.shape[0], np.int64)
    for t in range(planes.shape[0]):
        a32 = np.float32(planes[t, 0])
        b32 = np.float32(planes[t, 1])
        c32 = np.float32(planes[t, 2])
        count = 0
        for i in range(sx.size):
            r = a32 * sx[i]
            r += b32 * sy[i]
            r += c32
            r -= sz[i]
            count += abs(r) <= band32
        score[t] = count
    return score


@_jit
def ransac_plane(pts, picks, tan_tilt2, offset, band, score_points,
                 k):  # pragma: no cover - compiled
    """(k, 3) float64: floor.ransac_plane's best k hypotheses (the same float operations).

    The hypotheses: the triplets' planes, the configured floor and the level plane through
    the most common sample height; the best first, ties: the earlier hypothesis.
    """
    planes = np.zeros((picks.shape[1] + 2, 3))
    used = _hypotheses(pts, picks, tan_tilt2, offset, planes)
    planes[used + 1, 2] = _mode_height(pts, offset)   # planes[used]: the floor, (0, 0, 0)
    score = _scores(pts, planes[:used + 2], score_points, np.float32(band))
    return planes[np.argsort(-score, kind='mergesort')[:k]]


def floor_samples(depth_m: np.ndarray, step: int, sub_rays: np.ndarray, height_m: float,
                  tan_tilt: float, band0_m: float, min_x_m: float, max_x_m: float,
                  max_y_m: float, facing_cos2: float) -> np.ndarray:
    """(3, M) float64: floor.floor_samples' points, compiled (a fresh array)."""
    gh = (depth_m.shape[0] + step - 1) // step
    gw = (depth_m.shape[1] + step - 1) // step
    size = max(1, (gh - 1) * (gw - 1))
    buf = scratch('floor_samples', 3 * size, np.float64)[:3 * size].reshape(3, size)
    m = _floor_samples_kernel(np.ascontiguousarray(depth_m, np.float32), step,
                              np.ascontiguousarray(sub_rays, np.float32), float(height_m),
                              float(tan_tilt), float(band0_m), float(min_x_m), float(max_x_m),
                              float(max_y_m), float(facing_cos2), buf)
    return buf[:, :m].copy()
