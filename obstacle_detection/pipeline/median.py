"""Exact, fast K x K median filter of depth images (:func:`median_filter`).

Its output is identical to ``scipy.ndimage.median_filter(depth_m, size=k, mode='nearest')``
(see :data:`MEDIAN_MODE`). Three exact algorithms (OpenCV's medianBlur, a sorting network on
whole images, a two-pass 8-bit medianBlur) run in numpy/OpenCV; the compiled network of
:mod:`._compiled.median` runs instead for K = 7 .. 31 when :func:`.jit.enabled`. This module
builds the networks' programs and makes that choice.
"""

from __future__ import annotations

import functools
import operator
import time
from typing import Any

import cv2
import numpy as np
from scipy import ndimage

from . import jit, parallel
from ._compiled import median as jit_median
from .depth import MM_PER_M, DepthFormatError, check_image, depth_lut

__all__ = ['MEDIAN_MODE', 'median_and_decode', 'median_filter', 'median_of_codes', 'warm_up']

#: Border mode of :func:`median_filter`, as a ``scipy.ndimage`` mode: the image is extended
#: by repeating its edge pixels (OpenCV ``BORDER_REPLICATE``). Unlike 'constant' it adds no
#: fake zeros (= no return) along the border.
MEDIAN_MODE = 'nearest'

_UINT16_LEVELS = 1 << 16
#: Runs of median bands per thread (:func:`median_filter` with threads > 1): a thread that
#: starts late leaves its runs to the others; each run sorts K - 1 more rows into its ring.
BANDS_PER_THREAD = 2

#: Depth quantisations tried to turn float metres into exact uint16 keys for the median:
#: millimetres (Kinect, ROS 16UC1) and 1/5000 m (TUM RGB-D).
_KEY_UNITS_PER_M = (MM_PER_M, 5000.0)


def median_filter(depth_m: np.ndarray, k: int, threads: int = 1) -> np.ndarray:
    """Exact K x K median filter, equal to ``scipy.ndimage.median_filter`` but much faster.

    The result is identical (``np.testing.assert_array_equal``) to
    ``scipy.ndimage.median_filter(depth_m, size=k, mode='nearest')``: outside the image the
    edge pixels are repeated (:data:`MEDIAN_MODE`, OpenCV ``BORDER_REPLICATE``).

    Zeros (no return) are ordinary values here and take part in the median like any depth,
    exactly as in scipy: a pixel whose window is mostly valid gets a valid depth (isolated
    "pepper" zeros are filled), while a pixel whose window holds more than K*K // 2 zeros
    becomes 0 (an isolated valid pixel among zeros is removed).

    Method (every path is exact; which one runs depends only on K and the data):

    - K = 3, 5: OpenCV's sorting-network ``cv2.medianBlur`` (uint8, uint16, float32).
    - Larger K first map the values to uint16 keys with the same order. Depth quantised to
      millimetres (or 1/5000 m, TUM RGB-D) gets key = round(1000 * value), accepted when no
      key stands for two different values, so :func:`decode_depth`'s output and any other
      rounding of millimetre data (e.g. ``float32(mm) * 1e-3``) qualify in well under a
      millisecond. Other data get their rank among the distinct values (``np.unique``,
      about 6 ms per 512 x 424 frame) if there are at most 65536; more run the sorting
      network on the raw values (slower). Keys all below 256 use one 8-bit medianBlur.
    - K = 7 .. 31 with numba (:mod:`._compiled.median`, unless ``OBSTACLE_DETECTION_NO_JIT=1``):
      the sorting network below, turned by 90 degrees and compiled, on row chunks (float32
      metres are keyed by one compiled pass): for K <= 21 as straight-line vector code whose
      values stay in registers, for larger K by an interpreter. Data independent, except
      that outputs whose window holds more than K*K // 2 copies of the lowest key (0 = no
      return) are that key and skip the merge phase. Without numba, or switched off, the
      paths below run.
    - K = 7 .. 15: an exact min/max sorting network on whole images: every vertical
      K-window is sorted, and the sorted columns are merged with Batcher's odd-even merge,
      sharing work between neighbouring output columns and dropping values that can no
      longer be the median. Data independent.
    - K >= 17: two 8-bit ``cv2.medianBlur`` passes, exact because the median commutes with
      any non-decreasing map: a coarse pass on ``keys >> s`` (s = bit length of the largest
      key - 8) gives ``median >> s``; a fine pass on tiles of ``clip(keys - base, 0, 255)``
      (base per tile and 256-key group, with a K // 2 margin) gives the low bits. The tiles
      are chosen to minimise the filtered area (see the two-pass section below); where
      medians spread over many 256-key groups in every tile (noise-like data) it falls back
      to the network. The cost depends on the scene: steep depth gradients (walls seen at
      a grazing angle, the far floor) need thin tiles whose margins are filtered too.

    One thread, 512 x 424 Kinect-like frames (``scenes.render_scene``, float32 m), on a
    shared 2-core machine (absolute times varied up to 2x with the other jobs): K=5 0.6 ms.
    Compiled: K=7 0.8 ms, K=9 1.0 ms, K=13 1.5 ms, K=17 1.7-3.0 ms (1.7 with the most no
    return, ramps; 3.0 on corridor frames), K=21 3.5-4.5 ms in registers; K=31 18-21 ms
    through the interpreter (uint16 mm input is 0.2-0.3 ms faster than float32 m).
    Without numba: K=7 3.5-6.5 ms, K=9 6-10 ms, K=17 10-14 ms on floor scenes and 17-21 ms
    on corridor and farm-row scenes (the network alone: 25-35 ms), K=31 18-30 ms. scipy
    takes 0.1 s at K=7, 0.5 s at K=17 and 1.4 s at K=31.

    Args:
        depth_m: (H, W) image: float32 metres (pipeline format), uint16, or any other real
            integer / float dtype. Input containing NaN is passed to scipy unchanged (slow).
        k: window size K, odd, >= 1 (1 returns a copy). Any odd size works (the default
            parameters use 17).
        threads: threads the compiled in-register kernel (K = 7 .. 21) may use: its bands of
            output rows are cut into :data:`BANDS_PER_THREAD` runs per thread
            (:mod:`.parallel`); the same result. The other paths run on the calling thread.

    Returns:
        (H, W) C-contiguous array of the input dtype (a new array).

    Raises:
        ValueError: ``k`` even or < 1 (TypeError if not an integer).
        DepthFormatError: ``depth_m`` not a non-empty 2-D array, or a bool / complex /
            non-numeric dtype.
    """
    k = _check_kernel(k)
    arr = check_image(depth_m, 'median input')
    if arr.dtype.kind not in 'uif':
        raise DepthFormatError(f'median_filter needs a real numeric image, got dtype '
                               f'{arr.dtype} (shape {arr.shape})')
    arr = np.ascontiguousarray(arr)
    if k == 1:
        return arr.copy()
    if arr.dtype.kind == 'f' and np.isnan(arr.min()):
        return ndimage.median_filter(arr, size=k, mode=MEDIAN_MODE)
    if arr.dtype == np.uint8 or (k <= 5 and arr.dtype in (np.uint16, np.float32)):
        return _cv_median(arr, k)
    keys, values = _order_keys(arr)
    if keys is None:  # more than 65536 distinct values: run the network on the raw values
        return _network_median(arr, k)
    med = None
    if keys.max() < 256:
        med = _cv_median(keys.astype(np.uint8), k).astype(np.uint16)
    elif k <= 5:
        med = _cv_median(keys, k)
    elif k <= _JIT_MAX_K and jit.enabled():
        threads = parallel.check_threads(threads)
        med = jit_median.network_median(
            keys, _jit_program(k), parts=threads * BANDS_PER_THREAD if threads > 1 else 1,
            run_parts=functools.partial(parallel.run_parts, threads=threads))
    elif k >= _TWO_PASS_MIN_K:
        med = _two_pass_median(keys, k)
    if med is None:
        med = _network_median(keys, k)
    if values is None:
        return med
    if values.dtype == np.float32 and jit.enabled():
        return jit_median.take(values, med)
    return np.take(values, med)


def median_of_codes(codes: np.ndarray, k: int, table: np.ndarray,
                    threads: int = 1) -> np.ndarray:
    """Return ``median_filter(table[codes], k)`` computed on the codes, then looked up.

    codes: (H, W) uint16 raw depth (e.g. millimetres); table: (65536,) float32, the codes'
    depths in metres (:func:`.depth.depth_lut`), non-decreasing. The K x K median commutes
    with a non-decreasing map (the middle value of the window stays the middle value), so
    this equals the median of the decoded image to the bit, without mapping the decoded
    depths back to keys and the median's keys to depths (0.3-0.5 ms at 512 x 424).
    """
    return _median_of_codes(codes, k, table, threads, decode_input=False)


def median_and_decode(codes: np.ndarray, k: int, table: np.ndarray,
                      threads: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Return (:func:`median_of_codes`, ``table[codes]``): the filtered and the raw depth.

    With the compiled network the threads that filter a band of rows also look its raw
    codes up, so the decode costs no time of its own; otherwise the raw depth is looked up
    after the median. The same arrays either way.
    """
    return _median_of_codes(codes, k, table, threads, decode_input=True)


def _median_of_codes(codes: np.ndarray, k: int, table: np.ndarray, threads: int,
                     decode_input: bool) -> Any:
    """:func:`median_of_codes`, and with ``decode_input`` also ``table[codes]`` (a tuple)."""
    k = _check_kernel(k)
    codes = np.ascontiguousarray(check_image(codes, 'median input'), np.uint16)
    compiled = (jit.enabled() and 7 <= k <= _JIT_MAX_K and table.dtype == np.float32
                and table.shape == (_UINT16_LEVELS,))
    keys_range = jit_median.key_range(codes) if compiled else None
    if compiled and keys_range[1] >= 256:
        # the compiled network, each band of rows looked up by the thread that filtered it
        threads = parallel.check_threads(threads)
        return jit_median.network_median(
            codes, _jit_program(k), parts=threads * BANDS_PER_THREAD if threads > 1 else 1,
            run_parts=functools.partial(parallel.run_parts, threads=threads), table=table,
            decode_input=decode_input, keys_range=keys_range)
    filtered = _lookup(table, median_filter(codes, k, threads))
    return (filtered, _lookup(table, codes)) if decode_input else filtered


def _lookup(table: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Return ``table[codes]``: compiled for a float32 table, else numpy's take."""
    if table.dtype == np.float32 and jit.enabled():
        return jit_median.take(table, codes)
    return np.take(table, codes)


def _check_kernel(k: int) -> int:
    """Return ``k`` as an int after checking it is an odd window size >= 1."""
    if isinstance(k, (bool, np.bool_)):
        raise TypeError(f'median kernel size must be an integer, got {k!r}')
    k = operator.index(k)
    if k < 1 or k % 2 == 0:
        raise ValueError(f'median kernel size must be odd and >= 1, got {k}')
    return k


def _cv_median(img: np.ndarray, k: int) -> np.ndarray:
    """Run ``cv2.medianBlur`` (BORDER_REPLICATE, exact) and return a C-contiguous result.

    ``img``: (H, W) uint8 for any odd k; uint16 or float32 for k <= 5.
    """
    h, w = img.shape
    if min(h, w) < k:
        # Pad by replication so OpenCV never sees an image smaller than its window; the
        # central crop equals the 'nearest' median of the original.
        r = k // 2
        padded = cv2.copyMakeBorder(img, r, r, r, r, cv2.BORDER_REPLICATE)
        return np.ascontiguousarray(cv2.medianBlur(padded, k)[r:r + h, r:r + w])
    return cv2.medianBlur(img, k)


def _order_keys(arr: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Map an image to uint16 keys with the same order.

    Returns ``(keys, values)``: keys (H, W) uint16 with ``values[keys] == arr`` exactly and
    ``arr[p] < arr[q]`` iff ``keys[p] < keys[q]``; ``values`` is None when the keys are the
    image itself (uint16). ``(None, None)`` when there are more than 65536 distinct values.
    """
    if arr.dtype == np.uint16:
        return arr, None
    if arr.dtype == np.float32 and jit.enabled():
        for units_per_m in _KEY_UNITS_PER_M:   # one compiled pass each
            found = jit_median.quantised_keys(arr, units_per_m)
            if found is not None:
                return found
    if arr.dtype.kind == 'f' and arr.dtype.itemsize in (4, 8):
        lo, hi = arr.min(), arr.max()
        for units_per_m in _KEY_UNITS_PER_M:
            if not (lo >= 0.0 and hi * units_per_m <= _UINT16_LEVELS - 1):
                continue
            # Depth quantised to 1/units_per_m m: key = round(units_per_m * value). The map
            # value -> key is non-decreasing, so it is an exact order-preserving code as soon
            # as no key stands for two different values.
            scaled = np.multiply(arr, arr.dtype.type(units_per_m))
            np.rint(scaled, out=scaled)
            keys = scaled.astype(np.uint16)
            values = depth_lut(units_per_m, arr.dtype.name)   # as decode_depth makes it
            step = 61                      # a sample first: other roundings differ early
            if (np.array_equal(np.take(values, keys.reshape(-1)[::step]), arr.reshape(-1)[::step])
                    and np.array_equal(np.take(values, keys), arr)):
                return keys, values
            # Any other rounding of the same quantised data, e.g. float32(mm) * 1e-3.
            values = np.zeros(_UINT16_LEVELS, arr.dtype)
            values[keys.ravel()] = arr.ravel()
            if np.array_equal(np.take(values, keys), arr):
                return keys, values
    uniq, inverse = np.unique(arr, return_inverse=True)
    if uniq.size > _UINT16_LEVELS:
        return None, None
    return inverse.reshape(arr.shape).astype(np.uint16), uniq


# ------------------------------------------------- two-pass 8-bit median (K >= 17)
#
# For any non-decreasing map g, the median of g(window) is g(median of window) (odd count).
# cv2.medianBlur is exact on uint8 for any odd K, and for K >= 17 (images under a megapixel)
# it uses an O(1) histogram algorithm whose cost does not grow with K. So:
#   1. Coarse pass: level = medianBlur(keys >> s) with s = bit_length(max key) - 8, which is
#      exactly median >> s: the median lies in [level << s, ((level + 1) << s) - 1].
#   2. Fine pass, per tile: a group of span = 256 >> s consecutive levels starting at level
#      b covers 256 keys. One 8-bit medianBlur of the tile plus a K // 2 margin, mapped by
#      g(x) = clip(x - (b << s), 0, 255), returns g(median) = median - (b << s) for every
#      tile pixel whose level is in the group. A tile needs one pass per group its pixels'
#      levels fall in: either consecutive groups from its lowest level ("unaligned", best for
#      a smooth range) or the occupied ones of the groups aligned at multiples of span
#      ("aligned", best for a tile across a depth edge), whichever are fewer.
# The tiles are a partition of the image into dyadic rectangles (_FINE_LEAF * 2**a rows by
# _FINE_LEAF * 2**b columns, a, b <= _FINE_LEVELS) that minimises the filtered area,
# sum over tiles of passes * (rows + 2R) * (columns + 2R), found by dynamic programming from
# the smallest rectangles up (a rectangle is kept, or split in halves along y or x). Thin
# tiles follow depth bands (floor: rows; walls: columns). All tiles of one shape go through
# one medianBlur call, stacked into a tall mosaic; a tile's windows never leave its own block,
# so blocks do not interact. Pixels whose level holds a single key value (the lowest level,
# with 0 = no return, in depth images) need no fine pass. Sparse keys of 8192 and more are
# replaced by their rank among the distinct keys first, so that a few far outliers (65535)
# do not widen the levels of all the others.

#: Largest K run by the compiled network (:mod:`._compiled.median`) when it is enabled; larger K
#: use the two-pass method. Up to here the network is faster on every scene measured (at
#: K = 25 .. 31 the two-pass method is faster on floor scenes but much slower on walls).
_JIT_MAX_K = 31

#: Smallest K for the two-pass method: below 17, cv2.medianBlur switches to its O(K)
#: algorithm on images under a megapixel and the sorting network is faster.
_TWO_PASS_MIN_K = 17
#: Smallest fine-pass tile side [px] and number of doublings above it (largest 256 px).
_FINE_LEAF = 16
_FINE_LEVELS = 4
#: Fall back to the sorting network when the fine pass would filter more than this many
#: times the image area (data with a wide spread of values in every tile, e.g. noise).
_FINE_MAX_AREA = 8.0
_ALL_BITS = (1 << 64) - 1
#: Keys from this value up are ranked first if they are sparse (see _two_pass_median).
_COMPACT_FROM = 1 << 13


def _two_pass_median(keys: np.ndarray, k: int) -> np.ndarray | None:
    """Exact 'nearest'-mode K x K median of uint16 keys by 8-bit coarse + tiled fine passes.

    ``keys``: (H, W) uint16, C-contiguous; k odd >= 3. Returns an (H, W) uint16 array, or
    None when the fine pass would cost more than :data:`_FINE_MAX_AREA` image areas.
    """
    h, w = keys.shape
    r = k // 2
    kmin, kmax = int(keys.min()), int(keys.max())
    if kmax >= _COMPACT_FROM:
        # Sparse large keys (e.g. a few 65535 "far" codes above mm depths) would make the
        # coarse levels wide; rank the distinct keys instead when that saves a bit.
        present = np.zeros(kmax + 1, bool)
        present[keys.reshape(-1)] = True
        values = np.flatnonzero(present)
        if (values.size - 1).bit_length() < kmax.bit_length():
            rank = (np.cumsum(present, dtype=np.int32) - 1).astype(np.uint16)
            med = _two_pass_median(np.take(rank, keys), k)
            return None if med is None else np.take(values.astype(np.uint16), med)
    shift = max(0, kmax.bit_length() - 8)
    leaf, n_lev = _FINE_LEAF, _FINE_LEVELS
    # Smallest multiple of leaf * 2**i that covers each side, i <= n_lev.
    n_y = min(n_lev, (-(-h // leaf) - 1).bit_length())
    n_x = min(n_lev, (-(-w // leaf) - 1).bit_length())
    ph, pw = -(-h // (leaf << n_y)) * (leaf << n_y), -(-w // (leaf << n_x)) * (leaf << n_x)
    # Replicate padding = scipy's 'nearest'; beyond the image (up to ph, pw) it only feeds
    # outputs that are cropped away.
    padded = cv2.copyMakeBorder(keys, r, r + ph - h, r, r + pw - w, cv2.BORDER_REPLICATE)
    coarse = (padded[:h + 2 * r, :w + 2 * r] >> shift).astype(np.uint8)
    level = cv2.medianBlur(coarse, k)[r:r + h, r:r + w]
    if shift == 0:
        return level.astype(np.uint16)
    # Does the lowest level hold a single key value (kmin: 0 = no return in depth images)?
    lowest = kmin >> shift
    resolved = None
    if not np.any((keys > kmin) & (keys < (lowest + 1) << shift)):
        resolved = level == lowest

    # Per leaf tile, over the pixels that need the fine pass: lowest and highest level
    # (lo > hi: none), and (shift <= 6) the occupied aligned groups as a bit mask.
    lvl_lo = np.full((ph, pw), 255, np.uint8)
    lvl_lo[:h, :w] = level
    lvl_hi = np.zeros((ph, pw), np.uint8)
    lvl_hi[:h, :w] = level
    if resolved is not None:                 # resolved pixels are at the lowest level
        np.copyto(lvl_lo[:h, :w], np.uint8(255), where=resolved)
        np.copyto(lvl_hi[:h, :w], np.uint8(0), where=resolved)
    lo = _leaf_reduce(np.minimum, lvl_lo, leaf).astype(np.int32)
    hi = _leaf_reduce(np.maximum, lvl_hi, leaf).astype(np.int32)
    bits = None
    if shift <= 6:
        bits = _leaf_groups(lvl_lo, lvl_hi, lo, hi, leaf, 8 - shift)
    area, shapes = _plan_tiles(lo, hi, bits, leaf, n_y, n_x, r, 256 >> shift)
    if area > _FINE_MAX_AREA * h * w:
        return None
    out = np.empty((ph, pw), np.uint16)
    for shape, tiles, tile_lo, tile_hi, tile_bits in shapes:
        _fine_pass(padded, lvl_hi, out, shape, tiles, tile_lo, tile_hi, tile_bits, k, shift)
    out = out[:h, :w]
    if resolved is not None:
        np.copyto(out, np.uint16(kmin), where=resolved)
    return np.ascontiguousarray(out)


def _leaf_reduce(op: np.ufunc, img: np.ndarray, leaf: int) -> np.ndarray:
    """Reduce (H, W) ``img`` with ``op`` over leaf x leaf blocks; H, W multiples of leaf."""
    rows = op.reduce([img[i::leaf] for i in range(leaf)])
    return op.reduce([rows[:, i::leaf] for i in range(leaf)])


def _leaf_groups(lvl_lo: np.ndarray, lvl_hi: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 leaf: int, group_shift: int) -> np.ndarray:
    """Return the (Ly, Lx) uint64 mask of aligned groups (level >> group_shift) per leaf.

    ``lvl_lo``, ``lvl_hi``: (PH, PW) uint8 levels with 255 / 0 where no fine pass is needed;
    ``lo``, ``hi``: their (Ly, Lx) leaf minima / maxima. Groups from lo's to hi's are set;
    leaves where that range has a group in between are checked pixel by pixel, as a depth
    edge can leave it empty.
    """
    g_lo = (lo >> group_shift).astype(np.uint64)
    g_hi = (np.maximum(hi, 0) >> group_shift).astype(np.uint64)
    one = np.uint64(1)
    bits = (np.uint64(_ALL_BITS) >> (np.uint64(63) - g_hi)) & ~((one << g_lo) - one)
    bits[hi < lo] = 0
    iy, ix = np.nonzero((hi >= lo) & (g_hi > g_lo + one))
    if iy.size:
        shape = (lo.shape[0], leaf, lo.shape[1], leaf)
        tile_lo = lvl_lo.reshape(shape)[iy, :, ix, :]
        tile_hi = lvl_hi.reshape(shape)[iy, :, ix, :]
        px = np.left_shift(one, (tile_hi >> group_shift).astype(np.uint64))
        px[tile_lo != tile_hi] = 0           # pixels that need no fine pass
        bits[iy, ix] = np.bitwise_or.reduce(px.reshape(iy.size, -1), axis=1)
    return bits


def _popcount(x: np.ndarray) -> np.ndarray:
    """Return the number of set bits of each element of uint64 ``x`` as int32 (any numpy)."""
    as_bytes = np.ascontiguousarray(x).view(np.uint8).reshape(x.shape + (8,))
    return np.unpackbits(as_bytes, axis=-1).sum(axis=-1, dtype=np.int32)


def _passes(lo: np.ndarray, hi: np.ndarray, bits: np.ndarray | None,
            span: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Return (fine passes per tile, use-aligned mask or None); 0 passes where hi < lo."""
    unaligned = (hi - lo) // span + 1
    np.maximum(unaligned, 0, out=unaligned)
    if bits is None:
        return unaligned, None
    aligned = _popcount(bits)
    use = aligned < unaligned
    return np.where(use, aligned, unaligned), use


def _plan_tiles(lo: np.ndarray, hi: np.ndarray, bits: np.ndarray | None, leaf: int, n_y: int,
                n_x: int, r: int, span: int) -> tuple[int, list]:
    """Choose the fine-pass tiles of :func:`_two_pass_median`.

    ``lo``, ``hi``: (Ly, Lx) int32 lowest / highest level per leaf tile (lo > hi where no
    pixel needs the fine pass), Ly a multiple of 2**n_y, Lx of 2**n_x; ``bits``: (Ly, Lx)
    uint64 mask of the aligned groups that may occur, or None; ``span``: levels per fine
    pass. Returns
    (filtered area [px], [((rows, cols), (tile row index, tile column index), lo, hi, bits
    or None) per tile shape]).
    """
    ops = (np.minimum, np.maximum, np.bitwise_or)
    stats, best, split_y, split_x = {}, {}, {}, {}
    for a in range(n_y + 1):
        for b in range(n_x + 1):
            if a == 0 and b == 0:
                st = (lo, hi, bits)
            elif a > 0:   # two tiles of class (a - 1, b) stacked along y
                st = tuple(None if x is None else op(x[0::2], x[1::2])
                           for op, x in zip(ops, stats[a - 1, b]))
            else:
                st = tuple(None if x is None else op(x[:, 0::2], x[:, 1::2])
                           for op, x in zip(ops, stats[a, b - 1]))
            stats[a, b] = st
            cost = _passes(*st, span)[0] * (((leaf << a) + 2 * r) * ((leaf << b) + 2 * r))
            if a > 0:
                half = best[a - 1, b][0::2] + best[a - 1, b][1::2]
                split_y[a, b] = half < cost
                np.minimum(cost, half, out=cost)
            if b > 0:
                half = best[a, b - 1][:, 0::2] + best[a, b - 1][:, 1::2]
                split_x[a, b] = half < cost
                np.minimum(cost, half, out=cost)
            best[a, b] = cost
    area = int(best[n_y, n_x].sum())
    # Walk down from the whole image: a tile is active when its parent split into it; a
    # split along x overrides one along y (it was found better after it).
    active = {(n_y, n_x): np.ones(best[n_y, n_x].shape, bool)}
    shapes = []
    for a in range(n_y, -1, -1):
        for b in range(n_x, -1, -1):
            act = active.get((a, b))
            if act is None:
                continue
            keep = act
            for axis, split, child in ((1, split_x, (a, b - 1)), (0, split_y, (a - 1, b))):
                if (a, b) not in split:
                    continue
                sel = keep & split[a, b]
                keep = keep & ~sel
                if sel.any():
                    down = np.repeat(sel, 2, axis=axis)
                    active[child] = active[child] | down if child in active else down
            keep &= stats[a, b][1] >= stats[a, b][0]
            if keep.any():
                shapes.append(((leaf << a, leaf << b), np.nonzero(keep),
                               *(None if x is None else x[keep] for x in stats[a, b])))
    return area, shapes


def _fine_pass(padded: np.ndarray, levels: np.ndarray, out: np.ndarray, shape: tuple[int, int],
               tiles: tuple[np.ndarray, np.ndarray], lo: np.ndarray, hi: np.ndarray,
               bits: np.ndarray | None, k: int, shift: int) -> None:
    """Fine pass of :func:`_two_pass_median` over the chosen tiles of one shape.

    ``padded``: (PH + 2R, PW + 2R) replicate-padded uint16 keys; ``levels``: (PH, PW) uint8
    coarse level per pixel (any value where resolved); ``out``: (PH, PW) uint16, written on
    the tiles; ``shape``: (rows, cols) of a tile [px]; ``tiles``: (tile row index, tile
    column index) of the n tiles; ``lo``, ``hi``, ``bits``: (n,) their level range and
    aligned group mask (as in :func:`_plan_tiles`).
    """
    rows, cols = shape
    r = k // 2
    span = 256 >> shift
    n_slots = 1 << shift                 # groups of span levels in 0..255
    tile_y, tile_x = tiles
    # Group slot s of a tile covers levels [ref + s * span, ref + (s + 1) * span): ref = lo
    # for unaligned tiles, 0 for aligned ones; present[t, s]: the tile needs that pass.
    n_passes, aligned = _passes(lo, hi, bits, span)
    slot = np.arange(n_slots)
    present = slot < n_passes[:, None]
    ref = lo.copy()
    if aligned is not None and aligned.any():
        present[aligned] = (bits[aligned, None] >> slot.astype(np.uint64)) & np.uint64(1) > 0
        ref[aligned] = 0
    tile_of, block_slot = np.nonzero(present)            # blocks, sorted by tile
    base = ((ref[tile_of] + block_slot * span) << shift).astype(np.uint16)[:, None, None]
    bh, bw = rows + 2 * r, cols + 2 * r
    rs, cs = padded.strides
    windows = np.lib.stride_tricks.as_strided(
        padded, (padded.shape[0] // rows, padded.shape[1] // cols, bh, bw),
        (rows * rs, cols * cs, rs, cs), writeable=False)
    blocks = windows[tile_y[tile_of], tile_x[tile_of]]         # (blocks, bh, bw) copy
    np.maximum(blocks, base, out=blocks)
    blocks -= base
    if rows > cols:
        # Stack tall blocks transposed: cv2's O(1) algorithm slides along rows and is
        # cheaper when the median changes slowly along them (depth bands of walls).
        blocks = np.ascontiguousarray(blocks.transpose(0, 2, 1))
    mosaic = cv2.convertScaleAbs(blocks.reshape(-1, blocks.shape[2]))   # min(., 255)
    flat = cv2.medianBlur(mosaic, k).reshape(-1)
    fine = flat.reshape(blocks.shape)           # (blocks, bh, bw) uint8 view of flat
    if rows > cols:
        fine = fine.transpose(0, 2, 1)
    grid = out.reshape(out.shape[0] // rows, rows, out.shape[1] // cols, cols)
    first = np.searchsorted(tile_of, np.arange(tile_y.size))   # first block of each tile
    one = n_passes == 1
    if one.any():
        b = first[one]
        grid[tile_y[one], :, tile_x[one], :] = fine[b, r:r + rows, r:r + cols] + base[b]
    if not one.all():
        # Each pixel takes the block of its own level's group.
        many = ~one
        t_y, t_x = tile_y[many], tile_x[many]
        block_of = np.cumsum(present[many], axis=1) - 1 + first[many, None]   # (m, slots)
        t_ref = ref[many, None, None]
        group = levels.reshape(grid.shape)[t_y, :, t_x, :] - t_ref   # int32
        group //= span
        np.clip(group, 0, n_slots - 1, out=group)     # resolved pixels: any block
        block = np.take_along_axis(block_of, group.reshape(group.shape[0], -1), axis=1)
        block = np.maximum(block, first[many, None]).reshape(group.shape)
        step_b, step_y, step_x = fine.strides           # in elements: uint8
        pixel = (np.arange(r, r + rows) * step_y)[:, None] + np.arange(r, r + cols) * step_x
        values = np.take(flat, block * step_b + pixel)
        grid[t_y, :, t_x, :] = values + base[block, 0, 0]


# ----------------------------------------------------- sorting-network median (K >= 3)
#
# A network is built symbolically once per (K, tile) and cached. Values are leaves (input
# images) or results of elementwise np.minimum / np.maximum over whole images.
#
# Phase 1 sorts every vertical K-window ("column"): Batcher odd-even merge sort of the K
# rows y-R..y+R, giving K images S_0 <= ... <= S_{K-1} (rank i of the column at (y, x)).
# Phase 2 merges the K sorted columns x-R..x+R of each output. Outputs are grouped in tiles
# of T neighbouring columns (images subsampled by T along x): the columns shared by the whole
# tile are merged once, then the tile is split in halves that each add their own columns.
# After every merge, values that cannot be the median are dropped ("forgetful" selection):
# with n of the N remaining window values known and sorted and target rank m among the N,
# the lowest max(0, m - (N - n)) lie strictly below the median and the values above index m
# lie above it, so both ends can go (m and N shrink accordingly). Unused comparisons are
# removed by dead-code elimination, and results go to a small pool of reused buffers.


class _Net:
    """A symbolic min/max network. A value is a leaf (tuple) or an op index (int)."""

    def __init__(self) -> None:
        self.ops: list[tuple[bool, object, object]] = []   # (is_min, a, b)

    def exchange(self, a: object, b: object) -> tuple[int, int]:
        """Return (min(a, b), max(a, b)) as new values."""
        self.ops.append((True, a, b))
        self.ops.append((False, a, b))
        return len(self.ops) - 2, len(self.ops) - 1

    def merge(self, a: list, b: list) -> list:
        """Batcher's odd-even merge of two sorted value lists (any lengths)."""
        if not a or not b:
            return list(a) + list(b)
        if len(a) == 1 and len(b) == 1:
            return list(self.exchange(a[0], b[0]))
        even = self.merge(a[0::2], b[0::2])
        odd = self.merge(a[1::2], b[1::2])
        out = [even[0]]
        for i, o in enumerate(odd):
            if i + 1 < len(even):
                out.extend(self.exchange(o, even[i + 1]))
            else:
                out.append(o)
        out.extend(even[len(odd) + 1:])
        return out

    def merge_all(self, lists: list[list]) -> list:
        """Merge sorted lists pairwise (balanced tree) into one sorted list."""
        lists = [lst for lst in lists if lst]
        while len(lists) > 1:
            merged = [self.merge(lists[i], lists[i + 1]) for i in range(0, len(lists) - 1, 2)]
            lists = merged + ([lists[-1]] if len(lists) % 2 else [])
        return lists[0] if lists else []


def _forget(values: list, n_left: int, rank: int) -> tuple[list, int, int]:
    """Drop sorted ``values`` that cannot be the median; return (values, n_left, rank).

    ``values`` are sorted and part of the ``n_left`` window values not yet discarded, whose
    element of order ``rank`` (0-based) is the median.
    """
    n = len(values)
    low = max(0, rank - (n_left - n))
    high = max(0, n - rank - 1)
    return values[low:n - high], n_left - low - high, rank - low


def _tiled_network(k: int, tile: int, column: object, forget: bool) -> tuple[_Net, dict]:
    """Build the network for ``tile`` outputs x = 0..tile-1, each over columns x-R..x+R.

    ``column(c)`` gives the sorted value list of relative column c. Returns the network and
    {x: output value list}: the sorted window (``forget`` False) or [median] (True).
    """
    r = k // 2
    net = _Net()
    outputs: dict[int, list] = {}

    def split(a: int, b: int, core: list, n_left: int, rank: int) -> None:
        if b - a == 1:
            outputs[a] = core
            return
        mid = (a + b) // 2
        # The left half [a, mid) also needs columns mid-1-R .. b-2-R, the right half
        # [mid, b) columns a+R+1 .. mid+R.
        for lo, hi, extra in ((a, mid, range(mid - 1 - r, b - 1 - r)),
                              (mid, b, range(a + r + 1, mid + r + 1))):
            add = net.merge_all([column(c) for c in extra])
            n2, rank2 = n_left, rank
            if forget:
                add, n2, rank2 = _forget(add, n2, rank2)
            merged = net.merge(core, add)
            if forget:
                merged, n2, rank2 = _forget(merged, n2, rank2)
            split(lo, hi, merged, n2, rank2)

    n_total = k * len(column(0))
    core = net.merge_all([column(c) for c in range(tile - 1 - r, r + 1)])
    n_left, rank = n_total, (n_total - 1) // 2
    if forget:
        core, n_left, rank = _forget(core, n_left, rank)
    split(0, tile, core, n_left, rank)
    return net, outputs


def _live_ops(net: _Net, keep: list) -> set[int]:
    """Return the operations of ``net`` that the values in ``keep`` depend on (dead-code pass)."""
    needed: set[int] = set()
    stack = [v for v in keep if isinstance(v, int)]
    while stack:
        v = stack.pop()
        if v in needed:
            continue
        needed.add(v)
        stack.extend(u for u in net.ops[v][1:] if isinstance(u, int))
    return needed


def _compile(net: _Net, outputs: dict, leaves: list) -> tuple[list, int, dict]:
    """Dead-code-eliminate and register-allocate a network.

    Registers 0..len(leaves)-1 are the leaves (in ``leaves`` order), the rest are scratch
    buffers. Returns (instructions [(is_min, dst, a, b)], number of buffers,
    {x: [register of each output value]}).
    """
    leaf_reg = {leaf: i for i, leaf in enumerate(leaves)}
    keep = [v for vals in outputs.values() for v in vals]
    needed = _live_ops(net, keep)
    order = sorted(needed)
    last_use: dict[object, int] = {}
    for pos, v in enumerate(order):
        for u in net.ops[v][1:]:
            last_use[u] = pos
    kept = set(keep)
    reg: dict[object, int] = dict(leaf_reg)
    free: list[int] = []
    n_buf = 0
    code = []
    for pos, v in enumerate(order):
        is_min, a, b = net.ops[v]
        for u in {a, b}:
            if isinstance(u, int) and last_use[u] == pos and u not in kept:
                free.append(reg[u])
        if free:
            dst = free.pop()
        else:
            dst = len(leaves) + n_buf
            n_buf += 1
        reg[v] = dst
        code.append((is_min, dst, reg[a], reg[b]))
    out_regs = {x: [reg[v] for v in vals] for x, vals in outputs.items()}
    return code, n_buf, out_regs


@functools.lru_cache(maxsize=32)
def _median_programs(k: int, tile: int) -> tuple[tuple, tuple]:
    """Compiled phase-1 (column sort) and phase-2 (column merge) programs for (K, tile)."""
    r = k // 2
    net1, out1 = _tiled_network(k, 1, lambda c: [('row', c)], forget=False)
    leaves1 = [('row', c) for c in range(-r, r + 1)]
    net2, out2 = _tiled_network(k, tile, lambda c: [('col', c, i) for i in range(k)],
                                forget=True)
    leaves2 = [('col', c, i) for c in range(-r, tile + r) for i in range(k)]
    return _compile(net1, out1, leaves1), _compile(net2, out2, leaves2)


def _compile_fused(net: _Net, outputs: dict, leaves: list) -> tuple[np.ndarray, int, dict]:
    """Dead-code-eliminate and register-allocate a network as fused compare-exchanges.

    Like :func:`_compile`, but each instruction computes both min and max of its operands
    (rows (lo, hi, a, b), -1 for a result nobody uses) and never writes a register it reads,
    as :func:`._compiled.median.assemble_program` requires. Returns (code (m, 4) int64, number of
    scratch registers, {x: [register of each output value]}).
    """
    leaf_reg = {leaf: i for i, leaf in enumerate(leaves)}
    keep = [v for vals in outputs.values() for v in vals]
    needed = _live_ops(net, keep)
    # exchange() appends min then max of the same operands: fuse the pairs still needed.
    order = sorted(needed)
    instrs = []
    pos = 0
    while pos < len(order):
        v = order[pos]
        is_min, a, b = net.ops[v]
        if (is_min and pos + 1 < len(order) and order[pos + 1] == v + 1
                and net.ops[v + 1] == (False, a, b)):
            instrs.append((v, v + 1, a, b))
            pos += 2
        else:
            instrs.append((v, None, a, b) if is_min else (None, v, a, b))
            pos += 1
    last_use: dict[object, int] = {}
    for pos, (_, _, a, b) in enumerate(instrs):
        last_use[a] = last_use[b] = pos
    kept = set(keep)
    reg: dict[object, int] = dict(leaf_reg)
    free: list[int] = []
    n_buf = 0
    code = []
    for pos, (v_lo, v_hi, a, b) in enumerate(instrs):
        row = [-1, -1, reg[a], reg[b]]
        for slot, v in enumerate((v_lo, v_hi)):
            if v is None:
                continue
            if free:
                row[slot] = free.pop()
            else:
                row[slot] = len(leaves) + n_buf
                n_buf += 1
            reg[v] = row[slot]
        code.append(row)
        # Operands are released only after the results got their registers: no aliasing.
        for u in {a, b}:
            if isinstance(u, int) and last_use[u] == pos and u not in kept:
                free.append(reg[u])
    out_regs = {x: [reg[v] for v in vals] for x, vals in outputs.items()}
    return np.array(code, np.int64).reshape(-1, 4), n_buf, out_regs


def _jit_tile(k: int) -> int:
    """Output rows per band of the compiled network for K (the fastest, measured).

    8 for the in-register kernels (K <= :data:`._compiled.median.REGISTER_MAX_K`; 4 rows cost
    1.4-1.7x more at K = 7 and 13, 16 rows as much at K = 17 and 21 but twice the compile
    time), 16 for the interpreter at larger K.
    """
    return 8 if k <= jit_median.REGISTER_MAX_K else 16


@functools.lru_cache(maxsize=8)
def _jit_program(k: int) -> jit_median.NetworkProgram:
    """Build (once per K) the compiled-median program: rows sorted as runs, runs merged.

    The networks are those of :func:`_median_programs` turned by 90 degrees (the median of a
    square window does not care): phase 1 sorts each horizontal K-run of a padded row,
    phase 2 merges the K runs of ``tile`` consecutive output rows.
    """
    r = k // 2
    tile = _jit_tile(k)
    net1, out1 = _tiled_network(k, 1, lambda c: [('px', c)], forget=False)
    code1, n_buf1, regs1 = _compile_fused(net1, out1, [('px', c) for c in range(-r, r + 1)])
    net2, out2 = _tiled_network(k, tile, lambda c: [('run', c, i) for i in range(k)],
                                forget=True)
    leaves2 = [('run', c, i) for c in range(-r, tile + r) for i in range(k)]
    code2, n_buf2, regs2 = _compile_fused(net2, out2, leaves2)
    return jit_median.assemble_program(
        k, tile, (code1, n_buf1, regs1[0]),
        (code2, n_buf2, [regs2[t][0] for t in range(tile)]))


def _run(program: tuple, leaves: list, shape: tuple, dtype: np.dtype) -> tuple[list, dict]:
    """Execute a compiled program on leaf images; return (registers, output registers)."""
    code, n_buf, out_regs = program
    regs = list(leaves) + [np.empty(shape, dtype) for _ in range(n_buf)]
    ops = (np.maximum, np.minimum)
    for is_min, dst, a, b in code:
        ops[is_min](regs[a], regs[b], out=regs[dst])
    return regs, out_regs


def _network_median(img: np.ndarray, k: int) -> np.ndarray:
    """Exact 'nearest'-mode K x K median of a 2-D real image by a sorting network.

    ``img``: (H, W) C-contiguous, any real dtype (uint16 keys are the fast case), k odd >= 3.
    Returns an (H, W) C-contiguous array of the same dtype.
    """
    h, w = img.shape
    r = k // 2
    tile = 4 if k <= 9 else 8
    prog1, prog2 = _median_programs(k, tile)
    n_out = -(-w // tile)               # outputs per column class x % tile
    n_q = n_out + -(-2 * r // tile)     # padded columns per class
    pad = (r, r, r, n_q * tile - w - r)
    if img.dtype in (np.uint8, np.uint16, np.int16, np.float32, np.float64):
        padded = cv2.copyMakeBorder(img, *pad, cv2.BORDER_REPLICATE)
    else:
        padded = np.pad(img, ((pad[0], pad[1]), (pad[2], pad[3])), mode='edge')
    # Split the columns into `tile` classes (column q * tile + j -> planes[j][:, q]) so every
    # image in phase 2 is a contiguous block of one class.
    planes = np.ascontiguousarray(
        padded.reshape(h + 2 * r, n_q, tile).transpose(2, 0, 1))
    # Phase 1: sort each vertical window; leaves are the K row-shifted images.
    rows = [planes[:, c:c + h, :] for c in range(k)]
    regs1, out1 = _run(prog1, rows, (tile, h, n_q), img.dtype)
    cols = [regs1[i] for i in out1[0]]   # cols[i][j]: rank i of the column windows, class j
    # Phase 2: leaf (c, i) is rank i of relative column c for every tile.
    leaves2 = []
    for c in range(-r, tile + r):
        q0, j = divmod(c + r, tile)
        leaves2.extend(cols[i][j][:, q0:q0 + n_out] for i in range(k))
    regs2, out2 = _run(prog2, leaves2, (h, n_out), img.dtype)
    result = np.stack([regs2[out2[x][0]] for x in range(tile)], axis=-1)
    return np.ascontiguousarray(result.reshape(h, n_out * tile)[:, :w])


def warm_up(kernel_size: int = 17) -> float:
    """Compile (or load from the on-disk cache) the median kernels; return the seconds it took.

    Also builds the network program for ``kernel_size`` (the detector's median K), so the
    first frame pays neither. A no-op returning 0.0 when :func:`.jit.enabled` is False.
    """
    if not jit.enabled():
        return 0.0
    start = time.perf_counter()
    millimetres = np.random.default_rng(0).integers(0, 4000, (24, 40)).astype(np.uint16)
    metres = millimetres.astype(np.float32) * np.float32(1e-3)   # the key conversion kernels
    for k in sorted({7, kernel_size}):
        median_filter(millimetres, k)
        median_filter(metres, k)
        # the detector's uint16 paths: lookups in the read-only depth table (its own
        # signature), on one thread and in bands
        median_of_codes(millimetres, k, depth_lut(MM_PER_M))
        median_and_decode(millimetres, k, depth_lut(MM_PER_M), threads=2)
    return time.perf_counter() - start
