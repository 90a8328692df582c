"""Compiled (numba) RVL decoder, the kernel of :mod:`obstacle_detection.ros.rvl` (same pixels)."""

from __future__ import annotations

import numpy as np

from ._numba import jit as _jit

#: A code has at most this many nibbles (33 value bits: any count of pixels).
MAX_CODE_NIBBLES = 11
#: The largest zigzag code of a difference between two uint16 values (-65535 -> 131069,
#: 65535 -> 131070).
MAX_ZIGZAG = 131070
#: Status codes of :func:`decode`.
OK, TRUNCATED, CODE_TOO_LONG, RUN_BEYOND_IMAGE, DIFFERENCE_TOO_LARGE, WORDS_LEFT = range(6)


@_jit(inline='always')
def _next_code(words, w, word, left):  # pragma: no cover - compiled
    """Read one code: (value, w, word, left); value -TRUNCATED or -CODE_TOO_LONG on a problem."""
    value = np.int64(0)
    for k in range(MAX_CODE_NIBBLES):
        if left == 0:
            if w >= words.shape[0]:
                return np.int64(-TRUNCATED), w, word, left
            word = np.int64(words[w])
            w += 1
            left = np.int64(8)
        nibble = (word >> 28) & 0xF
        word = (word << 4) & 0xFFFFFFFF
        left -= 1
        value |= (nibble & 7) << (3 * k)
        if nibble < 8:
            return value, w, word, left
    return np.int64(-CODE_TOO_LONG), w, word, left


@_jit
def decode(words, out):  # pragma: no cover - compiled
    """Decode RVL ``words`` (M,) uint32 into ``out`` (N,) uint16: (status, pixels decoded)."""
    n = out.shape[0]
    w = np.int64(0)
    word = np.int64(0)
    left = np.int64(0)
    pixel = np.int64(0)
    previous = np.int64(0)
    while pixel < n:
        zeros, w, word, left = _next_code(words, w, word, left)
        if zeros < 0:
            return -zeros, pixel
        if zeros > n - pixel:
            return RUN_BEYOND_IMAGE, pixel
        for i in range(pixel, pixel + zeros):
            out[i] = 0
        pixel += zeros
        nonzeros, w, word, left = _next_code(words, w, word, left)
        if nonzeros < 0:
            return -nonzeros, pixel
        if nonzeros > n - pixel:
            return RUN_BEYOND_IMAGE, pixel
        for _ in range(nonzeros):
            positive, w, word, left = _next_code(words, w, word, left)
            if positive < 0:
                return -positive, pixel
            if positive > MAX_ZIGZAG:
                return DIFFERENCE_TOO_LARGE, pixel
            previous = (previous + ((positive >> 1) ^ -(positive & 1))) & 0xFFFF
            out[pixel] = previous
            pixel += 1
    if w < words.shape[0]:
        return WORDS_LEFT, pixel
    return OK, pixel


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel on a two-pixel stream."""
    # zeros 0, non-zeros 2, +3 (code 6), -1 (code 1): nibbles 0 2 6 1, padded
    decode(np.array([0x02610000], dtype=np.uint32), np.empty(2, np.uint16))
