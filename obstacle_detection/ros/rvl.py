"""RVL, the lossless depth codec of image_transport's ``compressedDepth rvl``: the decoder."""

from __future__ import annotations

import numpy as np

from obstacle_detection.ros import RosInputError

from obstacle_detection.pipeline import jit as jit_support
from obstacle_detection.pipeline._compiled import rvl as compiled
from obstacle_detection.pipeline._compiled.rvl import (CODE_TOO_LONG, DIFFERENCE_TOO_LARGE,
                                                       MAX_CODE_NIBBLES, MAX_ZIGZAG, OK,
                                                       RUN_BEYOND_IMAGE, TRUNCATED, WORDS_LEFT)

#: The nibbles of a word, most significant first: their right shifts [bits].
_NIBBLE_SHIFTS = np.arange(28, -1, -4, dtype=np.uint32)


def _error(status: int, pixel: int, num_pixels: int, words: int) -> RosInputError:
    """Return the RosInputError of a decoder status (see ``pipeline/_compiled/rvl.py``)."""
    reasons = {
        TRUNCATED: f'truncated: its {words} words end after {pixel} of {num_pixels} pixels',
        CODE_TOO_LONG: f'corrupt: a code longer than {MAX_CODE_NIBBLES} nibbles (after '
                       f'pixel {pixel})',
        RUN_BEYOND_IMAGE: f'corrupt: a run goes beyond the {num_pixels} pixels of the image '
                          f'(at pixel {pixel})',
        DIFFERENCE_TOO_LARGE: f'corrupt: a difference beyond 16 bits at pixel {pixel}',
        WORDS_LEFT: f'corrupt: words left after the last of its {num_pixels} pixels',
    }
    return RosInputError(f'RVL stream {reasons[status]}')


def _words(stream: bytes) -> np.ndarray:
    """Return the 32-bit little-endian words of a stream, (M,) uint32."""
    if len(stream) % 4:
        raise RosInputError(f'RVL stream truncated: {len(stream)} bytes are not whole 32-bit '
                            'words')
    return np.frombuffer(stream, dtype='<u4').astype(np.uint32, copy=False)


def _codes(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every complete code of the words: (values (K,) int64, nibble index after each (K,))."""
    nibbles = ((words[:, None] >> _NIBBLE_SHIFTS) & 0xF).reshape(-1).astype(np.int64)
    ends = np.flatnonzero((nibbles & 8) == 0)        # a code ends at a nibble without 8
    if ends.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts = np.concatenate(([0], ends[:-1] + 1))
    lengths = ends - starts + 1
    if lengths.max() > MAX_CODE_NIBBLES:
        at = int(np.argmax(lengths > MAX_CODE_NIBBLES))
        raise RosInputError(f'RVL stream corrupt: code {at} is longer than {MAX_CODE_NIBBLES} '
                            'nibbles')
    used = nibbles[:ends[-1] + 1]
    place = np.arange(used.size) - np.repeat(starts, lengths)   # nibble's place in its code
    values = np.add.reduceat((used & 7) << (3 * place), starts)
    return values, ends + 1


def _reference_decode_rvl(stream: bytes, num_pixels: int) -> np.ndarray:
    """Decode an RVL stream into its (num_pixels,) uint16 pixels: the reference decoder."""
    words = _words(stream)
    values, after = _codes(words)
    nonzero_pixel = np.zeros(num_pixels, dtype=bool)
    is_difference = np.zeros(values.size, dtype=bool)
    code = pixel = 0
    while pixel < num_pixels:
        for part in ('zeros', 'non-zeros'):
            if code >= values.size:
                raise _error(TRUNCATED, pixel, num_pixels, words.size)
            count = int(values[code])
            code += 1
            if count > num_pixels - pixel:
                raise _error(RUN_BEYOND_IMAGE, pixel, num_pixels, words.size)
            if part == 'non-zeros':
                if code + count > values.size:
                    raise _error(TRUNCATED, pixel + max(values.size - code, 0), num_pixels,
                                 words.size)
                nonzero_pixel[pixel:pixel + count] = True
                is_difference[code:code + count] = True
                code += count
            pixel += count
    words_used = -(-int(after[code - 1]) // 8) if code else 0
    if words.size > words_used:
        raise _error(WORDS_LEFT, pixel, num_pixels, words.size)
    positive = values[is_difference]
    if positive.size and positive.max() > MAX_ZIGZAG:
        at = int(np.flatnonzero(nonzero_pixel)[np.argmax(positive > MAX_ZIGZAG)])
        raise _error(DIFFERENCE_TOO_LARGE, at, num_pixels, words.size)
    differences = (positive >> 1) ^ -(positive & 1)
    pixels = np.zeros(num_pixels, dtype=np.uint16)
    pixels[nonzero_pixel] = (np.cumsum(differences) & 0xFFFF).astype(np.uint16)
    return pixels


def _compiled_decode_rvl(stream: bytes, num_pixels: int) -> np.ndarray:
    """Decode an RVL stream with the numba kernel; same result and refusals as the reference."""
    words = _words(stream)
    pixels = np.empty(num_pixels, dtype=np.uint16)
    status, pixel = compiled.decode(words, pixels)
    if status != OK:
        raise _error(status, pixel, num_pixels, words.size)
    return pixels


#: Decode an RVL stream into its (num_pixels,) uint16 pixels, row-major: the numba kernel when
#: the compiled path is on (about a millisecond for a 512 x 424 frame), else the numpy
#: reference. Raises RosInputError naming the problem.
decode_rvl = jit_support.choose(_reference_decode_rvl, _compiled_decode_rvl)


def warm_up() -> None:
    """Compile (or load from numba's cache) the RVL kernel, when the compiled path is on."""
    if jit_support.enabled():
        compiled.warm_up()
