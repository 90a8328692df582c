"""Compressed depth images: ``sensor_msgs/CompressedImage`` <-> the pipeline's depth arrays."""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np

from . import rvl
from . import RosInputError
from .conversions import DEPTH_ENCODINGS, byte_view

#: ``ConfigHeader`` of compressed_depth_image_transport: int32 format, float32 quantA, quantB.
CONFIG_HEADER = struct.Struct('<iff')
CONFIG_HEADER_SIZE = CONFIG_HEADER.size  # 12 bytes
#: The only compression format the header names (compressionFormat::INV_DEPTH).
INV_DEPTH = 0

PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
TIFF_SIGNATURES = (b'II*\x00', b'MM\x00*')

#: Topic suffixes image_transport adds to a raw topic for the compressed transports.
TRANSPORT_SUFFIXES = ('compressedDepth', 'compressed')
COMPRESSED_IMAGE_TYPE = 'sensor_msgs/msg/CompressedImage'

#: RVL data after the ConfigHeader: width, height (uint32 little-endian), then the stream.
RVL_SIZE = struct.Struct('<II')
#: The most pixels an RVL image may announce (4096 x 4096): a depth camera has fewer, and a
#: corrupt size must not make the decoder allocate gigabytes. (An all-zero image of any size
#: codes to 4 bytes, so its data length bounds nothing.)
MAX_RVL_PIXELS = 4096 * 4096

def is_compressed_image(msg: Any) -> bool:
    """Whether ``msg`` is a CompressedImage (has ``format``, no ``encoding``), rclpy or rosbags."""
    return hasattr(msg, 'format') and not hasattr(msg, 'encoding')


def raw_topic(topic: str) -> str:
    """Return the raw topic under a transport topic: ``.../image/compressed`` -> ``.../image``."""
    parent, _, last = topic.rstrip('/').rpartition('/')
    return parent if last in TRANSPORT_SUFFIXES and parent else topic


def parse_format(fmt: str) -> tuple[str, bool]:
    """Read a CompressedImage ``format``: ``(depth encoding, is RVL)``."""
    text = str(fmt)
    encoding, sep, rest = text.partition(';')
    encoding, rest = encoding.strip(), rest.strip()
    if encoding not in DEPTH_ENCODINGS:
        raise RosInputError(
            f'unknown compressed depth format {text!r}: the part before ";" must be '
            f'a depth encoding ({", ".join(DEPTH_ENCODINGS)}), got {encoding!r}')
    if not sep or rest in ('', 'compressedDepth'):
        return encoding, False  # older compressedDepth releases, iai_kinect2
    words = rest.split()
    if words[0] == 'compressedDepth':
        if words[1:] in (['png'], ['rvl']):
            return encoding, words[1] == 'rvl'
        raise RosInputError(f'unknown compressed depth format {text!r}: '
                            'compressedDepth names neither png nor rvl')
    if words[0] in ('png', 'tiff', 'tif') and words[1:2] == ['compressed']:
        return encoding, False
    if words[0] in ('jpeg', 'jpg'):
        raise RosInputError(f'compressed depth format {text!r}: JPEG is '
                            'lossy and cannot carry depth')
    raise RosInputError(
        f'unknown compressed depth format {text!r}: expected "{encoding}; '
        f'compressedDepth png", "{encoding}; compressedDepth" or "{encoding}; png compressed"')


def _container(data: bytes, offset: int) -> str | None:
    """``'png'``, ``'tiff'`` or None: which image starts at ``offset`` of ``data``."""
    if data.startswith(PNG_SIGNATURE, offset):
        return 'png'
    if any(data.startswith(sig, offset) for sig in TIFF_SIGNATURES):
        return 'tiff'
    return None


def _decode_image(payload: bytes, container: str) -> np.ndarray:
    """Decode the PNG or TIFF ``payload`` into a (H, W) uint16 array, naming any problem."""
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
        raise RosInputError(f'corrupt {name}: OpenCV cannot decode its '
                            f'{len(payload)} bytes{reason}')
    if image.ndim != 2 or image.dtype != np.uint16:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise RosInputError(
            f'{name} holds {channels} channel(s) of {image.dtype}, expected one '
            'channel of uint16 depth')
    return image


def _config_header(data: bytes, after: int, what: str) -> tuple[float, float]:
    """Read the ConfigHeader at the start of ``data``: (depthQuantA, depthQuantB)."""
    if len(data) < CONFIG_HEADER_SIZE + after:
        raise RosInputError(
            f'compressed depth data has {len(data)} bytes: too short for the '
            f'{CONFIG_HEADER_SIZE}-byte ConfigHeader and {what}')
    fmt_code, quant_a, quant_b = CONFIG_HEADER.unpack_from(data, 0)
    if fmt_code != INV_DEPTH:
        raise RosInputError(
            f'bad ConfigHeader: compression format {fmt_code}, expected '
            f'{INV_DEPTH} (INV_DEPTH); the data is not compressedDepth (first bytes '
            f'{data[:CONFIG_HEADER_SIZE].hex()})')
    return quant_a, quant_b


def _decode_rvl(payload: bytes) -> np.ndarray:
    """Decode the RVL part of compressedDepth (width, height, stream) into (H, W) uint16."""
    width, height = RVL_SIZE.unpack_from(payload, 0)
    if width == 0 or height == 0 or width * height > MAX_RVL_PIXELS:
        raise RosInputError(
            f'RVL image announces {width}x{height} pixels: '
            + ('empty' if width * height == 0 else f'more than {MAX_RVL_PIXELS:,}'))
    try:
        pixels = rvl.decode_rvl(payload[RVL_SIZE.size:], width * height)
    except RosInputError as error:
        raise RosInputError(f'{error} ({width}x{height} image)') from error
    return pixels.reshape(height, width)


def compressed_depth_to_array(msg: Any) -> np.ndarray:
    """Decode a compressed depth CompressedImage into the array the raw Image would give."""
    encoding, is_rvl = parse_format(msg.format)
    data = byte_view(msg.data).tobytes()
    container = None if is_rvl else _container(data, 0)
    quant: tuple[float, float] | None = None
    if is_rvl:
        quant = _config_header(data, RVL_SIZE.size, 'the RVL image size and data')
        payload = data[CONFIG_HEADER_SIZE:]
    elif container is None:
        quant = _config_header(data, 1, 'an image')
        container = _container(data, CONFIG_HEADER_SIZE)
        if container is None:
            raise RosInputError(
                f'no PNG or TIFF after the {CONFIG_HEADER_SIZE}-byte ConfigHeader '
                f'(it starts with {data[CONFIG_HEADER_SIZE:CONFIG_HEADER_SIZE + 8].hex()})')
        payload = data[CONFIG_HEADER_SIZE:]
    else:
        payload = data
    if encoding == '32FC1':
        if quant is None:
            raise RosInputError(
                '32FC1 compressed depth without the ConfigHeader: the quantisation '
                'parameters needed to invert the depth are missing')
        quant_a, quant_b = quant
        if not (np.isfinite(quant_a) and np.isfinite(quant_b) and quant_a > 0):
            raise RosInputError(
                f'bad ConfigHeader: depthQuantA={quant_a:g}, depthQuantB={quant_b:g} '
                'cannot invert the 32FC1 depth (A must be finite and positive)')
    image = _decode_rvl(payload) if is_rvl else _decode_image(payload, container)
    if encoding != '32FC1':
        return np.ascontiguousarray(image, dtype=np.uint16)
    quant_a32, quant_b32 = np.float32(quant[0]), np.float32(quant[1])
    depth = np.full(image.shape, np.nan, dtype=np.float32)
    valid = image != 0
    # float32 throughout, as the C++ decoder: d = A / (float(q) - B).
    np.divide(quant_a32, image.astype(np.float32) - quant_b32, out=depth, where=valid)
    return depth
