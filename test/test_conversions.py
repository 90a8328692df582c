"""Tests of the message conversion layer (no rclpy.init, no ROS graph)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField

from message_helpers import pointcloud2_to_points
from obstacle_detection.labels import (CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN, LABEL_GROUND,
                                       LABEL_OBSTACLE)
from obstacle_detection.ros.conversions import (
    array_to_image,
    camera_info_to_intrinsics,
    costmap_to_occupancy_grid,
    DEPTH_SAMPLE_ROWS,
    depth_problem,
    depth_sample,
    image_to_array,
    image_to_rgb,
    intrinsics_come_from_k,
    intrinsics_problem,
    intrinsics_to_camera_info,
    occupancy_grid_to_costmap,
    points_to_pointcloud2,
    result_to_messages,
)
from obstacle_detection.pipeline.costmap import Costmap
from obstacle_detection.ros import RosInputError
from obstacle_detection.viz.overlay import render_overlay

from eval_helpers import is_obstacle_rgb
from obstacle_detection.pipeline.params import KINECT_V2_SD, Intrinsics
from obstacle_detection.pipeline.detector import DetectionResult

STAMP = Time(sec=1234, nanosec=567)
RNG_SEED = 20240611

DEPTH_CASES = [('16UC1', np.uint16), ('mono16', np.uint16), ('32FC1', np.float32)]


def _depth_array(dtype: type, shape: tuple[int, int] = (5, 7)) -> np.ndarray:
    rng = np.random.default_rng(RNG_SEED)
    if dtype is np.uint16:
        array = rng.integers(0, 65535, size=shape, dtype=np.uint16)
        array[0, 0] = 0x0102  # byte-asymmetric, so a wrong byte order cannot pass
        return array
    array = rng.uniform(0.2, 9.0, size=shape).astype(np.float32)
    array[0, 0] = np.nan
    array[1, 1] = 0.0
    return array


def _wire_image(array: np.ndarray, encoding: str, *, big_endian: bool, padding: int) -> Image:
    """Build an Image by hand: explicit byte order and ``padding`` junk bytes per row."""
    height, width = array.shape
    wire = array.astype(array.dtype.newbyteorder('>' if big_endian else '<'))
    rows = wire.view(np.uint8).reshape(height, -1)
    junk = np.full((height, padding), 0xAB, dtype=np.uint8)
    data = np.concatenate([rows, junk], axis=1)
    return Image(height=height, width=width, encoding=encoding, is_bigendian=big_endian,
                 step=data.shape[1], data=data.tobytes())


@pytest.mark.parametrize('padding', [0, 3, 16])
@pytest.mark.parametrize('big_endian', [False, True])
@pytest.mark.parametrize(('encoding', 'dtype'), DEPTH_CASES)
def test_image_to_array_reads_every_encoding_byte_order_and_padding(
        encoding: str, dtype: type, big_endian: bool, padding: int) -> None:
    expected = _depth_array(dtype)
    msg = _wire_image(expected, encoding, big_endian=big_endian, padding=padding)

    array = image_to_array(msg)

    assert array.dtype == np.dtype(dtype)
    assert array.dtype.isnative
    assert array.flags.writeable and array.flags.c_contiguous
    np.testing.assert_array_equal(array, expected)


@pytest.mark.parametrize(('encoding', 'dtype'), DEPTH_CASES)
def test_array_to_image_round_trip(encoding: str, dtype: type) -> None:
    expected = _depth_array(dtype, (4, 9))

    msg = array_to_image(expected, stamp=STAMP, frame_id='camera', encoding=encoding)

    assert (msg.height, msg.width, msg.encoding) == (4, 9, encoding)
    assert msg.step == 9 * np.dtype(dtype).itemsize
    assert not msg.is_bigendian
    assert msg.header.frame_id == 'camera' and msg.header.stamp == STAMP
    np.testing.assert_array_equal(image_to_array(msg), expected)


def test_array_to_image_picks_encoding_from_dtype() -> None:
    assert array_to_image(np.zeros((2, 2), np.uint16), stamp=STAMP,
                          frame_id='c').encoding == '16UC1'
    assert array_to_image(np.zeros((2, 2), np.float32), stamp=STAMP,
                          frame_id='c').encoding == '32FC1'
    rgb = array_to_image(np.zeros((2, 3, 3), np.uint8), stamp=STAMP, frame_id='c')
    assert (rgb.encoding, rgb.step) == ('rgb8', 9)


def test_array_to_image_refuses_dtype_that_does_not_fit_encoding() -> None:
    with pytest.raises(RosInputError, match="encoding '32FC1' needs 1 channel"):
        array_to_image(np.zeros((2, 2), np.uint16), stamp=STAMP, frame_id='c',
                       encoding='32FC1')


def test_array_to_image_refuses_unknown_dtype() -> None:
    with pytest.raises(RosInputError, match='no image encoding for dtype int64'):
        array_to_image(np.zeros((2, 2), np.int64), stamp=STAMP, frame_id='c')


def test_image_to_array_reads_rosbags_messages() -> None:
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    expected = _depth_array(np.uint16)
    wire = _wire_image(expected, '16UC1', big_endian=True, padding=2)
    bag_image = store.types['sensor_msgs/msg/Image']
    header = store.types['std_msgs/msg/Header'](
        stamp=store.types['builtin_interfaces/msg/Time'](sec=1, nanosec=2), frame_id='cam')
    msg = bag_image(header=header, height=wire.height, width=wire.width, encoding='16UC1',
                    is_bigendian=1, step=wire.step,
                    data=np.frombuffer(bytes(wire.data), dtype=np.uint8))
    decoded = store.deserialize_cdr(store.serialize_cdr(msg, bag_image.__msgtype__),
                                    bag_image.__msgtype__)

    np.testing.assert_array_equal(image_to_array(decoded), expected)


def test_image_to_array_refuses_unknown_encoding() -> None:
    msg = _wire_image(_depth_array(np.uint16), '16UC1', big_endian=False, padding=0)
    msg.encoding = 'rgb8'
    with pytest.raises(RosInputError, match="unsupported depth encoding 'rgb8'"):
        image_to_array(msg)


def test_image_to_array_refuses_odd_byte_count() -> None:
    msg = _wire_image(_depth_array(np.uint16), '16UC1', big_endian=False, padding=0)
    msg.data = bytes(msg.data)[:-1]
    with pytest.raises(RosInputError, match=r'data has 69 bytes, expected step \* height'):
        image_to_array(msg)


def test_image_to_array_refuses_step_shorter_than_a_row() -> None:
    msg = _wire_image(_depth_array(np.float32), '32FC1', big_endian=False, padding=0)
    msg.step = 27
    with pytest.raises(RosInputError, match='step=27 is shorter than one row'):
        image_to_array(msg)


def test_image_to_array_refuses_empty_image() -> None:
    with pytest.raises(RosInputError, match='empty image: width=0'):
        image_to_array(Image(encoding='16UC1', height=3, width=0, step=0))


def test_camera_info_round_trip() -> None:
    intrinsics = Intrinsics(fx=365.5, fy=366.25, cx=255.0, cy=211.5)

    msg = intrinsics_to_camera_info(intrinsics, 512, 424, stamp=STAMP, frame_id='depth')

    assert isinstance(msg, CameraInfo)
    assert (msg.width, msg.height, msg.header.frame_id) == (512, 424, 'depth')
    assert list(msg.p)[:3] == [365.5, 0.0, 255.0]
    assert camera_info_to_intrinsics(msg) == intrinsics


def _rectified_info() -> CameraInfo:
    """Return a CameraInfo whose K (raw image) and P (rectified image) differ."""
    msg = intrinsics_to_camera_info(Intrinsics(fx=365.5, fy=366.25, cx=255.0, cy=211.5),
                                    512, 424, stamp=STAMP, frame_id='depth')
    msg.p = [360.0, 0.0, 250.0, 0.0, 0.0, 362.0, 209.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def test_intrinsics_come_from_p_when_k_and_p_differ() -> None:
    msg = _rectified_info()

    assert camera_info_to_intrinsics(msg) == Intrinsics(fx=360.0, fy=362.0, cx=250.0, cy=209.0)
    assert not intrinsics_come_from_k(msg)


def test_intrinsics_come_from_k_only_when_p_is_all_zero() -> None:
    msg = _rectified_info()
    msg.p = [0.0] * 12

    assert camera_info_to_intrinsics(msg) == Intrinsics(fx=365.5, fy=366.25, cx=255.0,
                                                        cy=211.5)
    assert intrinsics_come_from_k(msg)


def test_p_with_a_zero_focal_length_is_refused_naming_p() -> None:
    msg = _rectified_info()
    msg.p = [0.0, 0.0, 250.0, 0.0, 0.0, 362.0, 209.0, 0.0, 0.0, 0.0, 1.0, 0.0]

    with pytest.raises(ValueError, match='CameraInfo P is not a usable pinhole model'):
        camera_info_to_intrinsics(msg)


def test_camera_info_with_zero_focal_length_is_refused() -> None:
    msg = CameraInfo(width=512, height=424)  # an uncalibrated camera publishes K = 0
    with pytest.raises(ValueError, match='CameraInfo K is not a usable pinhole model: '
                                         'intrinsics focal lengths must be > 0'):
        camera_info_to_intrinsics(msg)


def _points(count: int) -> np.ndarray:
    rng = np.random.default_rng(RNG_SEED)
    return rng.uniform(-3.0, 3.0, size=(count, 3)).astype(np.float32)


def test_pointcloud2_bytes_decode_to_the_same_points() -> None:
    points = _points(257)

    msg = points_to_pointcloud2(points, stamp=STAMP, frame_id='base_footprint')

    assert isinstance(msg, PointCloud2)
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 257, 12, 257 * 12)
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ('x', 0, PointField.FLOAT32, 1), ('y', 4, PointField.FLOAT32, 1),
        ('z', 8, PointField.FLOAT32, 1)]
    assert not msg.is_bigendian and msg.is_dense
    assert msg.header.frame_id == 'base_footprint' and msg.header.stamp == STAMP
    decoded = np.frombuffer(bytes(msg.data), dtype='<f4').reshape(-1, 3)
    np.testing.assert_array_equal(decoded, points)
    np.testing.assert_array_equal(pointcloud2_to_points(msg), points)


def test_pointcloud2_of_float64_points_is_float32() -> None:
    points = _points(5).astype(np.float64) + 1e-9
    decoded = pointcloud2_to_points(points_to_pointcloud2(points, stamp=STAMP, frame_id='f'))
    np.testing.assert_allclose(decoded, points, rtol=1e-6)


def test_pointcloud2_empty_cloud() -> None:
    msg = points_to_pointcloud2(np.zeros((0, 3), np.float32), stamp=STAMP, frame_id='f')
    assert (msg.width, msg.row_step, len(msg.data)) == (0, 0, 0)
    assert pointcloud2_to_points(msg).shape == (0, 3)


def test_pointcloud2_with_nan_is_not_dense() -> None:
    points = _points(4)
    points[2, 1] = np.nan
    assert not points_to_pointcloud2(points, stamp=STAMP, frame_id='f').is_dense


def test_pointcloud2_refuses_wrong_shape() -> None:
    with pytest.raises(ValueError, match=r'points must have shape \(N, 3\), got \(4, 2\)'):
        points_to_pointcloud2(np.zeros((4, 2)), stamp=STAMP, frame_id='f')


def _costmap() -> Costmap:
    data = np.full((4, 6), CELL_UNKNOWN, dtype=np.int8)  # ny = 4 rows (y), nx = 6 cols (x)
    data[1, 2] = CELL_OCCUPIED
    data[3, 0] = CELL_FREE
    data[0, 5] = CELL_OCCUPIED
    return Costmap(data=data, resolution_m=0.05, origin_xy_m=(0.0, -0.1))


def test_occupancy_grid_data_origin_and_size() -> None:
    costmap = _costmap()

    grid = costmap_to_occupancy_grid(costmap, stamp=STAMP, frame_id='base_footprint')

    assert isinstance(grid, OccupancyGrid)
    assert (grid.info.width, grid.info.height) == (6, 4)
    assert math.isclose(grid.info.resolution, 0.05, rel_tol=1e-7)  # float32 on the wire
    origin = grid.info.origin
    assert (origin.position.x, origin.position.y, origin.position.z) == (0.0, -0.1, 0.0)
    assert (origin.orientation.x, origin.orientation.y, origin.orientation.z,
            origin.orientation.w) == (0.0, 0.0, 0.0, 1.0)
    assert grid.header.frame_id == 'base_footprint' and grid.header.stamp == STAMP
    data = np.asarray(grid.data, dtype=np.int8).reshape(grid.info.height, grid.info.width)
    np.testing.assert_array_equal(data, costmap.data)
    # Row-major, row = y: the cell at x index 2, y index 1 is element 1 * width + 2.
    assert grid.data[1 * 6 + 2] == CELL_OCCUPIED


def test_occupancy_grid_reads_back_into_the_same_costmap() -> None:
    costmap = _costmap()
    grid = costmap_to_occupancy_grid(costmap, stamp=STAMP, frame_id='base_footprint')
    wire = deserialize_message(serialize_message(grid), OccupancyGrid)

    for message in (grid, wire):
        back = occupancy_grid_to_costmap(message)
        np.testing.assert_array_equal(back.data, costmap.data)
        assert back.data.dtype == np.int8 and back.origin_xy_m == (0.0, -0.1)
        assert math.isclose(back.resolution_m, 0.05, rel_tol=1e-7)  # float32 on the wire
    # a cell placed by its ground coordinates lands in the same cell after the round trip
    row, col, inside = occupancy_grid_to_costmap(wire).cell_of(np.array([[0.275, -0.025]]))
    assert inside[0] and (row[0], col[0]) == (1, 5)


def test_colour_image_round_trip() -> None:
    rgb = np.arange(3 * 4 * 3, dtype=np.uint8).reshape(3, 4, 3)
    msg = array_to_image(rgb, stamp=STAMP, frame_id='cam', encoding='rgb8')
    np.testing.assert_array_equal(image_to_rgb(msg), rgb)
    with pytest.raises(RosInputError, match="unsupported colour encoding '16UC1'"):
        image_to_rgb(array_to_image(np.zeros((2, 2), np.uint16), stamp=STAMP, frame_id='c'))


def _result() -> DetectionResult:
    labels = np.full((3, 4), LABEL_GROUND, dtype=np.uint8)
    labels[1, 2] = LABEL_OBSTACLE
    depth = np.linspace(0.5, 2.0, 12, dtype=np.float32).reshape(3, 4)
    obstacles, ground = _points(6), _points(9) + 5.0
    return DetectionResult(
        obstacle_points=obstacles, ground_points=ground, labels=labels, costmap=_costmap(),
        timings_ms={'total': 1.0}, voxel_points=np.concatenate([obstacles, ground]),
        voxel_normals=np.zeros((15, 3), np.float32),
        voxel_slope_obstacle=np.arange(15) < 6, voxel_is_obstacle=np.arange(15) < 6,
        voxel_neighbours=np.arange(15)[:, None], pixel_voxel=np.full((3, 4), -1, np.int32),
        depth_m=depth, intrinsics=KINECT_V2_SD)


def test_result_to_messages_minimal() -> None:
    messages = result_to_messages(_result(), stamp=STAMP, cloud_frame_id='cloud',
                                  costmap_frame_id='grid', image_frame_id='cam')
    assert set(messages) == {'obstacles', 'costmap'}
    assert messages['obstacles'].header.frame_id == 'cloud'
    assert messages['costmap'].header.frame_id == 'grid'
    np.testing.assert_array_equal(pointcloud2_to_points(messages['obstacles']),
                                  _result().obstacle_points)


def test_result_to_messages_with_ground_and_overlay() -> None:
    result = _result()

    messages = result_to_messages(result, stamp=STAMP, cloud_frame_id='cloud',
                                  costmap_frame_id='grid', image_frame_id='cam',
                                  with_ground=True,
                                  overlay_rgb=render_overlay(result.depth_m, result.labels))

    assert set(messages) == {'obstacles', 'costmap', 'ground', 'overlay'}
    assert all(m.header.stamp == STAMP for m in messages.values())
    np.testing.assert_array_equal(pointcloud2_to_points(messages['ground']),
                                  result.ground_points)
    overlay = messages['overlay']
    assert (overlay.encoding, overlay.header.frame_id, overlay.width, overlay.height) == (
        'rgb8', 'cam', 4, 3)
    rgb = np.frombuffer(bytes(overlay.data), np.uint8).reshape(3, 4, 3)
    assert is_obstacle_rgb(rgb[1, 2])


# -- plausibility of CameraInfo and depth (issue: plausible-looking nonsense is refused) ------
KINECT = Intrinsics(fx=365.0, fy=365.0, cx=256.0, cy=212.0)


def test_kinect_intrinsics_are_plausible() -> None:
    assert intrinsics_problem(KINECT, 512, 424) is None


@pytest.mark.parametrize('intrinsics, size, expected', [
    (Intrinsics(fx=1e300, fy=1e300, cx=256.0, cy=212.0), (512, 424),
     'fx=1e+300 px gives a 2.93e-296 deg field of view'),   # 2 atan(256 / 1e300)
    (Intrinsics(fx=1e-300, fy=1e-300, cx=256.0, cy=212.0), (512, 424),
     'fx=1e-300 px gives a 180 deg field of view'),
    (KINECT, (0, 0), 'CameraInfo image size is 0x0'),
    (Intrinsics(fx=365.0, fy=365.0, cx=5000.0, cy=212.0), (512, 424),
     'principal point cx=5000 px lies far outside the 512x424 image'),
    (Intrinsics(fx=365.0, fy=365.0, cx=256.0, cy=-300.0), (512, 424),
     'principal point cy=-300 px'),
])
def test_implausible_intrinsics_are_named(intrinsics: Intrinsics, size: tuple[int, int],
                                          expected: str) -> None:
    problem = intrinsics_problem(intrinsics, *size)
    assert problem is not None and expected in problem


def test_real_depth_is_plausible_in_both_encodings() -> None:
    rng = np.random.default_rng(0)
    mm = rng.integers(500, 4500, (424, 512)).astype(np.uint16)
    mm[::7] = 0
    assert depth_problem(mm) is None
    metres = mm.astype(np.float32) * np.float32(1e-3)
    metres[::5] = np.nan
    assert depth_problem(metres) is None
    assert depth_problem(np.zeros((4, 4), np.uint16)) is None   # no valid pixel: not judged here


@pytest.mark.parametrize(('inside_code', 'outside_code'), [(50, 49), (20000, 20001)])
@pytest.mark.parametrize('extra_inside', [0, -1])
def test_uint16_plausibility_counts_the_band_edges_as_the_metres_rule(
        inside_code: int, outside_code: int, extra_inside: int) -> None:
    """16UC1: a code at the edge of 0.05-20 m counts as inside, the next one out as outside.

    Half of the sampled valid pixels at the edge code and half just outside: exactly the
    plausible share (accepted); one pixel fewer inside: refused. Zeros are not counted, and
    the rows between the sampled ones are not read.
    """
    frame = np.full((424, 512), 65535, np.uint16)    # unsampled rows: implausible
    sample = depth_sample(frame).copy()
    flat = sample.reshape(-1)
    valid = flat.size - 100                          # 100 sampled pixels without a return
    inside = valid // 2 + extra_inside
    flat[:inside] = inside_code
    flat[inside:valid] = outside_code
    flat[valid:] = 0
    frame[::DEPTH_SAMPLE_ROWS] = sample
    metres = flat[flat > 0].astype(np.float64) * 1e-3
    share = np.count_nonzero((metres >= 0.05) & (metres <= 20.0)) / metres.size
    assert (share >= 0.5) == (extra_inside == 0)
    assert (depth_problem(frame) is None) == (extra_inside == 0)


def test_millimetres_sent_as_metres_are_refused_with_the_guess() -> None:
    mm = np.full((424, 512), 1500.0, np.float32)
    problem = depth_problem(mm)
    assert problem is not None
    assert 'median 1500 m' in problem and 'millimetres sent as 32FC1 metres' in problem


def test_a_wrong_byte_order_is_refused() -> None:
    mm = np.random.default_rng(1).integers(500, 4500, (424, 512)).astype(np.uint16)
    swapped = mm.byteswap()   # what a wrong is_bigendian flag decodes to
    problem = depth_problem(swapped)
    assert problem is not None and 'is_bigendian may be wrong' in problem
    assert depth_problem(mm) is None


def test_random_bytes_are_refused() -> None:
    noise = np.random.default_rng(2).integers(0, 65536, (424, 512)).astype(np.uint16)
    assert depth_problem(noise) is not None
    floats = np.random.default_rng(3).integers(0, 2**32, (424, 512), dtype=np.uint64)
    assert depth_problem(floats.astype(np.uint32).view(np.float32)) is not None
