"""Compressed depth images: ``sensor_msgs/CompressedImage`` <-> the pipeline's depth arrays.

Message types only, no rclpy: readers are duck-typed like :mod:`.conversions` and take rclpy
and rosbags messages alike (``format`` a string, ``data`` as ``bytes``, ``array.array`` or a
numpy ``uint8`` array). What the wire holds, learnt from compressed_depth_image_transport's
codec and iai_kinect2's kinect2_bridge:

``<encoding>; compressedDepth png`` (image_transport's ``compressedDepth`` plugin; older
releases wrote ``<encoding>; compressedDepth`` or only ``<encoding>``)
    ``data`` = a 12-byte ``ConfigHeader`` (int32 compression format, 0 = INV_DEPTH; float32
    depthQuantA, depthQuantB; little-endian) followed by a PNG of one 16-bit channel.
    ``16UC1`` / ``mono16``: the PNG holds the millimetres unchanged, except that the encoder
    zeroes values above ``depth_max`` (10 m by default); the quantisation fields are unused
    (the ROS 2 encoder leaves them uninitialised). ``32FC1``: the PNG holds the quantised
    inverse depth ``q = trunc(A / d + B)`` (0 = invalid, and every depth >= depth_max), with
    ``A = z0 (z0 + 1)``, ``B = 1 - A / depth_max``, z0 = ``depth_quantization`` (100 by
    default); decoding gives ``d' = A / (q - B)`` in float32 and NaN where q = 0, so
    ``0 <= d' - d < d^2 / (A - d)`` (2 mm at 4.5 m with the defaults).
``<encoding>; compressedDepth rvl`` (image_transport_plugins 4.0, Jazzy: the publisher's
``format`` parameter set to ``rvl``)
    the same 12-byte ``ConfigHeader`` (and the same pixels: millimetres, or the quantised
    inverse depth of a 32FC1 image), then the image width and height (uint32 little-endian)
    and the pixels coded by RVL (:mod:`.rvl`), lossless.
``16UC1; compressedDepth`` (iai_kinect2's ``.../compressed`` depth topics)
    the same header (quantisation fields uninitialised) followed by a PNG or, with the
    bridge's default ``use_png: false``, a TIFF of the millimetres.
``16UC1; png compressed`` / ``16UC1; tiff compressed`` (iai_kinect2's IR, image_transport's
``compressed`` plugin on 16-bit images)
    the PNG or TIFF alone, without the header.

Which of the last two is on the wire is told by the magic bytes (PNG or TIFF signature at
byte 0, or at byte 12 after a header), not by the format string. Lossy formats (JPEG) are
refused by name.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any, NamedTuple

import cv2
import numpy as np

from . import rvl
from .conversions import DEPTH_ENCODINGS, ImageFormatError

#: ``ConfigHeader`` of compressed_depth_image_transport: int32 format, float32 quantA, quantB.
CONFIG_HEADER = struct.Struct('<iff')
CONFIG_HEADER_SIZE = CONFIG_HEADER.size  # 12 bytes
#: The only compression format the header names (compressionFormat::INV_DEPTH).
INV_DEPTH = 0

PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
TIFF_SIGNATURES = (b'II*\x00', b'MM\x00*')

#: The compressedDepth publisher's defaults (ROS 2) and the ranges its parameters accept.
DEFAULT_DEPTH_MAX_M = 10.0
DEFAULT_DEPTH_QUANTIZATION = 100.0
DEFAULT_PNG_LEVEL = 3
DEPTH_MAX_RANGE_M = (1.0, 100.0)
DEPTH_QUANTIZATION_RANGE = (1.0, 150.0)

#: Topic suffixes image_transport adds to a raw topic for the compressed transports.
TRANSPORT_SUFFIXES = ('compressedDepth', 'compressed')
COMPRESSED_IMAGE_TYPE = 'sensor_msgs/msg/CompressedImage'

#: RVL data after the ConfigHeader: width, height (uint32 little-endian), then the stream.
RVL_SIZE = struct.Struct('<II')
#: The most pixels an RVL image may announce (4096 x 4096): a depth camera has fewer, and a
#: corrupt size must not make the decoder allocate gigabytes. (An all-zero image of any size
#: codes to 4 bytes, so its data length bounds nothing.)
MAX_RVL_PIXELS = 4096 * 4096

#: Error kinds of CompressedDepthError.
ERROR_KINDS = ('format', 'header', 'corrupt', 'size')


class CompressedDepthError(ImageFormatError):
    """A CompressedImage cannot be read as a depth image; ``str()`` names the problem.

    kind: ``'format'`` (the format string names no depth encoding or an unsupported
    compression), ``'header'`` (no or a bad ConfigHeader), ``'corrupt'`` (the PNG or TIFF
    cannot be decoded: truncated, CRC mismatch, wrong bit depth or channels) or ``'size'``
    (the image is not the expected width x height). An ImageFormatError, hence a ValueError:
    the callers that skip an unreadable Image skip an unreadable CompressedImage too.
    """

    def __init__(self, kind: str, message: str) -> None:
        """Keep ``kind`` (one of ERROR_KINDS) beside the message."""
        super().__init__(message)
        self.kind = kind


def _byte_string(data: Any) -> bytes:
    """Return a message's ``data`` (bytes, array.array, ndarray or a list of ints) as bytes."""
    if isinstance(data, bytes):
        return data
    try:
        return memoryview(data).cast('B').tobytes()
    except TypeError:  # a plain sequence of ints
        return np.asarray(data, dtype=np.uint8).tobytes()


def is_compressed_image(msg: Any) -> bool:
    """Whether ``msg`` is a CompressedImage (has ``format``, no ``encoding``), rclpy or rosbags."""
    return hasattr(msg, 'format') and not hasattr(msg, 'encoding')


def raw_topic(topic: str) -> str:
    """Return the raw topic under a transport topic: ``.../image/compressed`` -> ``.../image``.

    A topic without a transport suffix (TRANSPORT_SUFFIXES) is returned unchanged.
    """
    parent, _, last = topic.rstrip('/').rpartition('/')
    return parent if last in TRANSPORT_SUFFIXES and parent else topic


class DepthFormat(NamedTuple):
    """A compressed depth ``format`` read: its encoding, and which codec it names."""

    encoding: str          #: '16UC1', 'mono16' or '32FC1'
    compressed_depth: bool  #: names compressedDepth (or is an older, bare format)
    rvl: bool = False      #: ``compressedDepth rvl``


def parse_format(fmt: str) -> DepthFormat:
    """Read a CompressedImage ``format``: ``(depth encoding, names compressedDepth, is RVL)``.

    Accepted: ``<enc>``, ``<enc>; compressedDepth``, ``<enc>; compressedDepth png``,
    ``<enc>; compressedDepth rvl``, ``<enc>; png compressed ...`` and ``<enc>; tiff
    compressed ...`` with <enc> one of ``16UC1``, ``mono16``, ``32FC1``. Raises
    CompressedDepthError (kind ``'format'``) naming the format otherwise: another encoding (a
    colour image), JPEG, an unknown codec.
    """
    text = str(fmt)
    encoding, sep, rest = text.partition(';')
    encoding, rest = encoding.strip(), rest.strip()
    if encoding not in DEPTH_ENCODINGS:
        raise CompressedDepthError(
            'format', f'unknown compressed depth format {text!r}: the part before ";" must be '
            f'a depth encoding ({", ".join(DEPTH_ENCODINGS)}), got {encoding!r}')
    if not sep or rest in ('', 'compressedDepth'):
        return DepthFormat(encoding, True)  # older compressedDepth releases, iai_kinect2
    words = rest.split()
    if words[0] == 'compressedDepth':
        if words[1:] == ['png']:
            return DepthFormat(encoding, True)
        if words[1:] == ['rvl']:
            return DepthFormat(encoding, True, rvl=True)
        raise CompressedDepthError('format', f'unknown compressed depth format {text!r}: '
                                             'compressedDepth names neither png nor rvl')
    if words[0] in ('png', 'tiff', 'tif') and words[1:2] == ['compressed']:
        return DepthFormat(encoding, False)
    if words[0] in ('jpeg', 'jpg'):
        raise CompressedDepthError('format', f'compressed depth format {text!r}: JPEG is '
                                             'lossy and cannot carry depth')
    raise CompressedDepthError(
        'format', f'unknown compressed depth format {text!r}: expected "{encoding}; '
        f'compressedDepth png", "{encoding}; compressedDepth" or "{encoding}; png compressed"')


def _container(data: bytes, offset: int) -> str | None:
    """``'png'``, ``'tiff'`` or None: which image starts at ``offset`` of ``data``."""
    if data.startswith(PNG_SIGNATURE, offset):
        return 'png'
    if any(data.startswith(sig, offset) for sig in TIFF_SIGNATURES):
        return 'tiff'
    return None


def _check_png(png: bytes) -> tuple[int, int, int, int]:
    """Walk a PNG's chunks and check their CRCs; return (width, height, bit depth, colour type).

    OpenCV only says "cannot decode" (and libpng prints to stderr); this names the problem:
    a truncated stream, a chunk whose CRC does not match, a missing IHDR or IEND.
    """
    pos, size = len(PNG_SIGNATURE), len(png)
    header = None
    while True:
        if pos + 8 > size:
            raise CompressedDepthError('corrupt', f'corrupt PNG: truncated after {size} bytes '
                                                  '(no IEND chunk)')
        length, kind = struct.unpack_from('>I4s', png, pos)
        end = pos + 8 + length + 4
        if end > size:
            raise CompressedDepthError(
                'corrupt', f'corrupt PNG: truncated in its {kind!r} chunk at byte {pos} '
                f'({length} data bytes announced, {size - pos - 12} present)')
        (crc,) = struct.unpack_from('>I', png, end - 4)
        if zlib.crc32(png[pos + 4:end - 4]) != crc:
            raise CompressedDepthError(
                'corrupt', f'corrupt PNG: CRC mismatch in its {kind!r} chunk at byte {pos}')
        if header is None:
            if kind != b'IHDR' or length != 13:
                raise CompressedDepthError('corrupt', 'corrupt PNG: does not start with IHDR')
            header = struct.unpack_from('>IIBB', png, pos + 8)
        if kind == b'IEND':
            return header
        pos = end


def _decode_image(payload: bytes, container: str) -> np.ndarray:
    """Decode the PNG or TIFF ``payload`` into a (H, W) uint16 array, naming any problem."""
    if container == 'png':
        width, height, bit_depth, colour = _check_png(payload)
        if bit_depth != 16 or colour != 0:
            what = {0: 'grey', 2: 'RGB', 3: 'palette', 4: 'grey+alpha', 6: 'RGBA'}.get(colour)
            raise CompressedDepthError(
                'corrupt', f'PNG holds {bit_depth}-bit {what or f"colour type {colour}"} '
                'pixels, expected 16-bit grey (one channel of depth)')
        if width == 0 or height == 0:
            raise CompressedDepthError('corrupt', f'PNG is empty ({width}x{height})')
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # we name the problem
    try:
        image = cv2.imdecode(np.frombuffer(payload, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        image, reason = None, f' ({err.msg.strip() if hasattr(err, "msg") else err})'
    else:
        reason = ''
    finally:
        cv2.utils.logging.setLogLevel(level)
    name = container.upper()
    if image is None:
        raise CompressedDepthError('corrupt', f'corrupt {name}: OpenCV cannot decode its '
                                              f'{len(payload)} bytes{reason}')
    if image.ndim != 2 or image.dtype != np.uint16:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise CompressedDepthError(
            'corrupt', f'{name} holds {channels} channel(s) of {image.dtype}, expected one '
            'channel of uint16 depth')
    return image


def _config_header(data: bytes, after: int, what: str) -> tuple[float, float]:
    """Read the ConfigHeader at the start of ``data``: (depthQuantA, depthQuantB).

    ``after``: the bytes that must follow it at least, ``what`` they are (for the message).
    """
    if len(data) < CONFIG_HEADER_SIZE + after:
        raise CompressedDepthError(
            'header', f'compressed depth data has {len(data)} bytes: too short for the '
            f'{CONFIG_HEADER_SIZE}-byte ConfigHeader and {what}')
    fmt_code, quant_a, quant_b = CONFIG_HEADER.unpack_from(data, 0)
    if fmt_code != INV_DEPTH:
        raise CompressedDepthError(
            'header', f'bad ConfigHeader: compression format {fmt_code}, expected '
            f'{INV_DEPTH} (INV_DEPTH); the data is not compressedDepth (first bytes '
            f'{data[:CONFIG_HEADER_SIZE].hex()})')
    return quant_a, quant_b


def _decode_rvl(payload: bytes, expected_shape: tuple[int, int] | None) -> np.ndarray:
    """Decode the RVL part of compressedDepth (width, height, stream) into (H, W) uint16."""
    width, height = RVL_SIZE.unpack_from(payload, 0)
    if width == 0 or height == 0 or width * height > MAX_RVL_PIXELS:
        raise CompressedDepthError(
            'corrupt', f'RVL image announces {width}x{height} pixels: '
            + ('empty' if width * height == 0 else f'more than {MAX_RVL_PIXELS:,}'))
    if expected_shape is not None and (height, width) != tuple(expected_shape):
        raise CompressedDepthError(
            'size', f'compressed depth image is {width}x{height} but {expected_shape[1]}x'
            f'{expected_shape[0]} was expected (the CameraInfo size)')
    try:
        pixels = rvl.decode_rvl(payload[RVL_SIZE.size:], width * height)
    except rvl.RvlError as error:
        raise CompressedDepthError('corrupt', f'{error} ({width}x{height} image)') from error
    return pixels.reshape(height, width)


def compressed_depth_to_array(msg: Any, *,
                              expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Decode a compressed depth CompressedImage into the array the raw Image would give.

    msg: ``sensor_msgs/CompressedImage`` (rclpy or rosbags, ROS 1 or 2) in one of the formats
    of the module docstring. Returns, like :func:`conversions.image_to_array`, a fresh (H, W)
    uint16 array [mm] for ``16UC1`` / ``mono16`` (bit-identical to what was encoded) or float32
    [m] for ``32FC1`` (NaN = no return; within the quantisation error d^2 / (A - d)).
    expected_shape: (height, width) the image must have (e.g. the CameraInfo's), or None.

    Raises CompressedDepthError naming the problem: ``kind`` 'format' (unknown or unsupported
    format string), 'header' (data too short for the ConfigHeader and an image, a header
    naming another compression, quantisation parameters that cannot invert, a 32FC1 image
    without them), 'corrupt' (no PNG/TIFF where one must start, a truncated or damaged image,
    not one channel of 16 bits; an RVL image of no or too many pixels, or whose stream is not
    one of that size, see :mod:`.rvl`), 'size' (not ``expected_shape``).
    """
    encoding, _, is_rvl = parse_format(msg.format)
    data = _byte_string(msg.data)
    container = None if is_rvl else _container(data, 0)
    quant: tuple[float, float] | None = None
    if is_rvl:
        quant = _config_header(data, RVL_SIZE.size, 'the RVL image size and data')
        payload = data[CONFIG_HEADER_SIZE:]
    elif container is None:
        quant = _config_header(data, 1, 'an image')
        container = _container(data, CONFIG_HEADER_SIZE)
        if container is None:
            raise CompressedDepthError(
                'corrupt', f'no PNG or TIFF after the {CONFIG_HEADER_SIZE}-byte ConfigHeader '
                f'(it starts with {data[CONFIG_HEADER_SIZE:CONFIG_HEADER_SIZE + 8].hex()})')
        payload = data[CONFIG_HEADER_SIZE:]
    else:
        payload = data
    if encoding == '32FC1':
        if quant is None:
            raise CompressedDepthError(
                'header', '32FC1 compressed depth without the ConfigHeader: the quantisation '
                'parameters needed to invert the depth are missing')
        quant_a, quant_b = quant
        if not (np.isfinite(quant_a) and np.isfinite(quant_b) and quant_a > 0):
            raise CompressedDepthError(
                'header', f'bad ConfigHeader: depthQuantA={quant_a:g}, depthQuantB={quant_b:g} '
                'cannot invert the 32FC1 depth (A must be finite and positive)')
    image = (_decode_rvl(payload, expected_shape) if is_rvl
             else _decode_image(payload, container))
    if expected_shape is not None and image.shape != tuple(expected_shape):
        height, width = expected_shape
        raise CompressedDepthError(
            'size', f'compressed depth image is {image.shape[1]}x{image.shape[0]} but '
            f'{width}x{height} was expected (the CameraInfo size)')
    if encoding != '32FC1':
        return np.ascontiguousarray(image, dtype=np.uint16)
    quant_a32, quant_b32 = np.float32(quant[0]), np.float32(quant[1])
    depth = np.full(image.shape, np.nan, dtype=np.float32)
    valid = image != 0
    # float32 throughout, as the C++ decoder: d = A / (float(q) - B).
    np.divide(quant_a32, image.astype(np.float32) - quant_b32, out=depth, where=valid)
    return depth




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
