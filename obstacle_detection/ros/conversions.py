"""Conversions between ROS messages and the numpy arrays of the pipeline."""

from __future__ import annotations

import array
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import Header

from obstacle_detection.pipeline.params import Intrinsics

from . import RosInputError

if TYPE_CHECKING:
    from builtin_interfaces.msg import Time

    from obstacle_detection.pipeline.costmap import Costmap
    from obstacle_detection.pipeline.detector import DetectionResult

#: Depth encodings the pipeline reads -> (numpy base dtype, channels).
DEPTH_ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    '16UC1': (np.dtype(np.uint16), 1),
    'mono16': (np.dtype(np.uint16), 1),
    '32FC1': (np.dtype(np.float32), 1),
}

#: Every encoding ``array_to_image`` writes -> (numpy base dtype, channels).
IMAGE_ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    **DEPTH_ENCODINGS,
    'rgb8': (np.dtype(np.uint8), 3),
    'bgr8': (np.dtype(np.uint8), 3),
}

#: Default encoding per (dtype, channels) for ``array_to_image``: the first listed above.
_DEFAULT_ENCODING = {kind: name for name, kind in reversed(IMAGE_ENCODINGS.items())}


def byte_view(data: Any) -> np.ndarray:
    """Return a flat uint8 view of a message's ``data`` (bytes, array.array, ndarray or a list)."""
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except TypeError:  # a plain sequence of ints
        return np.asarray(data, dtype=np.uint8).reshape(-1)


def image_to_array(msg: Any, *, copy: bool = True) -> np.ndarray:
    """Decode a depth Image message into a native-byte-order array.

    16UC1/mono16 -> (H, W) uint16 [mm], 32FC1 -> float32 [m]; copy=False may return a view of
    the message's data (do not write into it). Raises RosInputError naming the bad value.
    """
    encoding = str(msg.encoding)
    if encoding not in DEPTH_ENCODINGS:
        raise RosInputError(
            f'unsupported depth encoding {encoding!r}: expected one of '
            f'{", ".join(DEPTH_ENCODINGS)}')
    return _pixels(msg, *DEPTH_ENCODINGS[encoding], copy=copy)


def image_to_rgb(msg: Any) -> np.ndarray:
    """Decode an ``rgb8`` Image message (the node's overlay) into (H, W, 3) RGB."""
    if str(msg.encoding) != 'rgb8':
        raise RosInputError(f'unsupported colour encoding {msg.encoding!r}: expected rgb8')
    return _pixels(msg, *IMAGE_ENCODINGS['rgb8'])


def _pixels(msg: Any, base: np.dtype, channels: int, copy: bool = True) -> np.ndarray:
    """(H, W) or (H, W, channels) native-order pixels of an Image; RosInputError if bad."""
    encoding = str(msg.encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise RosInputError(f'empty image: width={width}, height={height}')
    row_bytes = width * channels * base.itemsize
    if step < row_bytes:
        raise RosInputError(
            f'step={step} is shorter than one row of {width} x {encoding} ({row_bytes} bytes)')
    buffer = byte_view(msg.data)
    if buffer.size != step * height:
        raise RosInputError(
            f'data has {buffer.size} bytes, expected step * height = {step} * {height} = '
            f'{step * height}')
    wire = base.newbyteorder('>' if msg.is_bigendian else '<')
    rows = buffer.reshape(height, step)[:, :row_bytes]
    # The copy makes the rows contiguous (drops the padding); astype() then yields native order.
    shape = (height, width) if channels == 1 else (height, width, channels)
    pixels = np.ascontiguousarray(rows).view(wire).reshape(shape)
    return pixels.astype(base.newbyteorder('='), copy=copy)


def array_to_image(array: np.ndarray, *, stamp: Time, frame_id: str,
                   encoding: str | None = None) -> Image:
    """Build an Image message from an array (little-endian, no row padding)."""
    array = np.asarray(array)
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (1, 3)):
        raise RosInputError(f'cannot make an image from an array of shape {array.shape}')
    channels = 1 if array.ndim == 2 else array.shape[2]
    if encoding is None:
        encoding = _DEFAULT_ENCODING.get((array.dtype.newbyteorder('='), channels))
        if encoding is None:
            raise RosInputError(
                f'no image encoding for dtype {array.dtype} with {channels} channel(s)')
    if encoding not in IMAGE_ENCODINGS:
        raise RosInputError(
            f'unsupported encoding {encoding!r}: expected one of {", ".join(IMAGE_ENCODINGS)}')
    base, want_channels = IMAGE_ENCODINGS[encoding]
    if array.dtype.newbyteorder('=') != base or channels != want_channels:
        raise RosInputError(
            f'encoding {encoding!r} needs {want_channels} channel(s) of {base}, got '
            f'{channels} of {array.dtype}')
    height, width = array.shape[:2]
    little = np.ascontiguousarray(array, dtype=base.newbyteorder('<'))
    return Image(
        header=Header(stamp=stamp, frame_id=frame_id), height=height, width=width,
        encoding=encoding, is_bigendian=0, step=width * channels * base.itemsize,
        data=little.tobytes())


#: Why a CameraInfo's intrinsics come from K: its P is all zero.
K_FALLBACK_NOTE = ('P is all zero (a driver that fills only K): intrinsics from K, which '
                   'describe the unrectified image')


def intrinsics_come_from_k(msg: Any) -> bool:
    """Whether :func:`camera_info_to_intrinsics` reads K: the CameraInfo's P is all zero."""
    p = np.asarray(msg.p, dtype=np.float64).reshape(-1)
    return not np.any(p)


def camera_info_to_intrinsics(msg: Any) -> Intrinsics:
    """Pinhole intrinsics from a CameraInfo's P, the rectified image's matrix [px].

    From K only when P is all zero (:func:`intrinsics_come_from_k`); ValueError if uncalibrated.
    """
    name, columns = ('K', 3) if intrinsics_come_from_k(msg) else ('P', 4)
    matrix = np.asarray(msg.k if name == 'K' else msg.p, dtype=np.float64).reshape(-1)
    if matrix.size != 3 * columns:
        raise ValueError(f'CameraInfo {name} has {matrix.size} entries, expected {3 * columns}')
    m = matrix.reshape(3, columns)
    try:
        return Intrinsics(fx=float(m[0, 0]), fy=float(m[1, 1]), cx=float(m[0, 2]),
                          cy=float(m[1, 2]))
    except ValueError as error:
        raise ValueError(f'CameraInfo {name} is not a usable pinhole model: {error}') from error


#: Field of view a depth camera can have [deg]: focal lengths outside it are a bad CameraInfo.
PLAUSIBLE_FOV_DEG = (5.0, 170.0)
#: How far the principal point may lie outside the image, as a share of its size.
PRINCIPAL_POINT_MARGIN = 0.25
#: Depths any depth sensor of this class returns [m]: near limit, far limit.
PLAUSIBLE_DEPTH_M = (0.05, 20.0)
#: A frame is implausible when less than this share of its valid pixels lies in that band.
PLAUSIBLE_SHARE = 0.5
#: The checks of a frame read every this many-th row (:func:`depth_sample`).
DEPTH_SAMPLE_ROWS = 16


def intrinsics_problem(intrinsics: Intrinsics, width: int, height: int) -> str | None:
    """Say why intrinsics cannot belong to a ``width`` x ``height`` depth camera, or None."""
    if width <= 0 or height <= 0:
        return (f'CameraInfo image size is {width}x{height}: a depth camera has a size, '
                'needed to check frames against it')
    low_deg, high_deg = PLAUSIBLE_FOV_DEG
    for axis, focal, size in (('fx', intrinsics.fx, width), ('fy', intrinsics.fy, height)):
        fov = 2.0 * math.degrees(math.atan2(size / 2.0, focal))
        if not low_deg <= fov <= high_deg:
            return (f'CameraInfo {axis}={focal:g} px gives a {fov:.3g} deg field of view over '
                    f'{size} px ({"too narrow" if fov < low_deg else "too wide"}), outside '
                    f'the {low_deg:g}-{high_deg:g} deg of any depth camera')
    margin = PRINCIPAL_POINT_MARGIN
    for axis, centre, size in (('cx', intrinsics.cx, width), ('cy', intrinsics.cy, height)):
        if not -margin * size <= centre <= (1.0 + margin) * size:
            return (f'CameraInfo principal point {axis}={centre:g} px lies far outside the '
                    f'{width}x{height} image')
    return None


def depth_sample(depth: np.ndarray) -> np.ndarray:
    """Return the rows of a depth frame that the checks of a frame read (a view)."""
    return depth[::DEPTH_SAMPLE_ROWS]


def depth_problem(depth: np.ndarray) -> str | None:
    """Say why a decoded depth frame cannot be real depth, or None."""
    sample = depth_sample(depth)
    if sample.dtype.kind == 'f':
        metres = sample[np.isfinite(sample) & (sample > 0)].astype(np.float64)
        unit = '32FC1 [m]'
    else:
        metres = sample[sample > 0].astype(np.float64) * 1e-3
        unit = '16UC1 [mm]'
    if metres.size == 0:
        return None
    near, far = PLAUSIBLE_DEPTH_M
    share = float(np.count_nonzero((metres >= near) & (metres <= far))) / metres.size
    if share >= PLAUSIBLE_SHARE:
        return None
    median = float(np.median(metres))
    if sample.dtype.kind == 'f' and median > 50.0:
        guess = '; it looks like millimetres sent as 32FC1 metres'
    elif sample.dtype.kind != 'f' and median > far:
        guess = '; is_bigendian may be wrong, or the values are not millimetres'
    elif median < near:
        guess = '; the values look too small for the unit (metres sent as 16UC1?)'
    else:
        guess = ''
    return (f'implausible depth for {unit}: only {100.0 * share:.0f} % of the valid pixels '
            f'lie within {near:g}-{far:g} m (median {median:.4g} m){guess}')


def intrinsics_to_camera_info(intrinsics: Intrinsics, width: int, height: int, *, stamp: Time,
                              frame_id: str) -> CameraInfo:
    """Build a CameraInfo of an undistorted pinhole camera (K, P, identity R, zero D)."""
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    return CameraInfo(
        header=Header(stamp=stamp, frame_id=frame_id), width=int(width), height=int(height),
        distortion_model='plumb_bob', d=[0.0] * 5,
        k=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def points_to_pointcloud2(points: np.ndarray, *, stamp: Time, frame_id: str) -> PointCloud2:
    """Build an unorganised PointCloud2 (height 1) of float32 x, y, z, little-endian."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f'points must have shape (N, 3), got {points.shape}')
    xyz = np.ascontiguousarray(points, dtype='<f4')
    fields = [PointField(name=name, offset=i * 4, datatype=PointField.FLOAT32, count=1)
              for i, name in enumerate('xyz')]
    count = xyz.shape[0]
    # filled in place: the constructor builds a default header anyway, copies data=bytes twice
    msg = PointCloud2(height=1, width=count, fields=fields, is_bigendian=False, point_step=12,
                      row_step=12 * count, is_dense=bool(np.isfinite(xyz).all()))
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.data = _byte_array('B', xyz)
    return msg


def _byte_array(typecode: str, values: np.ndarray) -> array.array:
    """Return an array.array of a C-contiguous array's bytes, copied once."""
    out = array.array(typecode)
    out.frombytes(memoryview(values.reshape(-1)).cast('B'))
    return out


def costmap_to_occupancy_grid(costmap: Costmap, *, stamp: Time,
                              frame_id: str) -> OccupancyGrid:
    """Build an OccupancyGrid of the costmap, lying in the ground plane of ``frame_id``."""
    data = np.ascontiguousarray(costmap.data, dtype=np.int8)
    # filled in place: the default sub-messages are built anyway (see points_to_pointcloud2)
    grid = OccupancyGrid()
    grid.header.stamp = stamp
    grid.header.frame_id = frame_id
    info = grid.info
    info.map_load_time = stamp
    info.resolution = float(costmap.resolution_m)
    info.width = int(data.shape[1])
    info.height = int(data.shape[0])
    info.origin.position.x = float(costmap.origin_xy_m[0])
    info.origin.position.y = float(costmap.origin_xy_m[1])
    info.origin.orientation.w = 1.0
    # array.array('b') is stored as is; a numpy array or a list would be converted per element.
    grid.data = _byte_array('b', data)
    return grid


def occupancy_grid_to_costmap(grid: Any) -> Costmap:
    """Read a grid the node published back into a Costmap (axis-aligned, as it publishes)."""
    from obstacle_detection.pipeline.costmap import Costmap

    info = grid.info
    cells = byte_view(grid.data).view(np.int8)
    return Costmap(data=cells.reshape(int(info.height), int(info.width)).copy(),
                   resolution_m=float(info.resolution),
                   origin_xy_m=(float(info.origin.position.x), float(info.origin.position.y)))


def result_to_messages(result: DetectionResult, *, stamp: Time, cloud_frame_id: str,
                       costmap_frame_id: str, image_frame_id: str, with_ground: bool = False,
                       overlay_rgb: np.ndarray | None = None,
                       clearing_points: np.ndarray | None = None,
                       marking_points: np.ndarray | None = None) -> dict[str, Any]:
    """All output messages of one pipeline result, stamped with the input's stamp.

    Keys: 'obstacles', 'costmap', and 'ground', 'overlay', 'clearing', 'marking' when asked
    for. clearing_points: (N, 3) in the image's optical frame; marking_points: (M, 3), the
    marks matched to them for a voxel layer (NodeConfig.nav2_clouds), in cloud_frame_id.
    """
    messages: dict[str, Any] = {
        'obstacles': points_to_pointcloud2(result.obstacle_points, stamp=stamp,
                                           frame_id=cloud_frame_id),
        'costmap': costmap_to_occupancy_grid(result.costmap, stamp=stamp,
                                             frame_id=costmap_frame_id),
    }
    if with_ground:
        messages['ground'] = points_to_pointcloud2(result.ground_points, stamp=stamp,
                                                   frame_id=cloud_frame_id)
    if clearing_points is not None:
        messages['clearing'] = points_to_pointcloud2(clearing_points, stamp=stamp,
                                                     frame_id=image_frame_id)
    if marking_points is not None:
        messages['marking'] = points_to_pointcloud2(marking_points, stamp=stamp,
                                                    frame_id=cloud_frame_id)
    if overlay_rgb is not None:
        messages['overlay'] = array_to_image(overlay_rgb, stamp=stamp, frame_id=image_frame_id,
                                             encoding='rgb8')
    return messages
