"""A test-side RVL encoder (compressed_depth_image_transport's CompressRVL, in plain Python).

The package only decodes RVL (``obstacle_detection.ros.rvl``); the tests make their streams
here, one pixel at a time, as the C++ encoder does, and wrap them in a ``compressedDepth rvl``
CompressedImage as its publisher does.
"""

from __future__ import annotations

import struct

import cv2
import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CompressedImage

from message_helpers import array_to_compressed_depth
from obstacle_detection.ros.compressed_depth import CONFIG_HEADER_SIZE


class _Nibbles:
    """Collects nibbles into 32-bit words, most significant nibble first."""

    def __init__(self) -> None:
        self.words: list[int] = []
        self.word = 0
        self.count = 0

    def code(self, value: int) -> None:
        """Append ``value`` >= 0 as a variable-length code: 3 bits a nibble, 8 = more."""
        while True:
            nibble = value & 0x7
            value >>= 3
            if value:
                nibble |= 0x8
            self.word = (self.word << 4) | nibble
            self.count += 1
            if self.count == 8:
                self.words.append(self.word)
                self.word, self.count = 0, 0
            if not value:
                return

    def to_bytes(self) -> bytes:
        """Return the words, the last one padded with zero nibbles, little-endian."""
        words = list(self.words)
        if self.count:
            words.append(self.word << (4 * (8 - self.count)))
        return struct.pack(f'<{len(words)}I', *words)


def encode_rvl(pixels: np.ndarray) -> bytes:
    """RVL stream of ``pixels`` (any shape, uint16), row-major, as CompressRVL writes it."""
    flat = [int(v) for v in np.asarray(pixels, dtype=np.uint16).reshape(-1)]
    out = _Nibbles()
    previous, i, n = 0, 0, len(flat)
    while i < n:
        zeros = 0
        while i < n and flat[i] == 0:
            zeros, i = zeros + 1, i + 1
        out.code(zeros)
        nonzeros = 0
        while i + nonzeros < n and flat[i + nonzeros] != 0:
            nonzeros += 1
        out.code(nonzeros)
        for current in flat[i:i + nonzeros]:
            delta = current - previous
            out.code(2 * delta if delta >= 0 else -2 * delta - 1)   # zigzag
            previous = current
        i += nonzeros
    return out.to_bytes()


def rvl_message(depth: np.ndarray, stamp: Time, frame_id: str, **png_options: object
                ) -> CompressedImage:
    """Return a ``<encoding>; compressedDepth rvl`` CompressedImage of ``depth``, as published.

    The pixels and the 12-byte ConfigHeader are those of the PNG codec
    (``array_to_compressed_depth``: 16-bit depth as is, 32FC1 quantised inverse depth); the
    RVL data is the header, then width and height (uint32 little-endian), then the stream.
    """
    png = array_to_compressed_depth(depth, stamp, frame_id, **png_options)
    data = bytes(png.data)
    pixels = cv2.imdecode(np.frombuffer(data[CONFIG_HEADER_SIZE:], np.uint8),
                          cv2.IMREAD_UNCHANGED)
    height, width = pixels.shape
    body = struct.pack('<II', width, height) + encode_rvl(pixels)
    return CompressedImage(header=png.header,
                           format=png.format.replace('compressedDepth png', 'compressedDepth rvl'),
                           data=data[:CONFIG_HEADER_SIZE] + body)
