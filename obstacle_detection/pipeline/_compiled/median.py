"""Compiled (numba) sorting-network median for ``median_filter`` (depth).

numba is an optional accelerator: when :func:`obstacle_detection.pipeline.jit.enabled`,
:func:`obstacle_detection.pipeline.median.median_filter` runs the exact K x K median of uint16
keys for K >= 7 through :func:`network_median`; otherwise the numpy / OpenCV code of
:mod:`obstacle_detection.pipeline.median` runs unchanged. Both are exact (equal to
``scipy.ndimage.median_filter(mode='nearest')``), so they give identical results.

Method: the min/max network that :mod:`obstacle_detection.pipeline.median` builds (every horizontal
K-run is sorted, then the K sorted runs of each window are merged across rows, ``tile``
output rows sharing their common runs, values that can no longer be the median dropped) runs
on rows of ``chunk`` (<= 512) pixels. The sorted runs of the last ``tile + K - 1`` padded
rows live in a ring of registers, so each run is sorted once. Float depth in metres is keyed
to millimetres by one compiled pass (:func:`quantised_keys`).

- K <= :data:`REGISTER_MAX_K` (21): each network is generated as straight-line vector code
  (a numba intrinsic emitting LLVM IR, :func:`register_kernel`) on 32 pixels at a time:
  every compare-exchange is an unsigned min and max of values held in vector registers, so
  only the sorted runs and the medians go through memory. Its source, with the program's
  networks as literals, is written once to a module file named by a digest (numba's cache
  directory, else ``__pycache__``), so numba caches it on disk like the other kernels: the
  first compilation takes about 1 s at K = 9, 3 s at K = 17, 8 s at K = 21 (2-4x that on a
  busy machine), later processes load it in under a second
  (:func:`obstacle_detection.pipeline.median.warm_up`).
- Larger K: a small interpreter (:func:`_median_kernel`) runs fused compare-exchange
  instructions ``(lo, hi) = (min(a, b), max(a, b))`` on vectors of ``chunk`` pixels in a
  register file in memory (vectorised by the compiler); every instruction loads two vectors
  and stores two, from a file of about 650 KB at K = 17 that lives in the L2 cache, which
  bounds it at about 80 cycles a pixel at K = 17 (4.3 ms for the merge phase at 512 x 424,
  1.8 ms in registers).

Both skip the merge phase for the 64-pixel blocks at either end of a band's row chunk whose
outputs are all the image's lowest key (0 = no return in depth images): that is the median
exactly when more than K * K // 2 window keys equal it, which one box count finds.

Alternatives measured on 512 x 424 Kinect-like frames (one thread): Huang's sliding
histogram (two-level, snake order, median tracked incrementally) took 8.6 ms at K=7 and 13 ms
at K=17, dominated by walking the median across the histogram at depth edges; the same
network tiled in 2-D (blocks of outputs per lane, about 30 % fewer operations at K=17) lost
what it saved to unaligned loads and data reshuffling below K=21 (5.1 vs 5.3 ms at K=17);
straight-line Python source for the whole network exhausted numba's compiler (over 20 GB at
K = 17), hence the intrinsic; the interpreter with 8-bit registers gained only 1.4x; OpenCV's
8-bit O(1) histogram median (cv2.medianBlur) alone takes 6-8 ms at K = 17 here.

The kernels are compiled on first use (the interpreter's about 3 s) and cached on disk
(``cache=True``; then 0.2 s each). All kernels run on one thread.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import math
import os
import sys
import threading
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from . import _parts
from ._numba import AVAILABLE, jit as _jit

__all__ = ['AVAILABLE', 'NetworkProgram', 'aligned_registers', 'assemble_program', 'band_lanes',
           'band_plan', 'key_range', 'network_median', 'quantised_keys', 'take', 'write_band']

#: The interpreter processes ``blocks * _LANES`` pixels of a row per instruction.
_LANES = 64
#: Smallest fraction of the image at the lowest key (no return) for which
#: :func:`network_median` looks for outputs that are that key: measured on 512 x 424 frames,
#: skipping gains 0.5 ms at K = 17 with 45-57 % of no return and nothing with under 40 %.
_SKIP_MIN_FRACTION = 0.4
#: Pixels per vector of the in-register kernels: 32 uint16, one 512-bit (two 256-bit) register.
_REG_LANES = 32
#: Largest K whose networks run in registers (:func:`register_kernel`). Their machine code is
#: generated per K (first compilation about 1 s at K = 9, 3 s at 17, 8 s at 21, then cached
#: on disk); larger K would take longer and spill more, so they keep the interpreter.
REGISTER_MAX_K = 21
#: Most pixels per row chunk: larger chunks cost fewer instruction dispatches, smaller ones
#: keep the register file (about 250 to 650 rows of ``chunk`` uint16 for K = 7 .. 17) in cache.
_MAX_CHUNK = 512


# --------------------------------------------------------------------------- kernels


@_jit
def _run(code, mem, start, blocks):  # pragma: no cover - compiled
    """Execute fused compare-exchange instructions on vectors of ``blocks * 64`` lanes.

    ``code``: (m, 4) int64 rows (lo, hi, a, b) of element offsets into the flat uint16
    ``mem``, shifted by ``start`` lanes: ``mem[lo + start:lo + start + n] = min(mem[a +
    start:...], mem[b + start:...])`` and the max into hi (-1: not needed); the written
    vectors never overlap the read ones.
    """
    # Unsigned offsets: numba then needs no negative-index handling, and the loops vectorise
    # (the compiler checks at run time that the vectors do not overlap).
    n = np.uint64(blocks) * np.uint64(64)
    s = np.uint64(start)
    for p in range(code.shape[0]):
        lo = np.uint64(code[p, 0]) + s
        hi = np.uint64(code[p, 1]) + s
        a = np.uint64(code[p, 2]) + s
        b = np.uint64(code[p, 3]) + s
        if code[p, 1] < 0:
            for j in range(n):
                x = mem[a + j]
                y = mem[b + j]
                mem[lo + j] = x if x < y else y
        elif code[p, 0] < 0:
            for j in range(n):
                x = mem[a + j]
                y = mem[b + j]
                mem[hi + j] = y if x < y else x
        else:
            for j in range(n):
                x = mem[a + j]
                y = mem[b + j]
                mem[lo + j] = x if x < y else y
                mem[hi + j] = y if x < y else x


@_jit
def _addresses(code, chunk, n_regs):  # pragma: no cover - compiled
    """Turn the register numbers of ``code`` into element offsets (int64, -1 stays -1).

    Register i < n_regs starts at i * chunk; i >= n_regs is the row buffer after the
    registers, shifted by i - n_regs pixels.
    """
    out = np.empty(code.shape, np.int64)
    flat_in = code.reshape(-1)
    flat_out = out.reshape(-1)
    for i in range(flat_in.size):
        reg = np.int64(flat_in[i])
        if reg < 0:
            flat_out[i] = -1
        elif reg < n_regs:
            flat_out[i] = reg * chunk
        else:
            flat_out[i] = n_regs * chunk + reg - n_regs
    return out


@_jit
def aligned_registers(size):  # pragma: no cover - compiled
    """Return an uninitialised (size,) uint16 buffer that starts on a 64-byte cache line.

    Vector loads that straddle two cache lines cost up to 1.5x.
    """
    raw = np.empty(size + 32, np.uint16)
    skip = (-raw.ctypes.data % 64) // 2
    return raw[skip:skip + size]


@_jit
def band_plan(h, w, chunk, tile, r):  # pragma: no cover - compiled
    """Return the bands of a median run in order: (n, 5) int64 rows (x0, y0, rows, band, c0).

    Row chunks of ``chunk`` lanes from x0, bands of ``tile`` output rows from y0 (``rows`` of
    them, fewer in the last band); phase 1 sorts the padded rows y0 + c0 .. y0 + tile + 2r - 1
    of a band (all of them for the first band of a chunk; then the ring holds the others).
    """
    n_bands = (h + tile - 1) // tile
    n_chunks = (w + chunk - 1) // chunk
    plan = np.empty((n_chunks * n_bands, 5), np.int64)
    p = 0
    for x0 in range(0, w, chunk):
        for band in range(n_bands):
            plan[p, 0] = x0
            plan[p, 1] = band * tile
            plan[p, 2] = min(tile, h - band * tile)
            plan[p, 3] = band
            plan[p, 4] = 0 if band == 0 else 2 * r
            p += 1
    return plan


@_jit
def band_lanes(need, y0, x0, n_rows, width):  # pragma: no cover - compiled
    """Return (first, last, start, stop): the lanes of a band's row chunk the merge must run.

    Lanes [first, last] hold every output of the band not known to be the lowest key;
    [start, stop) is that span widened to whole 64-lane blocks (clipped to the chunk).
    ``need``: (h, w) uint8, 0 where the median is known, or (0, 0) to compute every output;
    the band's rows are y0 .. y0 + n_rows - 1, the chunk's lanes x0 .. x0 + width - 1.
    last < first when no output is needed. Shared by the interpreter
    (:func:`_median_kernel`) and the in-register kernels.
    """
    first, last = 0, width - 1
    if need.shape[0] > 0:
        first, last = width, -1
        for t in range(n_rows):
            lane = 0                  # scans stop at the first needed lane
            while lane < first and not need[y0 + t, x0 + lane]:
                lane += 1
            first = lane if lane < first else first
            lane = width - 1
            while lane > last and not need[y0 + t, x0 + lane]:
                lane -= 1
            last = lane if lane > last else last
    start = (first // 64) * 64
    stop = min(-(-(last + 1) // 64) * 64, width)
    return first, last, start, stop


@_jit
def write_band(out, mem, y0, x0, n_rows, width, lanes, fill, sources,
               scale):  # pragma: no cover - compiled
    """Copy a band's medians from the registers into ``out``; ``fill`` outside the merged lanes.

    ``lanes``: (first, last, start, stop) of :func:`band_lanes`; row t of the band is read
    from ``mem[sources[t] * scale + start:... + stop]``.
    """
    first, last, start, stop = lanes
    for t in range(n_rows):
        out[y0 + t, x0:x0 + start] = fill
        if last >= first:
            src = sources[t] * scale
            out[y0 + t, x0 + start:x0 + stop] = mem[src + start:src + stop]
        out[y0 + t, x0 + max(stop, start):x0 + width] = fill


@_jit
def _median_kernel(padded, h, w, k, tile, blocks, code1, code2, out2, n_regs, need,
                   fill):  # pragma: no cover - compiled
    """Run a :class:`NetworkProgram` over a replicate-padded uint16 key image.

    ``padded``: (bands * tile + 2R, chunks * chunk + 2R) uint16, the (h, w) keys padded by
    R = k // 2 with their edge values (and beyond, to whole bands and chunks). ``need``:
    (h, w) uint8, 0 where the median is known to be ``fill`` (the merge phase skips the
    64-lane blocks of a band at either end of a row chunk whose outputs all are), or (0, 0)
    to compute every output. Returns the (h, w) uint16 median.
    """
    r = k // 2
    rows = tile + 2 * r
    chunk = blocks * 64
    # Registers, then one padded row segment (phase 1 reads its k shifts in place).
    mem = aligned_registers(n_regs * chunk + chunk + 2 * r)
    row = n_regs * chunk
    addr1 = _addresses(code1, chunk, n_regs)
    addr2 = _addresses(code2, chunk, n_regs)
    out = np.empty((h, w), np.uint16)
    plan = band_plan(h, w, chunk, tile, r)
    for p in range(plan.shape[0]):
        x0, y0, n_rows = plan[p, 0], plan[p, 1], plan[p, 2]
        width = min(chunk, w - x0)
        # Sort the horizontal runs of the padded rows this band adds to the ring.
        for py in range(y0 + plan[p, 4], y0 + rows):
            mem[row:row + chunk + 2 * r] = padded[py, x0:x0 + chunk + 2 * r]
            _run(addr1[py % rows], mem, 0, blocks)
        lanes = band_lanes(need, y0, x0, n_rows, width)
        phase = plan[p, 3] % code2.shape[0]
        if lanes[1] >= lanes[0]:
            # Merge the runs into the medians of the band's rows.
            _run(addr2[phase], mem, lanes[2], -(-(lanes[3] - lanes[2]) // 64))
        write_band(out, mem, y0, x0, n_rows, width, lanes, fill, out2[phase], chunk)
    return out


@_jit
def _quantise_kernel(flat, scale, keys, values):  # pragma: no cover - compiled
    """Key each value of float32 ``flat`` by ``rint(value * scale)``; False on a failure.

    Fails (returns False) on a key outside 0..65535 (or NaN) and on a key that two different
    values share. ``keys``: (n,) uint16 out; ``values``: (65536,) float32 zeros in, out the
    value of each key that occurs.
    """
    # Branch-free passes (they vectorise): keys and their range, scatter, check. Rounding to
    # nearest (ties to even) by adding and removing 2**23, exact for 0 <= x < 2**23.
    magic = np.float32(8388608.0)
    top = np.float32(65535.0)
    good = True
    for i in range(flat.size):
        x = flat[i] * scale
        good &= (x >= np.float32(0.0)) & (x < np.float32(65535.5))   # False for NaN
        keys[i] = np.uint16((min(max(x, np.float32(0.0)), top) + magic) - magic)
    if not good:
        return False
    for i in range(flat.size):
        values[keys[i]] = flat[i]
    same = True
    for i in range(flat.size):
        same &= values[keys[i]] == flat[i]
    return same


@_jit
def _take_kernel(values, keys, out):  # pragma: no cover - compiled
    """``out[i] = values[keys[i]]`` for flat arrays (uint16 keys)."""
    for i in range(keys.size):
        out[i] = values[keys[i]]


@_jit
def _key_range_kernel(keys):  # pragma: no cover - compiled
    """Return (lowest, highest, count of the lowest) of flat uint16 keys (size >= 1)."""
    lowest = keys[0]
    highest = keys[0]
    for i in range(keys.size):
        lowest = min(lowest, keys[i])
        highest = max(highest, keys[i])
    count = 0
    for i in range(keys.size):
        count += keys[i] == lowest
    return lowest, highest, count


def key_range(keys: np.ndarray) -> tuple[int, int, int]:
    """Return (lowest key, highest key, pixels at the lowest) of a non-empty uint16 image.

    One compiled pass (two over data in the cache) in place of ``min``, ``max`` and a count
    of ``keys == min``: what :func:`network_median` and its caller look at before filtering.
    """
    flat = np.ascontiguousarray(keys, np.uint16).reshape(-1)
    lowest, highest, count = _key_range_kernel(flat)
    return int(lowest), int(highest), int(count)


def quantised_keys(depth: np.ndarray,
                   units_per_m: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Map a quantised depth image to uint16 keys with the same order, in one pass.

    Args:
        depth: (H, W) float32 depth [m] (or any non-negative float32 values).
        units_per_m: quantisation step: key = rint(value * units_per_m) (float32 arithmetic).

    Returns:
        ``(keys, values)``: keys (H, W) uint16 and values (65536,) float32 with
        ``values[keys] == depth`` exactly; the map value -> key is non-decreasing and one to
        one on the values present, so it keeps their order. None when a value is negative,
        NaN or too large for 16 bits, or two different values round to one key.
    """
    flat = np.ascontiguousarray(depth, np.float32).reshape(-1)
    keys = np.empty(flat.size, np.uint16)
    values = np.zeros(1 << 16, np.float32)
    if not _quantise_kernel(flat, np.float32(units_per_m), keys, values):
        return None
    return keys.reshape(depth.shape), values


def take(values: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Return ``values[keys]`` for (n,) float32 values and (H, W) uint16 keys (= ``np.take``)."""
    out = np.empty(keys.shape, values.dtype)
    _take_kernel(values, np.ascontiguousarray(keys).reshape(-1), out.reshape(-1))
    return out


# --------------------------------------------------------------------------- programs


class NetworkProgram(NamedTuple):
    """A sorting-network median program for :func:`network_median`, for one K and tile.

    Register file layout: a ring of ``tile + K - 1`` slots of K registers (the sorted
    horizontal runs of consecutive padded rows, rank i of slot s in register s * K + i), then
    phase-1 scratch, then phase-2 scratch (``n_regs`` registers in all). Register numbers
    ``n_regs + s`` stand for the padded row being sorted, shifted by s pixels (phase 1 reads
    its K leaves there in place). Code rows are (lo, hi, a, b), -1 for a result not needed.
    """

    k: int
    tile: int                 #: output rows per band
    code1: np.ndarray         #: (ring slots, m1, 4) int32 phase 1, writing into each slot
    code2: np.ndarray         #: (phases, m2, 4) int32 phase 2 per ring phase of a band
    out2: np.ndarray          #: (phases, tile) int32 register of each output row's median
    n_regs: int
    net1: tuple = ()          #: phase 1 as given: ((m1, 4) int64 code, (K,) sorted outputs)
    net2: tuple = ()          #: phase 2 as given: ((m2, 4) int64 code, (tile,) medians)


def assemble_program(k: int, tile: int, phase1: tuple, phase2: tuple) -> NetworkProgram:
    """Lay out two register-level networks on the register file of :func:`network_median`.

    Args:
        k: window size K (odd, >= 3).
        tile: output rows per band (>= 1).
        phase1: ``(code, n_buf, outputs)`` sorting one horizontal run: code (m, 4) int
            (lo, hi, a, b) with -1 for an unused lo / hi, registers 0..K-1 the pixels at
            horizontal offsets -R..R, K.. scratch; outputs: the K registers of the sorted run.
        phase2: ``(code, n_buf, outputs)`` merging runs into ``tile`` medians: registers
            (c + R) * K + i are rank i of the run of relative row c (-R <= c < tile + R), the
            rest scratch; outputs: the ``tile`` median registers, row by row.

    In both, a written register is never an input of the same instruction.
    """
    r = k // 2
    rows = tile + 2 * r
    code1, n_buf1, outs1 = phase1
    code2, n_buf2, outs2 = phase2
    code1 = np.asarray(code1, np.int64).reshape(-1, 4)
    code2 = np.asarray(code2, np.int64).reshape(-1, 4)
    scratch1 = rows * k
    scratch2 = scratch1 + n_buf1
    n_regs = scratch2 + n_buf2
    n_leaves2 = rows * k
    outs1 = np.asarray(outs1)
    if (outs1 < k).any():
        raise ValueError('phase-1 outputs must be computed registers')

    # Phase 1 for ring slot s: the k leaves are the row buffer shifted by 0..K-1 (registers
    # n_regs + shift); the sorted outputs land in the slot (free while this row is sorted: it
    # held a row no later band needs).
    out_rank = np.full(k + n_buf1, -1)
    out_rank[outs1] = np.arange(k)
    reg1 = np.arange(k + n_buf1)
    base1 = np.where(reg1 < k, n_regs + reg1, scratch1 + reg1 - k)
    slots = []
    for s in range(rows):
        phys = np.where(out_rank >= 0, s * k + out_rank, base1)
        slots.append(_relocate(code1, phys))

    # Phase 2 for each ring phase: band b starts at padded row b * tile, slot of row c is
    # (b * tile + c) % rows, which repeats every rows / gcd(rows, tile) bands.
    period = rows // math.gcd(rows, tile)
    reg2 = np.arange(n_leaves2 + n_buf2)
    phases, outs = [], []
    for phase in range(period):
        c, i = np.divmod(np.minimum(reg2, n_leaves2 - 1), k)
        leaf = ((phase * tile + c) % rows) * k + i
        phys = np.where(reg2 < n_leaves2, leaf, scratch2 + reg2 - n_leaves2)
        phases.append(_relocate(code2, phys))
        outs.append(phys[np.asarray(outs2)])
    return NetworkProgram(k, tile, np.stack(slots), np.stack(phases),
                          np.asarray(outs, np.int32), n_regs,
                          (code1, np.asarray(outs1, np.int64)),
                          (code2, np.asarray(outs2, np.int64)))


def _relocate(code: np.ndarray, phys: np.ndarray) -> np.ndarray:
    """Map register numbers through ``phys``; an unused output (-1) stays -1."""
    out = np.where(code >= 0, phys[np.maximum(code, 0)], -1)
    return np.ascontiguousarray(out, np.int32)


# --------------------------------------------------------------------------- in registers


def _network_intrinsic(code: np.ndarray, n_leaves: int, outputs: np.ndarray) -> object:
    """Return a numba intrinsic ``net(src, leaf_at, i, dst, out_at, j)``: a network in registers.

    The network (``code`` rows (lo, hi, a, b), registers < ``n_leaves`` its leaves, the others
    intermediate values, -1 an unused result) becomes straight-line LLVM code on vectors of
    :data:`_REG_LANES` uint16 (1-D arrays ``src`` and ``dst``): leaf l is loaded from
    ``src[leaf_at[l] + i:... + 32]`` at its first use, every compare-exchange is an unsigned
    min / max of two SSA values (no memory traffic but the compiler's own spills, which stay
    in the L1 cache), and output t is stored to ``dst[out_at[t] + j:... + 32]``. Loads and
    stores may be unaligned.
    """
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic

    rows = [tuple(int(v) for v in row) for row in np.asarray(code).reshape(-1, 4)]
    outs = [int(v) for v in outputs]

    @intrinsic
    def net(typingctx, src_t, leaf_t, i_t, dst_t, out_t, j_t):  # pragma: no cover - compile
        sig = types.void(src_t, leaf_t, i_t, dst_t, out_t, j_t)

        def codegen(context, builder, signature, args):
            src, leaf_at, i, dst, out_at, j = args
            arrays = [context.make_array(signature.args[n])(context, builder, args[n]).data
                      for n in (0, 1, 3, 4)]
            src_ptr, leaf_ptr, dst_ptr, out_ptr = arrays
            i64 = ir.IntType(64)
            vec_ptr = ir.VectorType(ir.IntType(16), _REG_LANES).as_pointer()

            def address(base, table, index, shift):
                offset = builder.load(builder.gep(table, [ir.Constant(i64, index)]))
                return builder.bitcast(builder.gep(base, [builder.add(offset, shift)]),
                                       vec_ptr)

            values = {}

            def value(reg):
                if reg not in values:        # only leaves are missing: load at first use
                    values[reg] = builder.load(address(src_ptr, leaf_ptr, reg, i), align=2)
                return values[reg]

            for lo, hi, a, b in rows:
                x, y = value(a), value(b)
                less = builder.icmp_unsigned('<', x, y)
                if lo >= 0:
                    values[lo] = builder.select(less, x, y)
                if hi >= 0:
                    values[hi] = builder.select(less, y, x)
            for t, reg in enumerate(outs):
                builder.store(value(reg), address(dst_ptr, out_ptr, t, j), align=2)
            return context.get_dummy_value()

        return sig, codegen

    return net


_REGISTER_KERNELS: dict = {}
_REGISTER_LOCK = threading.Lock()
#: id(program) -> (program, kernel) and (id(program), chunk) -> (program, tables): the
#: per-frame lookups of :func:`network_median` (hashing the networks and building the tables
#: cost 0.1-0.2 ms a frame).
_BY_PROGRAM: dict = {}
_TABLES: dict = {}
#: Why the in-register kernels could not be compiled, if they could not (then, said once by
#: a warning, :func:`network_median` runs the interpreter).
_REGISTER_FAILED: list[str] = []


def register_kernel(program: NetworkProgram) -> object:
    """Return the compiled in-register median kernel of ``program`` (built once per program).

    Phase 1 (sorting the horizontal runs of each padded row into the ring) and phase 2
    (merging them into the medians of a band) run as straight-line vector code
    (:func:`_network_intrinsic`) on 32 pixels at a time, in the same order and on the same
    ring as the interpreter of :func:`_median_kernel`, whose result it equals. numba compiles
    it at the first call, or loads it from its disk cache (:func:`_make_register_kernel`).
    """
    seen = _BY_PROGRAM.get(id(program))      # this very program: no hashing of its networks
    if seen is not None and seen[0] is program:
        return seen[1]
    key = (program.k, program.tile, hash(program.net1[0].tobytes()),
           hash(program.net2[0].tobytes()))
    with _REGISTER_LOCK:
        kernel = _REGISTER_KERNELS.get(key)
        if kernel is None:
            kernel = _REGISTER_KERNELS[key] = _make_register_kernel(program)
        _BY_PROGRAM[id(program)] = (program, kernel)   # the program kept: its id stays its own
    return kernel


def _make_register_kernel(program: NetworkProgram) -> object:
    """Build (uncompiled) the numba kernel of :func:`register_kernel`.

    Its source (:data:`_KERNEL_SOURCE` with the program's networks as literals) is written
    to a file named by a digest of this module and of the program, so that numba caches the
    compiled kernel on disk like the others (``cache=True``): a later process loads it in
    well under a second instead of compiling it again. Without a writable directory it is
    compiled in memory at each start.
    """
    k, tile = program.k, program.tile
    (code1, outs1), (code2, outs2) = program.net1, program.net2
    fields = {'k': k, 'tile': tile, 'lanes': _REG_LANES,
              'code1': np.asarray(code1, np.int64).reshape(-1).tolist(),
              'outs1': np.asarray(outs1, np.int64).tolist(),
              'code2': np.asarray(code2, np.int64).reshape(-1).tolist(),
              'outs2': np.asarray(outs2, np.int64).tolist()}
    body = _KERNEL_SOURCE.format(**fields)
    digest = hashlib.sha1((Path(__file__).read_bytes().hex() + body).encode()).hexdigest()[:16]
    name = f'median_k{k}_t{tile}_{digest}'
    for directory in _kernel_directories():
        path = directory / f'{name}.py'
        try:
            if not path.exists():
                directory.mkdir(parents=True, exist_ok=True)
                partial = directory / f'.{name}.{os.getpid()}.tmp'
                partial.write_text(body.replace('cache=CACHE', 'cache=True'))
                os.replace(partial, path)
        except OSError:
            continue
        spec = importlib.util.spec_from_file_location(f'obstacle_detection._{name}', path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        return module.kernel
    namespace: dict = {}
    exec(compile(body.replace('cache=CACHE', 'cache=False'), f'<{name}>', 'exec'),  # noqa: S102
         namespace)
    return namespace['kernel']


def _kernel_directories() -> list[Path]:
    """Where generated kernel sources may go: numba's cache directory, else __pycache__."""
    found = []
    if os.environ.get('NUMBA_CACHE_DIR'):
        found.append(Path(os.environ['NUMBA_CACHE_DIR']) / 'obstacle_detection_median')
    found.append(Path(__file__).resolve().parent / '__pycache__' / 'median_kernels')
    return found


#: Source of one in-register kernel (a module of its own, see :func:`_make_register_kernel`).
_KERNEL_SOURCE = '''"""In-register K x K median, generated by ._compiled.median."""

import numpy as np

from obstacle_detection.pipeline._compiled import median as jit_median
from obstacle_detection.pipeline._compiled._numba import numba

K = {k}
TILE = {tile}
ROWS = TILE + 2 * (K // 2)
LANES = {lanes}
NET1 = jit_median._network_intrinsic(np.array({code1}, np.int64), K,
                                     np.array({outs1}, np.int64))
NET2 = jit_median._network_intrinsic(np.array({code2}, np.int64), ROWS * K,
                                     np.array({outs2}, np.int64))


@numba.njit(cache=CACHE, nogil=True, boundscheck=False)
def kernel(padded, h, w, chunk, leaf1, out1, leaf2, out2, need, fill, plan, out, mem):
    flat = padded.reshape(padded.size)        # phase 1 reads the padded rows in place
    step = padded.shape[1]
    for p in range(plan.shape[0]):
        x0, y0, n_rows = plan[p, 0], plan[p, 1], plan[p, 2]
        for py in range(y0 + plan[p, 4], y0 + ROWS):
            for j in range(0, chunk, LANES):
                NET1(flat, leaf1, py * step + x0 + j, mem, out1[py % ROWS], j)
        width = min(chunk, w - x0)
        first, last, start, stop = jit_median.band_lanes(need, y0, x0, n_rows, width)
        if last >= first:
            leaves = leaf2[plan[p, 3] % leaf2.shape[0]]
            for j in range(start, start + -(-(stop - start) // 64) * 64, LANES):
                NET2(mem, leaves, j, mem, out2, j)
        jit_median.write_band(out, mem, y0, x0, n_rows, width, (first, last, start, stop),
                              fill, out2, 1)
'''


def _register_tables(program: NetworkProgram, chunk: int) -> tuple:
    """Element offsets of the in-register kernel's ring and outputs for one chunk width.

    Layout: ring slot s, rank i at (s * K + i) * chunk; the band's medians after the ring.
    Returns (leaf1, out1, leaf2, out2): leaf1 (K,) the shifts of a padded row that phase 1
    sorts, out1 (slots, K) where each slot's sorted run goes, leaf2 (phases, slots * K) the
    ring register of each phase-2 leaf, out2 (tile,) the medians.
    """
    k, tile = program.k, program.tile
    rows = tile + 2 * (k // 2)
    ring = rows * k
    leaf1 = np.arange(k, dtype=np.int64)
    out1 = np.arange(ring, dtype=np.int64).reshape(rows, k) * chunk
    period = rows // math.gcd(rows, tile)
    c, i = np.divmod(np.arange(ring, dtype=np.int64), k)
    leaf2 = np.stack([((phase * tile + c) % rows) * k + i for phase in range(period)]) * chunk
    out2 = (ring + np.arange(tile, dtype=np.int64)) * chunk
    return leaf1, out1, np.ascontiguousarray(leaf2), out2


def network_median(keys: np.ndarray, program: NetworkProgram, *,
                   in_registers: bool | None = None, parts: int = 1,
                   run_parts: Callable[[list[Callable[[], None]]], None] | None = None,
                   table: np.ndarray | None = None,
                   decode_input: bool = False,
                   keys_range: tuple[int, int, int] | None = None,
                   ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Exact 'nearest'-mode K x K median of uint16 keys by a compiled network program.

    Args:
        keys: (H, W) uint16 image.
        program: from :func:`assemble_program` (:mod:`obstacle_detection.pipeline.median`
            builds and caches one per K).
        in_registers: run the in-register kernel (:func:`register_kernel`) rather than the
            interpreter; None (default) does for K <= :data:`REGISTER_MAX_K`. Same result.
        parts: the in-register kernel's bands of output rows are cut into this many runs of
            consecutive bands, each writing its own rows of the output (the first band of a
            run sorts all its rows into the ring, the others only their new ones): the same
            result whoever runs them, in any order.
        run_parts: called with the list of ``parts`` functions (no arguments) and returns once
            all have run, e.g. on several threads; None runs them in order here.
        table: (65536,) float32: return ``table[median]`` instead (:func:`take`), looked up
            by each run for its rows when the image is one row chunk wide.
        decode_input: with ``table``, return ``(table[median], table[keys])``: the runs look
            their input rows up too (the detector's decoded raw depth, on the threads).
        keys_range: :func:`key_range` of ``keys`` when the caller has it (None: found here).

    Returns:
        (H, W) uint16 C-contiguous median, equal to
        ``scipy.ndimage.median_filter(keys, size=K, mode='nearest')``.

    Where more than half of a window is the smallest key of the image (0 = no return in
    depth images), the median is that key: one box count finds those pixels, and the merge
    phase skips the lanes at either end of a row chunk that hold only such outputs.
    """
    if not AVAILABLE:
        raise RuntimeError('numba is not available')
    keys = np.ascontiguousarray(keys, np.uint16)
    h, w = keys.shape
    k, tile = program.k, program.tile
    r = k // 2
    n_chunks = -(-w // _MAX_CHUNK)
    blocks = -(-w // (n_chunks * _LANES))      # lanes per chunk / 64, as even as possible
    chunk = blocks * _LANES
    bands = -(-h // tile)
    fill, need = _known_lowest(keys, k, keys_range)
    padded = cv2.copyMakeBorder(keys, r, r + bands * tile - h,
                                r, r + n_chunks * chunk - w, cv2.BORDER_REPLICATE)
    automatic = in_registers is None
    if automatic:
        in_registers = k <= REGISTER_MAX_K and bool(program.net1) and not _REGISTER_FAILED
    if in_registers:
        seen = _TABLES.get((id(program), chunk))
        if seen is None or seen[0] is not program:
            seen = _TABLES[(id(program), chunk)] = (program, _register_tables(program, chunk))
        tables = seen[1]
        try:
            kernel = register_kernel(program)
            plan = band_plan(h, w, chunk, tile, r)
            out = np.empty((h, w), np.uint16)
            size = int(tables[3][-1]) + chunk   # the ring and the band's medians
            looked_up = None if table is None else np.empty((h, w), table.dtype)
            decoded = np.empty((h, w), table.dtype) if table is not None and decode_input else None
            runs = []
            for begin, end in _plan_runs(plan, parts):
                run = plan[begin:end].copy()
                run[0, 4] = 0                 # the run's first band fills the whole ring
                # one chunk wide: the run's bands are whole rows, which it looks up itself
                rows = (int(run[0, 1]), int(run[-1, 1] + run[-1, 2])) if n_chunks == 1 else None
                runs.append(functools.partial(_run_register_kernel, kernel, size,
                                              (padded, h, w, chunk, *tables, need, fill, run,
                                               out), table, looked_up, rows,
                                              None if decoded is None else (keys, decoded)))
            _parts.run(runs, run_parts)
            if table is None:
                return out
            if n_chunks > 1:
                _take_kernel(table, out.reshape(-1), looked_up.reshape(-1))
                if decoded is not None:
                    _take_kernel(table, keys.reshape(-1), decoded.reshape(-1))
            return looked_up if decoded is None else (looked_up, decoded)
        except Exception as error:  # noqa: BLE001 - code generation by another numba
            if not automatic:
                raise
            _REGISTER_FAILED.append(repr(error))
            warnings.warn(f'the in-register median kernels failed to compile ({error!r}); '
                          f'the slower interpreter runs instead (same results)',
                          RuntimeWarning, stacklevel=2)
    med = _median_kernel(padded, h, w, k, tile, blocks, program.code1, program.code2,
                         program.out2, program.n_regs, need, fill)
    if table is None:
        return med
    return (take(table, med), take(table, keys)) if decode_input else take(table, med)


_scratch = threading.local()


def _run_register_kernel(kernel: Any, size: int, args: tuple, table: np.ndarray | None = None,
                         looked_up: np.ndarray | None = None,
                         rows: tuple[int, int] | None = None,
                         decode: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Run an in-register kernel on this thread's ring buffer of ``size`` registers.

    The buffer is kept for the thread's next call: a fresh one would cost its page faults at
    every call (0.1-0.2 ms at 512 x 424), and two threads faulting at once wait on each other.
    With ``rows`` (y0, y1): then ``looked_up[y0:y1] = table[out[y0:y1]]`` (out: args[-1]),
    and with ``decode`` (keys, decoded) also ``decoded[y0:y1] = table[keys[y0:y1]]``.
    """
    mem = getattr(_scratch, 'mem', None)
    if mem is None or mem.shape[0] < size:
        mem = _scratch.mem = aligned_registers(size)
    kernel(*args, mem[:size])
    if rows is not None and table is not None and looked_up is not None:
        y0, y1 = rows
        _take_kernel(table, args[-1][y0:y1].reshape(-1), looked_up[y0:y1].reshape(-1))
        if decode is not None:
            keys, decoded = decode
            _take_kernel(table, keys[y0:y1].reshape(-1), decoded[y0:y1].reshape(-1))


def _plan_runs(plan: np.ndarray, parts: int) -> list[tuple[int, int]]:
    """Cut the rows of a :func:`band_plan` into at most ``parts`` runs of near-equal length."""
    cuts = _parts.edges(plan.shape[0], max(1, min(int(parts), plan.shape[0])))
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def _known_lowest(keys: np.ndarray, k: int,
                  keys_range: tuple[int, int, int] | None = None) -> tuple[int, np.ndarray]:
    """Return (lowest key, need): need (H, W) uint8 is 0 where the median is that key.

    The K x K median ('nearest' border) is the lowest key v exactly when more than
    K * K // 2 of the window's keys equal v: a count by ``cv2.boxFilter`` on the replicated
    border (the image's edge pixels count as often as scipy's 'nearest' mode repeats them).
    need is (0, 0) (compute every output) when under :data:`_SKIP_MIN_FRACTION` of the keys
    are the lowest: the count (0.15 ms at 512 x 424) would then cost more than it saves.
    keys_range: :func:`key_range` of ``keys`` (None: computed here).
    """
    lowest, _, at_lowest = key_range(keys) if keys_range is None else keys_range
    if at_lowest < _SKIP_MIN_FRACTION * keys.size:
        return lowest, np.zeros((0, 0), np.uint8)
    is_lowest = keys == lowest
    count = cv2.boxFilter(is_lowest.view(np.uint8), cv2.CV_16U, (k, k), normalize=False,
                          borderType=cv2.BORDER_REPLICATE)
    return lowest, (count <= k * k // 2).view(np.uint8)

