"""Compiled (numba) back-projection, region of interest and voxel grid of :mod:`..voxel`.

Bit-identical to the numpy path: the same float32 operations, float64 sums in point order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from obstacle_detection.labels import (LABEL_GROUND, LABEL_NO_RETURN, LABEL_OBSTACLE,
                                       LABEL_OUTSIDE_ROI)

from ._numba import jit as _jit, scratch
from .traversal import ray_row

#: Most lattice cells [cells] of the occupied-cell bitmap (as the numpy path's dense limit).
_DENSE_LIMIT = 16_000_000
#: uint64 0 and 1 (numba turns uint64 mixed with an int literal into float64).
_U0 = np.uint64(0)
_U1 = np.uint64(1)
#: Pixels whose rays are computed at once (96 kB, cache resident).
_RAY_BAND_PX = 8192


@_jit
def _project_kernel(depth, rays, offset, bounds, size, low, dims, labels, pixel_voxel, cols,
                    pix, keys):  # pragma: no cover - compiled
    """Back-project, keep the region of interest, key the kept points' voxels.

    offset: the image index of depth[0]; bounds: as :func:`project_roi`. Writes labels,
    pixel_voxel (-1) and the kept points' cols, pix, keys (on the lattice low, dims, which
    holds the region of interest: :func:`roi_lattice`); returns their number.
    """
    min_x, max_x, lateral = bounds[0], bounds[1], bounds[2]
    height, min_z, max_z = bounds[3], bounds[4], bounds[5]
    m = 0
    for p in range(depth.size):
        z = depth[p]
        pixel_voxel[p] = -1
        if not z > 0.0:
            labels[p] = LABEL_NO_RETURN
            continue
        gx = z * rays[0, p]
        gy = z * rays[1, p]
        gz = z * rays[2, p]
        gz = gz + height
        if (gx >= min_x and gx <= max_x and abs(gy) <= lateral and gz >= min_z
                and gz <= max_z):
            i = np.int64(np.floor(gx / size[0])) - low[0]
            j = np.int64(np.floor(gy / size[1])) - low[1]
            k = np.int64(np.floor(gz / size[2])) - low[2]
            labels[p] = LABEL_GROUND   # inside the region of interest until label_pixels
            cols[0, m] = gx
            cols[1, m] = gy
            cols[2, m] = gz
            pix[m] = p + offset
            keys[m] = (i * dims[1] + j) * dims[2] + k
            m += 1
        else:
            labels[p] = LABEL_OUTSIDE_ROI
    return m


@_jit
def _project_rays_kernel(depth, ru, rv, rot, chunk, bounds, size, low, dims, labels,
                         pixel_voxel, cols, pix, keys):  # pragma: no cover - compiled
    """_project_kernel with the rays of geometry.GroundRays computed into chunk, band by band."""
    width = ru.size
    height = rv.size
    band = max(1, chunk.shape[1] // width)
    m = 0
    for i0 in range(0, height, band):
        i1 = min(height, i0 + band)
        for a in range(3):
            for i in range(i0, i1):
                ray_row(ru, rv[i], rot[a, 0], rot[a, 1], rot[a, 2],
                        chunk[a, (i - i0) * width:(i - i0 + 1) * width])
        p0, p1 = i0 * width, i1 * width
        got = _project_kernel(depth[p0:p1], chunk[:, :p1 - p0], p0, bounds, size, low, dims,
                              labels[p0:p1], pixel_voxel[p0:p1], cols[:, m:], pix[m:],
                              keys[m:])
        m += got
    return m


@_jit(inline='always')
def _popcount(x):  # pragma: no cover - compiled
    """Return the number of set bits of the uint64 ``x`` (counted in parallel in the word)."""
    x = x - ((x >> _U1) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2))
                                               & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@_jit
def _voxel_kernel(cols, keys, n_cells, pixels, pixel_voxel, point_voxel, bits,
                  prefix):  # pragma: no cover - compiled
    """Give the occupied cells numbers in key order (a bitmap, bits; prefix: counts per word).

    Writes point_voxel (m,) and pixel_voxel at each point's pixel; bits must be all zero and
    are left so. Returns (centroids, point_voxel, counts).
    """
    n_words = (n_cells + 63) // 64
    m = point_voxel.shape[0]
    for q in range(m):
        key = keys[q]
        bits[key >> 6] |= _U1 << np.uint64(key & 63)
    n_vox = 0
    for w in range(n_words):
        prefix[w] = n_vox
        n_vox += _popcount(bits[w])
    counts = np.zeros(n_vox, np.int64)
    sums = np.zeros((n_vox, 3), np.float64)
    for q in range(m):
        key = keys[q]
        w = key >> 6
        v = prefix[w] + _popcount(bits[w] & ((_U1 << np.uint64(key & 63)) - _U1))
        point_voxel[q] = v
        counts[v] += 1
        sums[v, 0] += np.float64(cols[0, q])
        sums[v, 1] += np.float64(cols[1, q])
        sums[v, 2] += np.float64(cols[2, q])
        pixel_voxel[pixels[q]] = v
    for q in range(m):
        bits[keys[q] >> 6] = _U0
    centroids = np.empty((n_vox, 3), np.float32)
    for v in range(n_vox):
        n = np.float64(counts[v])
        for a in range(3):
            centroids[v, a] = np.float32(sums[v, a] / n)
    return centroids, point_voxel, counts


@_jit
def _label_kernel(labels, pixel_voxel, is_obstacle):  # pragma: no cover - compiled
    """labels[p] = LABEL_OBSTACLE or LABEL_GROUND where pixel_voxel[p] >= 0."""
    for p in range(labels.size):
        v = pixel_voxel[p]
        if v >= 0:
            labels[p] = LABEL_OBSTACLE if is_obstacle[v] else LABEL_GROUND


@dataclass
class Projection:
    """What :func:`project_roi` found in one depth image (flat pixel order).

    points (M, 3) float32, a view of cols (3, N); their flat pixel_index and voxel keys int64
    on the lattice ``low``, ``dims`` (None: too large a lattice); labels (H, W) uint8;
    pixel_voxel (H, W) int32, -1 until :func:`voxelise`; reuse: per-thread buffers.
    """

    points: np.ndarray
    pixel_index: np.ndarray
    keys: np.ndarray | None
    labels: np.ndarray
    pixel_voxel: np.ndarray
    low: np.ndarray
    dims: np.ndarray
    reuse: bool
    cols: np.ndarray


def roi_lattice(bounds: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Voxel lattice (low, dims) int64 holding every point inside the float32 bounds."""
    lo = np.array([bounds[0], -bounds[2], bounds[4]], np.float32)
    hi = np.array([bounds[1], bounds[2], bounds[5]], np.float32)
    low = np.floor(lo / size).astype(np.int64)
    dims = np.floor(hi / size).astype(np.int64) - low + 1
    return low, dims


def project_roi(depth_m: np.ndarray, rays: tuple, bounds: np.ndarray,
                voxel_size_m: tuple[float, float, float], *, reuse: bool = False,
                ) -> Projection:
    """Back-project a depth image through ground rays, keep the ROI, key the voxels.

    rays: GroundRays' factors (ru, rv, rot) of the image, computed on the fly; bounds:
    ``voxel.roi_bounds``. reuse: per-thread buffers that the thread's next call overwrites.
    """
    shape = depth_m.shape
    depth = np.ascontiguousarray(depth_m, np.float32).reshape(-1)
    n = depth.size
    band = max(1, _RAY_BAND_PX // shape[1]) * shape[1]   # whole rows
    chunk = scratch('ray_band', 3 * band, np.float32)[:3 * band].reshape(3, band)
    size = np.asarray(voxel_size_m, np.float32)
    low, dims = roi_lattice(bounds, size)
    labels = np.empty(shape, np.uint8)
    pixel_voxel = np.empty(shape, np.int32)
    if reuse:
        cols = scratch('cols', 3 * n, np.float32)[:3 * n].reshape(3, n)
        pix = scratch('pix', n, np.int64)[:n]
        keys = scratch('keys', n, np.int64)[:n]
    else:
        cols = np.empty((3, n), np.float32)
        pix = np.empty(n, np.int64)
        keys = np.empty(n, np.int64)
    keyed = int(dims[0]) * int(dims[1]) * int(dims[2]) <= _DENSE_LIMIT
    unkeyed = np.full(3, 1 << 62, np.int64)   # a lattice no key leaves: points only
    m = _project_rays_kernel(depth, *rays, chunk, bounds, size, low, dims if keyed else unkeyed,
                             labels.reshape(-1), pixel_voxel.reshape(-1), cols, pix, keys)
    return Projection(cols[:, :m].T, pix[:m], keys[:m] if keyed else None, labels, pixel_voxel,
                      low, dims, reuse, cols)


def voxelise(proj: Projection) -> tuple:
    """Return the VoxelGrid fields of a keyed :class:`Projection` (points); fill pixel_voxel."""
    m = proj.pixel_index.size
    n_cells = int(proj.dims[0] * proj.dims[1] * proj.dims[2])
    point_voxel = scratch('point_voxel', m, np.int64)[:m] if proj.reuse else np.empty(m,
                                                                                      np.int64)
    n_words = (n_cells + 63) // 64
    return _voxel_kernel(proj.cols, proj.keys, n_cells, proj.pixel_index,
                         proj.pixel_voxel.reshape(-1), point_voxel,
                         scratch('occupied_bits', n_words, np.uint64, zero=True),
                         scratch('bit_prefix', n_words, np.int64))


def label_pixels(labels: np.ndarray, pixel_voxel: np.ndarray, is_obstacle: np.ndarray) -> None:
    """In place: labels (H, W) uint8 of voxel pixels become LABEL_OBSTACLE or LABEL_GROUND."""
    _label_kernel(labels.reshape(-1), pixel_voxel.reshape(-1),
                  np.ascontiguousarray(is_obstacle, np.bool_))
