"""Message helpers only the tests use: build compressed depth, read clouds back, bound errors.

The package reads compressed depth and writes clouds; these are their inverses, written here
so the tests can make inputs and check outputs (compressed_depth_image_transport's encoder,
a PointCloud2 reader) without the package carrying code no user calls.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CompressedImage, PointField
from std_msgs.msg import Header

from obstacle_detection.ros.compressed_depth import (CONFIG_HEADER, INV_DEPTH,
                                                     compressed_depth_to_array,
                                                     is_compressed_image)
from obstacle_detection.ros import RosInputError
from obstacle_detection.ros.conversions import image_to_array

_XYZ = ('x', 'y', 'z')

#: The compressedDepth publisher's defaults (ROS 2) and the ranges its parameters accept.
DEFAULT_DEPTH_MAX_M = 10.0
DEFAULT_DEPTH_QUANTIZATION = 100.0
DEFAULT_PNG_LEVEL = 3
DEPTH_MAX_RANGE_M = (1.0, 100.0)
DEPTH_QUANTIZATION_RANGE = (1.0, 150.0)


def quantisation_constants(depth_max_m: float = DEFAULT_DEPTH_MAX_M,
                           depth_quantization: float = DEFAULT_DEPTH_QUANTIZATION
                           ) -> tuple[np.float32, np.float32]:
    """Return the 32FC1 inverse-depth constants (A, B) in float32, as the C++ encoder does.

    A = z0 (z0 + 1), B = 1 - A / depth_max; q = trunc(A / d + B).
    """
    z0 = np.float32(depth_quantization)
    quant_a = np.float32(z0 * (z0 + np.float32(1.0)))
    quant_b = np.float32(np.float32(1.0) - quant_a / np.float32(depth_max_m))
    return quant_a, quant_b


def pointcloud2_to_points(msg: Any) -> np.ndarray:
    """Read the x, y, z float32 fields of a PointCloud2 into (N, 3) float32 (any layout)."""
    offsets = {f.name: int(f.offset) for f in msg.fields
               if f.name in _XYZ and int(f.datatype) == PointField.FLOAT32}
    missing = [name for name in _XYZ if name not in offsets]
    if missing:
        raise ValueError(f'PointCloud2 has no float32 field(s) {", ".join(missing)}')
    order = '>' if msg.is_bigendian else '<'
    dtype = np.dtype({'names': list(_XYZ), 'formats': [order + 'f4'] * 3,
                      'offsets': [offsets[name] for name in _XYZ],
                      'itemsize': int(msg.point_step)})
    count = int(msg.width) * int(msg.height)
    row_step, width = int(msg.row_step), int(msg.width)
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if count == 0:
        return np.zeros((0, 3), dtype=np.float32)
    rows = raw[:row_step * int(msg.height)].reshape(int(msg.height), row_step)
    records = np.ascontiguousarray(rows[:, :width * int(msg.point_step)]).view(dtype).reshape(-1)
    return np.stack([records[name] for name in _XYZ], axis=1).astype(np.float32)


def depth_message_to_array(msg: Any) -> np.ndarray:
    """Decode a depth ``Image`` or ``CompressedImage`` (rclpy or rosbags) into its array.

    Image: :func:`conversions.image_to_array`; CompressedImage:
    :func:`compressed_depth_to_array`. Same result for the same frame either way (16UC1
    exactly, 32FC1 within the quantisation). Raises RosInputError naming the problem.
    """
    if is_compressed_image(msg):
        return compressed_depth_to_array(msg)
    return image_to_array(msg)


def quantisation_error_bound_m(depth_m: np.ndarray | float,
                               depth_quantization: float = DEFAULT_DEPTH_QUANTIZATION
                               ) -> np.ndarray | float:
    """Largest amount a 32FC1 depth grows through the codec: d' - d < d^2 / (A - d) [m].

    From q = trunc(A / d + B) > A / d + B - 1 and d' = A / (q - B): d <= d' < A d / (A - d)
    in exact arithmetic (float32 rounding adds a few ulp). depth_m [m]; A = z0 (z0 + 1).
    """
    quant_a = float(depth_quantization) * (float(depth_quantization) + 1.0)
    depth = np.asarray(depth_m, dtype=np.float64)
    return depth * depth / (quant_a - depth)


def array_to_compressed_depth(depth: np.ndarray, stamp: Time, frame_id: str, *,
                              encoding: str | None = None,
                              depth_max_m: float = DEFAULT_DEPTH_MAX_M,
                              depth_quantization: float = DEFAULT_DEPTH_QUANTIZATION,
                              png_level: int = DEFAULT_PNG_LEVEL) -> CompressedImage:
    """Build a ``compressedDepth png`` CompressedImage as compressed_depth_image_transport does.

    depth: (H, W) uint16 [mm] (encoding ``16UC1``, or ``mono16``) or float32 [m] (``32FC1``).
    encoding None picks it from the dtype. The message: header (stamp, frame_id), format
    ``<encoding>; compressedDepth png``, data = ConfigHeader (INV_DEPTH, A, B; zeros for
    16-bit) + PNG at ``png_level`` (0-9, the publisher's default 3).

    16-bit: values above ``uint16(depth_max_m * 1000)`` become 0, as the encoder does; the rest
    is lossless. 32FC1: q = trunc(A / d + B) with (A, B) from :func:`quantisation_constants`,
    and q = 0 (no return) where d >= depth_max_m or is NaN, as the encoder does, and also
    where d <= 0, is infinite or is nearer than A / (65535 - B) (0.15 m by default), where the
    C++ float-to-uint16 conversion is undefined.

    Raises ValueError naming the bad value: a parameter outside the publisher's ranges
    (depth_max_m 1-100, depth_quantization 1-150, png_level 0-9) or an array that is not
    one of the two depth layouts (RosInputError).
    """
    low, high = DEPTH_MAX_RANGE_M
    if not low <= depth_max_m <= high:
        raise ValueError(f'depth_max_m={depth_max_m} outside [{low:g}, {high:g}] m')
    low, high = DEPTH_QUANTIZATION_RANGE
    if not low <= depth_quantization <= high:
        raise ValueError(f'depth_quantization={depth_quantization} outside [{low:g}, {high:g}]')
    if int(png_level) != png_level or not 0 <= png_level <= 9:
        raise ValueError(f'png_level={png_level} must be an integer in [0, 9]')
    depth = np.asarray(depth)
    kind = {np.dtype(np.uint16): ('16UC1', 'mono16'),
            np.dtype(np.float32): ('32FC1',)}.get(depth.dtype.newbyteorder('='))
    if depth.ndim != 2 or kind is None or 0 in depth.shape:
        raise RosInputError(f'compressed depth needs a non-empty (H, W) uint16 [mm] or '
                            f'float32 [m] array, got shape {depth.shape} of {depth.dtype}')
    encoding = kind[0] if encoding is None else encoding
    if encoding not in kind:
        raise RosInputError(f'encoding {encoding!r} does not fit a {depth.dtype} array '
                            f'(expected {" or ".join(kind)})')
    if encoding == '32FC1':
        quant_a, quant_b = quantisation_constants(depth_max_m, depth_quantization)
        metres = depth.astype(np.float32)
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            inverse = quant_a / metres + quant_b  # float32, as the C++ encoder
            usable = (metres < np.float32(depth_max_m)) & (metres > 0) & (inverse >= 0) & (
                inverse < 65536.0)
        pixels = np.zeros(depth.shape, dtype=np.uint16)
        pixels[usable] = inverse[usable].astype(np.uint16)  # truncation toward zero
        config = CONFIG_HEADER.pack(INV_DEPTH, float(quant_a), float(quant_b))
    else:
        # static_cast<unsigned short>(depth_max * 1000.0f): truncation of the double.
        limit = np.uint16(min(int(depth_max_m * 1000.0), 65535))
        pixels = depth.astype(np.uint16, copy=True)
        pixels[pixels > limit] = 0
        config = CONFIG_HEADER.pack(INV_DEPTH, 0.0, 0.0)
    ok, png = cv2.imencode('.png', pixels, [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)])
    if not ok:  # pragma: no cover - OpenCV always encodes a uint16 array
        raise RosInputError('OpenCV could not encode the depth as PNG')
    return CompressedImage(header=Header(stamp=stamp, frame_id=frame_id),
                           format=f'{encoding}; compressedDepth png',
                           data=config + png.tobytes())
