"""Tests of tools/bag_convert.py: each layout converts and reads back intact; bad input fails."""

from __future__ import annotations

import io
import struct
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from builtin_interfaces.msg import Time as RclTime
from rclpy.serialization import deserialize_message
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, Image

from message_helpers import array_to_compressed_depth
from obstacle_detection.ros.compressed_depth import compressed_depth_to_array
from obstacle_detection.ros.conversions import image_to_array
from obstacle_detection.pipeline.params import KINECT_V2_SD, Intrinsics
from obstacle_detection.sim.scenes import render_scene
from obstacle_detection.evaluation import datasets
from obstacle_detection.cli import bag_writer
from obstacle_detection.tools import bag_convert
from obstacle_detection.cli.progress import Progress

INTR = Intrinsics(60.0, 61.0, 40.0, 29.5)
SIZE = (80, 60)  # width, height
DEPTH = bag_writer.DEFAULT_DEPTH_TOPIC
INFO = bag_writer.DEFAULT_INFO_TOPIC
COLOR = bag_writer.DEFAULT_COLOR_TOPIC
JAZZY = get_typestore(Stores.ROS2_JAZZY)
ROS_TYPES = {'sensor_msgs/msg/Image': Image, 'sensor_msgs/msg/CameraInfo': CameraInfo}


def scene_depth(k: int) -> np.ndarray:
    """(60, 80) uint16 [mm] frame k of the walking-person scene."""
    return render_scene('person_walking', seed=3, intrinsics=INTR, size=SIZE,
                        frame_index=k).depth_mm


def fake_color(depth: np.ndarray, k: int) -> np.ndarray:
    """Return a (H, W, 3) uint8 BGR picture, different per channel and per frame."""
    grey = (depth // 20).astype(np.uint8)
    return np.dstack([grey, 255 - grey, np.full_like(grey, 10 * k)])


def write_intrinsics(path: Path, intr: Intrinsics = INTR, size: tuple[int, int] | None = SIZE
                     ) -> Path:
    text = f'fx: {intr.fx}\nfy: {intr.fy}\ncx: {intr.cx}\ncy: {intr.cy}\n'
    if size is not None:
        text += f'width: {size[0]}\nheight: {size[1]}\n'
    path.write_text(text)
    return path


def read_bag(path: Path) -> dict[str, list[tuple[int, object]]]:
    """Topic -> [(bag timestamp ns, rosbags message)], also checking rclpy can read each one."""
    topics: dict[str, list[tuple[int, object]]] = {}
    with Reader(path) as reader:
        for conn, timestamp, raw in reader.messages():
            msg = JAZZY.deserialize_cdr(raw, conn.msgtype)
            if conn.msgtype in ROS_TYPES:
                assert isinstance(deserialize_message(bytes(raw), ROS_TYPES[conn.msgtype]),
                                  ROS_TYPES[conn.msgtype])
            topics.setdefault(conn.topic, []).append((timestamp, msg))
    return topics


def stamp_of(msg: object) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def check_info(msg: object, intr: Intrinsics, size: tuple[int, int], frame_id: str) -> None:
    assert msg.header.frame_id == frame_id
    assert (msg.width, msg.height) == size
    np.testing.assert_allclose(msg.k, [intr.fx, 0, intr.cx, 0, intr.fy, intr.cy, 0, 0, 1])
    np.testing.assert_allclose(msg.p, [intr.fx, 0, intr.cx, 0, 0, intr.fy, intr.cy, 0, 0, 0, 1, 0])
    np.testing.assert_allclose(msg.r, np.eye(3).ravel())
    np.testing.assert_allclose(msg.d, 0.0)


def check_frames(bag: Path, depths: list[np.ndarray], stamps: list[int], *,
                 colors: list[np.ndarray | None] | None = None, intr: Intrinsics = INTR,
                 encoding: str = 'bgr8') -> None:
    """Every depth value, stamp, encoding and intrinsic of the bag is what was written."""
    topics = read_bag(bag)
    frame_id = bag_writer.DEFAULT_FRAME_ID
    size = (depths[0].shape[1], depths[0].shape[0])
    assert len(topics[DEPTH]) == len(topics[INFO]) == len(depths)
    for (t, depth_msg), (t_info, info_msg), want, stamp in zip(
            topics[DEPTH], topics[INFO], depths, stamps, strict=True):
        assert t == t_info == stamp == stamp_of(depth_msg) == stamp_of(info_msg)
        assert depth_msg.encoding == '16UC1'
        assert depth_msg.header.frame_id == frame_id
        np.testing.assert_array_equal(image_to_array(depth_msg), want)
        check_info(info_msg, intr, size, frame_id)
    if colors is None:
        assert COLOR not in topics
        return
    want_colors = [(c, s) for c, s in zip(colors, stamps) if c is not None]
    assert len(topics[COLOR]) == len(want_colors)
    for (t, msg), (color, stamp) in zip(topics[COLOR], want_colors, strict=True):
        assert t == stamp == stamp_of(msg)
        assert msg.encoding == encoding
        got = np.asarray(msg.data).reshape(msg.height, msg.width, 3)
        np.testing.assert_array_equal(got, color if encoding == 'bgr8' else color[..., ::-1])


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = bag_convert.main([*argv, '--quiet'])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope='module')
def depths() -> list[np.ndarray]:
    return [scene_depth(k) for k in range(4)]


def make_folder(root: Path, depths: list[np.ndarray], *, with_color: bool = True) -> Path:
    (root / 'depth').mkdir(parents=True)
    if with_color:
        (root / 'color').mkdir()
    for k, depth in enumerate(depths):
        cv2.imwrite(str(root / 'depth' / f'frame_{k:04d}.png'), depth)
        if with_color:
            cv2.imwrite(str(root / 'color' / f'frame_{k:04d}.png'), fake_color(depth, k))
    return root


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_folder_round_trip(tmp_path: Path, depths: list[np.ndarray], storage: str,
                           capsys: pytest.CaptureFixture[str]) -> None:
    root = make_folder(tmp_path / 'data', depths)
    yaml_path = write_intrinsics(tmp_path / 'camera.yaml')
    bag = tmp_path / 'out'
    code, out, _ = run(['folder', str(root / 'depth'), str(bag), '--color-dir',
                        str(root / 'color'), '--intrinsics', str(yaml_path), '--rate', '10',
                        '--start-time', '100', '--storage', storage], capsys)
    assert code == 0
    assert 'frames: 4 depth' in out
    assert [p.suffix for p in bag.iterdir() if p.name != 'metadata.yaml'] == [
        {'sqlite3': '.db3', 'mcap': '.mcap'}[storage]]
    stamps = [100_000_000_000 + k * 100_000_000 for k in range(4)]
    colors = [fake_color(d, k) for k, d in enumerate(depths)]
    check_frames(bag, depths, stamps, colors=colors)
    assert not list(tmp_path.glob('.*partial*'))


def make_diml(seq: Path, depths: list[np.ndarray], numbers: list[int]) -> None:
    """Write a DIML/CVL sequence folder: col, raw_png, up_png, warp_png, the release's names."""
    for folder in ('col', 'raw_png', 'up_png', 'warp_png'):
        (seq / folder).mkdir(parents=True)
    for k, (depth, n) in enumerate(zip(depths, numbers)):
        stem = f'in_k_03_170201_{n:06d}'
        cv2.imwrite(str(seq / 'raw_png' / f'{stem}_rd.png'), depth)
        cv2.imwrite(str(seq / 'up_png' / f'{stem}_ud.png'), depth + 1)
        cv2.imwrite(str(seq / 'warp_png' / f'{stem}_wd.png'), depth + 2)
        cv2.imwrite(str(seq / 'col' / f'{stem}_c.png'), fake_color(depth, k))


@pytest.mark.parametrize(('kind', 'offset'), [('raw', 0), ('up', 1), ('warp', 2)])
def test_diml_sequence(tmp_path: Path, depths: list[np.ndarray], kind: str, offset: int,
                       capsys: pytest.CaptureFixture[str]) -> None:
    numbers = [630, 631, 633, 634]  # 632 is missing: the stamps keep the gap
    seq = tmp_path / 'office' / '170201' / '3'
    make_diml(seq, depths, numbers)
    bag = tmp_path / 'out'
    code, _, err = run(['diml', str(seq), str(bag), '--depth', kind, '--intrinsics',
                        str(write_intrinsics(tmp_path / 'k.yaml'))], capsys)
    assert code == 0
    assert 'warning' not in err
    stamps = [round(n / 30.0 * 1e9) for n in numbers]
    check_frames(bag, [d + offset for d in depths], stamps,
                 colors=[fake_color(d, k) for k, d in enumerate(depths)])


def test_diml_without_intrinsics_warns_and_uses_kinect_defaults(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(7)
    depths = [rng.integers(0, 8000, size=(424, 512), dtype=np.uint16) for _ in range(2)]
    seq = tmp_path / 'seq'
    make_diml(seq, depths, [1, 2])
    bag = tmp_path / 'out'
    code, _, err = run(['diml', str(seq), str(bag), '--no-color', '--rate', '15'], capsys)
    assert code == 0
    assert 'warning: no intrinsics given' in err
    assert 'Kinect v2 depth camera defaults' in err
    check_frames(bag, depths, [round(1e9 / 15), round(2e9 / 15)], intr=KINECT_V2_SD)


def make_tum(root: Path, depths: list[np.ndarray]) -> tuple[list[np.ndarray], list[int]]:
    """Return a TUM-format sequence: depth in 5000 units/m; colour 10 ms later, none for frame 2.

    Returns the expected depth in millimetres and the expected stamps [ns].
    """
    (root / 'rgb').mkdir(parents=True)
    (root / 'depth').mkdir()
    t0 = 1305031102.160407
    depth_lines = ['# depth maps', '# file: test', '# timestamp filename']
    rgb_lines = ['# color images', '# file: test', '# timestamp filename']
    expected, stamps = [], []
    for k, depth in enumerate(depths):
        t = t0 + k / 30.0
        units = (depth.astype(np.uint32) * 5 + np.arange(depth.size).reshape(depth.shape) % 5)
        units = np.minimum(units, 65535).astype(np.uint16)
        cv2.imwrite(str(root / 'depth' / f'{t:.6f}.png'), units)
        depth_lines.append(f'{t:.6f} depth/{t:.6f}.png')
        if k != 2:  # frame 2's colour image is missing: no colour within 0.02 s of it
            tc = t + 0.010
            cv2.imwrite(str(root / 'rgb' / f'{tc:.6f}.png'), fake_color(depth, k))
            rgb_lines.append(f'{tc:.6f} rgb/{tc:.6f}.png')
        expected.append(np.round(units / 5.0).astype(np.uint16))
        stamps.append(round(float(f'{t:.6f}') * 1e9))
    (root / 'depth.txt').write_text('\n'.join(depth_lines) + '\n')
    (root / 'rgb.txt').write_text('\n'.join(rgb_lines) + '\n')
    return expected, stamps


def test_tum_sequence(tmp_path: Path, depths: list[np.ndarray],
                      capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / 'rgbd_dataset_freiburg2_desk'
    expected, stamps = make_tum(root, depths)
    bag = tmp_path / 'out'
    code, out, _ = run(['tum', str(root), str(bag), '--storage', 'mcap'], capsys)
    assert code == 0
    assert 'dropped pairs: 1' in out
    assert 'no colour frame within 0.02 s' in out
    colors = [fake_color(d, k) if k != 2 else None for k, d in enumerate(depths)]
    check_frames(bag, expected, stamps, colors=colors, intr=datasets.TUM_CAMERAS['fr2'])


def test_tum_camera_option(tmp_path: Path, depths: list[np.ndarray],
                           capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / 'seq'
    expected, stamps = make_tum(root, depths[:2])
    bag = tmp_path / 'out'
    code, _, _ = run(['tum', str(root), str(bag), '--camera', 'fr1', '--no-color'], capsys)
    assert code == 0
    check_frames(bag, expected, stamps, intr=Intrinsics(517.3, 516.5, 318.6, 255.3))


def test_ros1_kinect2_bag(tmp_path: Path, depths: list[np.ndarray],
                          capsys: pytest.CaptureFixture[str]) -> None:
    noetic = get_typestore(Stores.ROS1_NOETIC)
    Img = noetic.types['sensor_msgs/msg/Image']
    Info = noetic.types['sensor_msgs/msg/CameraInfo']
    Header = noetic.types['std_msgs/msg/Header']
    Time = noetic.types['builtin_interfaces/msg/Time']
    Roi = noetic.types['sensor_msgs/msg/RegionOfInterest']
    src = tmp_path / 'kinect2.bag'
    stamps = [1_600_000_000_000_000_000 + k * 33_333_333 for k in range(len(depths))]
    d = np.array([0.09, -0.27, 0.0, 0.0, 0.1])
    k_matrix = np.array([365.5, 0, 255.5, 0, 366.0, 211.5, 0, 0, 1])
    p_matrix = np.array([365.5, 0, 255.5, 0, 0, 366.0, 211.5, 0, 0, 0, 1, 0])
    with Writer1(src) as writer:
        topics = {name: writer.add_connection(name, typ, typestore=noetic) for name, typ in (
            ('/kinect2/sd/image_depth_rect', Img.__msgtype__),
            ('/kinect2/sd/camera_info', Info.__msgtype__),
            ('/kinect2/sd/image_color_rect', Img.__msgtype__),
            ('/tf_static_like', 'std_msgs/msg/String'))}
        for k, (depth, stamp) in enumerate(zip(depths, stamps)):
            header = Header(seq=k, stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9),
                            frame_id='kinect2_ir_optical_frame')
            h, w = depth.shape
            depth_msg = Img(header=header, height=h, width=w, encoding='16UC1', is_bigendian=0,
                            step=2 * w, data=depth.view(np.uint8).reshape(-1))
            color = fake_color(depth, k)
            color_msg = Img(header=header, height=h, width=w, encoding='bgr8', is_bigendian=0,
                            step=3 * w, data=color.reshape(-1))
            info = Info(header=header, height=h, width=w, distortion_model='plumb_bob', D=d,
                        K=k_matrix, R=np.eye(3).ravel(), P=p_matrix, binning_x=0, binning_y=0,
                        roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
            for topic, msg in (('/kinect2/sd/camera_info', info),
                               ('/kinect2/sd/image_depth_rect', depth_msg),
                               ('/kinect2/sd/image_color_rect', color_msg)):
                writer.write(topics[topic], stamp + k, noetic.serialize_ros1(msg, msg.__msgtype__))
        string = noetic.types['std_msgs/msg/String'](data='hello')
        writer.write(topics['/tf_static_like'], stamps[0],
                     noetic.serialize_ros1(string, 'std_msgs/msg/String'))

    bag = tmp_path / 'out'
    code, out, _ = run(['ros1', str(src), str(bag)], capsys)
    assert code == 0
    assert '/kinect2/sd/image_depth_rect: 4 messages' in out
    got = read_bag(bag)
    assert sorted(got) == sorted(topics)
    for k, depth in enumerate(depths):
        t, depth_msg = got['/kinect2/sd/image_depth_rect'][k]
        _, info = got['/kinect2/sd/camera_info'][k]
        _, color_msg = got['/kinect2/sd/image_color_rect'][k]
        assert t == stamps[k] + k
        for msg in (depth_msg, info, color_msg):
            assert stamp_of(msg) == stamps[k]
            assert msg.header.frame_id == 'kinect2_ir_optical_frame'
        np.testing.assert_array_equal(image_to_array(depth_msg), depth)
        np.testing.assert_array_equal(np.asarray(color_msg.data).reshape(depth.shape + (3,)),
                                      fake_color(depth, k))
        np.testing.assert_allclose(info.k, k_matrix)
        np.testing.assert_allclose(info.p, p_matrix)
        np.testing.assert_allclose(info.d, d)
        np.testing.assert_allclose(info.r, np.eye(3).ravel())
    assert got['/tf_static_like'][0][1].data == 'hello'


def test_ros1_topic_selection(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    noetic = get_typestore(Stores.ROS1_NOETIC)
    src = tmp_path / 'two.bag'
    with Writer1(src) as writer:
        a = writer.add_connection('/a', 'std_msgs/msg/String', typestore=noetic)
        b = writer.add_connection('/b', 'std_msgs/msg/String', typestore=noetic)
        for conn in (a, b):
            msg = noetic.types['std_msgs/msg/String'](data=conn.topic)
            writer.write(conn, 5, noetic.serialize_ros1(msg, 'std_msgs/msg/String'))
    code, _, _ = run(['ros1', str(src), str(tmp_path / 'out'), '--topics', '/b'], capsys)
    assert code == 0
    assert sorted(read_bag(tmp_path / 'out')) == ['/b']
    code, _, err = run(['ros1', str(src), str(tmp_path / 'out2'), '--topics', '/c'], capsys)
    assert code == 1
    assert '/c' in err


# -------------------------------------------------------------------------------------------
# ROS 1 bags with compressed depth (iai_kinect2's .../compressed, image_transport's
# .../compressedDepth)

KINECT2_DEPTH = '/kinect2/sd/image_depth_rect'
KINECT2_INFO = '/kinect2/sd/camera_info'
ROS1_T0_NS = 1_600_000_000_000_000_000


def iai_tiff(depth: np.ndarray) -> tuple[str, bytes]:
    """iai_kinect2's depth/compressed with its default use_png: false: header + TIFF."""
    return '16UC1; compressedDepth', struct.pack('<iff', 0, 0.0, 0.0) + cv2.imencode(
        '.tif', depth)[1].tobytes()


def compressed_depth_png(depth: np.ndarray) -> tuple[str, bytes]:
    """compressed_depth_image_transport's depth/compressedDepth: header + PNG."""
    msg = array_to_compressed_depth(depth, RclTime(), 'f')
    return msg.format, bytes(msg.data)


def write_ros1_kinect2(path: Path, depths: list[np.ndarray], intr: Intrinsics, *,
                       depth_topic: str = KINECT2_DEPTH,
                       compress: Callable[[np.ndarray], tuple[str, bytes]] | None = None,
                       jpeg_color: bool = False) -> list[int]:
    """Write a ROS 1 bag as kinect2_bridge records it; return the frames' stamps [ns].

    Per frame a CameraInfo and the depth: a raw 16UC1 Image, or with ``compress`` a
    CompressedImage of (format, data) = compress(depth); ``jpeg_color`` adds a colour
    CompressedImage (bgr8 jpeg).
    """
    noetic = get_typestore(Stores.ROS1_NOETIC)
    types = noetic.types
    header_t, time_t = types['std_msgs/msg/Header'], types['builtin_interfaces/msg/Time']
    stamps = [ROS1_T0_NS + k * 33_333_333 for k in range(len(depths))]
    k_matrix = np.array([intr.fx, 0, intr.cx, 0, intr.fy, intr.cy, 0, 0, 1])
    p_matrix = np.array([intr.fx, 0, intr.cx, 0, 0, intr.fy, intr.cy, 0, 0, 0, 1, 0])
    with Writer1(path) as writer:
        def conn(topic: str, msgtype: str) -> object:
            return writer.add_connection(topic, msgtype, typestore=noetic)
        info_c = conn(KINECT2_INFO, 'sensor_msgs/msg/CameraInfo')
        depth_c = conn(depth_topic, 'sensor_msgs/msg/CompressedImage' if compress
                       else 'sensor_msgs/msg/Image')
        color_c = conn('/kinect2/sd/image_color_rect/compressed',
                       'sensor_msgs/msg/CompressedImage') if jpeg_color else None
        for k, (depth, stamp) in enumerate(zip(depths, stamps)):
            header = header_t(seq=k, stamp=time_t(sec=stamp // 10**9, nanosec=stamp % 10**9),
                              frame_id='kinect2_ir_optical_frame')
            h, w = depth.shape
            raw = types['sensor_msgs/msg/Image'](
                header=header, height=h, width=w, encoding='16UC1', is_bigendian=0, step=2 * w,
                data=depth.view(np.uint8).reshape(-1))
            info = types['sensor_msgs/msg/CameraInfo'](
                header=header, height=h, width=w, distortion_model='plumb_bob', D=np.zeros(5),
                K=k_matrix, R=np.eye(3).ravel(), P=p_matrix, binning_x=0, binning_y=0,
                roi=types['sensor_msgs/msg/RegionOfInterest'](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
            items = [(info_c, info)]
            if compress is None:
                items.append((depth_c, raw))
            else:
                fmt, data = compress(depth)
                items.append((depth_c, types['sensor_msgs/msg/CompressedImage'](
                    header=header, format=fmt, data=np.frombuffer(data, np.uint8))))
            if color_c is not None:
                jpeg = cv2.imencode('.jpg', fake_color(depth, k))[1].reshape(-1)
                items.append((color_c, types['sensor_msgs/msg/CompressedImage'](
                    header=header, format='bgr8; jpeg compressed bgr8', data=jpeg)))
            for c, msg in items:
                writer.write(c, stamp, noetic.serialize_ros1(msg, msg.__msgtype__))
    return stamps


@pytest.mark.parametrize(('suffix', 'compress'), [
    ('compressed', iai_tiff), ('compressedDepth', compressed_depth_png)])
def test_ros1_compressed_depth_is_kept(
        tmp_path: Path, depths: list[np.ndarray], suffix: str,
        compress: Callable[[np.ndarray], tuple[str, bytes]],
        capsys: pytest.CaptureFixture[str]) -> None:
    topic = f'{KINECT2_DEPTH}/{suffix}'
    stamps = write_ros1_kinect2(tmp_path / 'k.bag', depths, INTR, depth_topic=topic,
                                compress=compress, jpeg_color=True)

    code, out, _ = run(['ros1', str(tmp_path / 'k.bag'), str(tmp_path / 'out')], capsys)

    assert code == 0
    got = read_bag(tmp_path / 'out')
    assert KINECT2_DEPTH not in got
    assert [t for t, _ in got[topic]] == stamps
    for (_, msg), depth in zip(got[topic], depths, strict=True):
        np.testing.assert_array_equal(compressed_depth_to_array(msg), depth)


# -------------------------------------------------------------------------------------------
# Bad input: exit code 1, a message naming the file, nothing left at the output.


def bad_depth_8bit(root: Path) -> tuple[list[str], Path]:
    make_folder(root, [scene_depth(0), scene_depth(1)], with_color=False)
    bad = root / 'depth' / 'frame_0001.png'
    cv2.imwrite(str(bad), (scene_depth(1) // 50).astype(np.uint8))
    return ['folder', str(root / 'depth')], bad


def bad_depth_unreadable(root: Path) -> tuple[list[str], Path]:
    make_folder(root, [scene_depth(0), scene_depth(1)], with_color=False)
    bad = root / 'depth' / 'frame_0001.png'
    bad.write_text('not a png')
    return ['folder', str(root / 'depth')], bad


def bad_depth_colour_image(root: Path) -> tuple[list[str], Path]:
    make_folder(root, [scene_depth(0)], with_color=False)
    bad = root / 'depth' / 'frame_0000.png'
    cv2.imwrite(str(bad), np.zeros((4, 4, 3), np.uint16))
    return ['folder', str(root / 'depth')], bad


def bad_size_change(root: Path) -> tuple[list[str], Path]:
    make_folder(root, [scene_depth(0), scene_depth(1)], with_color=False)
    bad = root / 'depth' / 'frame_0001.png'
    cv2.imwrite(str(bad), np.ones((10, 10), np.uint16))
    return ['folder', str(root / 'depth')], bad


def bad_count_mismatch(root: Path) -> tuple[list[str], Path]:
    make_folder(root, [scene_depth(0), scene_depth(1)])
    (root / 'color' / 'frame_0001.png').unlink()
    return ['folder', str(root / 'depth'), '--color-dir', str(root / 'color')], root / 'color'


def bad_missing_folder(root: Path) -> tuple[list[str], Path]:
    return ['folder', str(root / 'nowhere')], root / 'nowhere'


def bad_diml_count_mismatch(root: Path) -> tuple[list[str], Path]:
    make_diml(root, [scene_depth(0), scene_depth(1)], [1, 2])
    (root / 'col' / 'in_k_03_170201_000002_c.png').unlink()
    return ['diml', str(root)], root / 'col'


def bad_diml_not_a_sequence(root: Path) -> tuple[list[str], Path]:
    make_diml(root / '170201' / '1', [scene_depth(0)], [1])
    return ['diml', str(root)], root / 'raw_png'


def bad_tum_missing_list(root: Path) -> tuple[list[str], Path]:
    root.mkdir()
    return ['tum', str(root)], root / 'depth.txt'


def bad_tum_missing_image(root: Path) -> tuple[list[str], Path]:
    make_tum(root, [scene_depth(0), scene_depth(1)])
    bad = next((root / 'depth').iterdir())
    bad.unlink()
    return ['tum', str(root), '--camera', 'fr1'], bad


def bad_intrinsics_yaml(root: Path) -> tuple[list[str], Path]:
    make_folder(root, [scene_depth(0)], with_color=False)
    bad = root / 'camera.yaml'
    bad.write_text('fx: 60\nfy: 60\ncx: 40\n')
    return ['folder', str(root / 'depth'), '--intrinsics', str(bad)], bad


def bad_intrinsics_size(root: Path) -> tuple[list[str], Path]:
    make_folder(root, [scene_depth(0)], with_color=False)
    bad = write_intrinsics(root / 'camera.yaml', size=(640, 480))
    return ['folder', str(root / 'depth'), '--intrinsics', str(bad)], bad


def bad_ros1_not_a_bag(root: Path) -> tuple[list[str], Path]:
    root.mkdir()
    bad = root / 'x.bag'
    bad.write_bytes(b'#ROSBAG V1.0\n')
    return ['ros1', str(bad)], bad


@pytest.mark.parametrize('make_bad', [
    bad_depth_8bit, bad_depth_unreadable, bad_depth_colour_image, bad_size_change,
    bad_count_mismatch, bad_missing_folder, bad_diml_count_mismatch, bad_diml_not_a_sequence,
    bad_tum_missing_list, bad_tum_missing_image, bad_intrinsics_yaml, bad_intrinsics_size,
    bad_ros1_not_a_bag])
def test_bad_input_fails_cleanly(tmp_path: Path, make_bad, capsys: pytest.CaptureFixture[str]
                                 ) -> None:
    args, named = make_bad(tmp_path / 'data')
    bag = tmp_path / 'out' / 'bag'
    code, _, err = run([*args, str(bag)], capsys)
    assert code == 1
    assert str(named) in err
    assert err.startswith('error: ') or 'error: ' in err
    assert not bag.exists()
    assert not list((tmp_path / 'out').glob('*')) if (tmp_path / 'out').exists() else True


def test_existing_output_is_not_touched(tmp_path: Path, depths: list[np.ndarray],
                                        capsys: pytest.CaptureFixture[str]) -> None:
    root = make_folder(tmp_path / 'data', depths[:1], with_color=False)
    bag = tmp_path / 'out'
    bag.mkdir()
    (bag / 'keep.txt').write_text('mine')
    code, _, err = run(['folder', str(root / 'depth'), str(bag)], capsys)
    assert code == 1
    assert str(bag) in err and 'exists' in err
    assert [p.name for p in bag.iterdir()] == ['keep.txt']


def test_load_intrinsics_formats(tmp_path: Path) -> None:
    ros = tmp_path / 'ros.yaml'
    ros.write_text('image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n'
                   '  data: [500.0, 0.0, 320.0, 0.0, 501.0, 240.0, 0.0, 0.0, 1.0]\n')
    eth3d = tmp_path / 'calibration.txt'
    eth3d.write_text('726.28 726.28 354.64 186.46\n')
    assert datasets.load_intrinsics(ros) == (Intrinsics(500.0, 501.0, 320.0, 240.0),
                                                (640, 480))
    assert datasets.load_intrinsics(eth3d) == (Intrinsics(726.28, 726.28, 354.64, 186.46),
                                                  None)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('fx: 0\nfy: 1\ncx: 1\ncy: 1\n')
    with pytest.raises(datasets.EvaluationError, match='bad.yaml'):
        datasets.load_intrinsics(bad)


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_is_quiet_off_a_terminal_except_the_final_line() -> None:
    stream = io.StringIO()
    with Progress(3, 'work', stream=stream) as bar:
        for _ in range(3):
            bar.update()
            assert stream.getvalue() == ''
    assert stream.getvalue().startswith('work [') and stream.getvalue().count('\n') == 1
    assert '3/3' in stream.getvalue()


def test_progress_redraws_on_a_terminal_and_marks_a_stop() -> None:
    stream = _Tty()
    with pytest.raises(RuntimeError), Progress(2, 'work', stream=stream) as bar:
        bar.update()
        raise RuntimeError('boom')
    text = stream.getvalue()
    assert text.startswith('\rwork [') and '1/2' in text and text.endswith('(stopped)\n')


def test_frames_with_a_pose_carry_odometry_and_the_processor_keeps_it(
        tmp_path: Path, depths: list[np.ndarray]) -> None:
    import dataclasses
    import math

    from nav_msgs.msg import Odometry

    from obstacle_detection.tools import bag_process

    root = make_folder(tmp_path / 'data', depths, with_color=False)
    source = datasets.folder_frames(root / 'depth', intrinsics_path=write_intrinsics(
        tmp_path / 'camera.yaml'), rate_hz=10.0, start_s=100.0)
    poses = [(0.1 * k, -0.05 * k, math.radians(10.0 * k)) for k in range(len(depths))]
    source.frames = [dataclasses.replace(f, pose=p) for f, p in zip(source.frames, poses)]
    summary = bag_writer.write_frames(source, tmp_path / 'bag',
                                       bag_writer.BagOptions(progress=False))
    assert summary.topics['/odom'] == len(depths)

    def odometry(bag: Path) -> list[tuple[int, tuple[float, float, float]]]:
        with Reader(bag) as reader:
            conns = [c for c in reader.connections if c.topic == '/odom']
            out = []
            for _, stamp, raw in reader.messages(connections=conns):
                msg = deserialize_message(bytes(raw), Odometry)
                q = msg.pose.pose.orientation
                out.append((stamp, (msg.pose.pose.position.x, msg.pose.pose.position.y,
                                    2.0 * math.atan2(q.z, q.w))))
            return out

    written = odometry(tmp_path / 'bag')
    assert [s for s, _ in written] == [100_000_000_000 + k * 100_000_000 for k in range(4)]
    for (_, got), want in zip(written, poses):
        assert got == pytest.approx(want, abs=1e-12)
    assert bag_process.main([str(tmp_path / 'bag'), str(tmp_path / 'processed'),
                             '--quiet']) == 0
    assert odometry(tmp_path / 'processed') == written


def tum_units(depth_mm: np.ndarray) -> np.ndarray:
    """Depth [mm] in TUM's 5000 units/m, with sub-millimetre remainders."""
    remainder = np.arange(depth_mm.size).reshape(depth_mm.shape) % 5
    return np.minimum(depth_mm.astype(np.uint32) * 5 + remainder * (depth_mm > 0),
                      65535).astype(np.uint16)


def write_pngs(folder: Path, images: list[np.ndarray], name: str = 'frame_{:04d}.png') -> Path:
    folder.mkdir(parents=True)
    for k, image in enumerate(images):
        cv2.imwrite(str(folder / name.format(k)), image)
    return folder


def test_folder_states_the_default_depth_unit(tmp_path: Path, depths: list[np.ndarray],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    folder = write_pngs(tmp_path / 'depth', depths[:2])
    code, out, _ = run(['folder', str(folder), str(tmp_path / 'out'), '--intrinsics',
                        str(write_intrinsics(tmp_path / 'k.yaml'))], capsys)
    assert code == 0
    assert 'depth read at 1000 units/m (millimetres, the default; --depth-scale' in out
    check_frames(tmp_path / 'out', depths[:2], [0, 33_333_333])


def test_folder_of_tum_frames_converts_with_depth_scale(tmp_path: Path, depths: list[np.ndarray],
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    folder = write_pngs(tmp_path / 'depth', [tum_units(d) for d in depths[:2]])
    code, out, err = run(['folder', str(folder), str(tmp_path / 'out'), '--depth-scale', '5000',
                          '--intrinsics', str(write_intrinsics(tmp_path / 'k.yaml'))], capsys)
    assert code == 0, err
    assert 'depth read at 5000 units/m (--depth-scale)' in out
    # 5 units of 0.2 mm a millimetre, rounded to the nearest
    expected = [np.floor(tum_units(d) / 5.0 + 0.5).astype(np.uint16) for d in depths[:2]]
    check_frames(tmp_path / 'out', expected, [0, 33_333_333])


@pytest.mark.parametrize('frame', ['office', 'desk'])
def test_folder_of_tum_frames_without_depth_scale_is_refused(
        tmp_path: Path, frame: str, capsys: pytest.CaptureFixture[str]) -> None:
    # as ../shared/data/real/tum_office and tum_fr2_desk
    if frame == 'office':  # 2.4 m away, 12 m read as millimetres; some pixels no return
        image = np.full((60, 80), 12000, np.uint16)
        image[::7] = 0
    else:  # a desk at 1.5 m (7.5 m as mm, plausible) before a hall at 4 m (20 m as mm)
        image = np.full((60, 80), 7500, np.uint16)
        image[:8] = 20000
    folder = write_pngs(tmp_path / 'depth', [image])
    code, out, err = run(['folder', str(folder), str(tmp_path / 'out')], capsys)
    assert code == 1 and out == ''
    assert err.count('\n') == 1 and err.startswith(f'error: {folder / "frame_0000.png"}: ')
    assert '--depth-scale 5000 (TUM RGB-D format' in err
    assert not (tmp_path / 'out').exists() and not list(tmp_path.glob('.out*'))


def test_tum_without_lists_takes_the_stamps_from_the_file_names(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / 'seq'
    expected, stamps = make_tum(root, depths[:3])
    (root / 'depth.txt').unlink()
    (root / 'rgb.txt').unlink()
    code, out, err = run(['tum', str(root), str(tmp_path / 'out'), '--camera', 'fr2'], capsys)
    assert code == 0, err
    assert 'depth frames listed from the timestamps in the file names' in out
    colors = [fake_color(d, k) if k != 2 else None for k, d in enumerate(depths[:3])]
    check_frames(tmp_path / 'out', expected, stamps, colors=colors,
                 intr=datasets.TUM_CAMERAS['fr2'])


def test_tum_without_lists_or_stamped_names_says_what_to_write(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    # the layout of ../shared/data/real/tum_fr2_desk: depth_N.png and color_N.png side by side
    root = write_pngs(tmp_path / 'desk', [tum_units(d) for d in depths[:2]], 'depth_{}.png')
    cv2.imwrite(str(root / 'color_0.png'), fake_color(depths[0], 0))
    code, out, err = run(['tum', str(root), str(tmp_path / 'out')], capsys)
    assert code == 1 and out == ''
    assert err.count('\n') == 1
    assert err.startswith(f'error: {root / "depth.txt"}: not found')
    assert 'one "timestamp filename" line per depth image' in err
    assert 'rgb.txt likewise' in err and '--no-color' in err
    assert not (tmp_path / 'out').exists()


# --- The real frames of ../shared/data/real, converted as they ship -------------------------

#: ../shared/data/real beside the clone (CI keeps a copy of shared/ there).
REAL_DIR = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'real'
#: folder -> (depth files, colour files, extra options): the README of the real frames.
REAL = {
    'tum_office': (['depth.png'], ['color.png'],
                   ['--depth-scale', '5000', '--intrinsics', '535.4,539.2,320.1,247.6']),
    'tum_fr2_desk': (['depth_1.png', 'depth_2.png'], ['color_1.png', 'color_2.png'],
                     ['--depth-scale', '5000', '--intrinsics', '520.9,521.0,325.1,249.7']),
    'dining_room': ([f'depth_{i}.pgm' for i in range(1, 6)],
                    [f'color_{i}.png' for i in range(1, 6)],
                    ['--intrinsics', '518.0,519.0,325.5,253.5']),
}


@pytest.mark.parametrize('name', sorted(REAL))
def test_the_real_frames_convert_as_they_ship(name: str, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    # depth and colour side by side in one folder, PNG (TUM units) or PGM (mm): no splitting,
    # no converting by hand
    if not (REAL_DIR / name).is_dir():
        pytest.skip(f'no real frames at {REAL_DIR / name} (../shared beside the clone)')
    depth_files, color_files, options = REAL[name]
    code, out, err = run(['folder', str(REAL_DIR / name), str(tmp_path / 'out'), *options],
                         capsys)
    assert code == 0, err
    units = 5000.0 if '--depth-scale' in options else 1000.0
    depths = [cv2.imread(str(REAL_DIR / name / f), cv2.IMREAD_UNCHANGED) for f in depth_files]
    want = [np.floor(d * (1000.0 / units) + 0.5).astype(np.uint16) for d in depths]
    colors = [cv2.imread(str(REAL_DIR / name / f), cv2.IMREAD_COLOR) for f in color_files]
    fx, fy, cx, cy = (float(v) for v in options[options.index('--intrinsics') + 1].split(','))
    check_frames(tmp_path / 'out', want, [round(k * 1e9 / 30) for k in range(len(want))],
                 colors=colors, intr=Intrinsics(fx, fy, cx, cy))
    assert f'frames: {len(want)} depth (640x480' in out


def test_a_folder_mixing_depth_and_colour_pairs_them_by_name(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    folder = write_pngs(tmp_path / 'rec', depths[:3], 'depth_{}.pgm')
    colors = [fake_color(d, k) for k, d in enumerate(depths[:3])]
    for k, color in enumerate(colors):
        cv2.imwrite(str(folder / f'color_{k}.png'), color)
    code, out, err = run(['folder', str(folder), str(tmp_path / 'out'), '--intrinsics',
                          str(write_intrinsics(tmp_path / 'k.yaml'))], capsys)
    assert code == 0, err
    check_frames(tmp_path / 'out', depths[:3], [0, 33_333_333, 66_666_667], colors=colors)


def test_a_colour_image_given_as_depth_says_what_the_folder_must_hold(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    folder = write_pngs(tmp_path / 'rgb', [fake_color(depths[0], 0)])
    code, out, err = run(['folder', str(folder), str(tmp_path / 'out')], capsys)
    assert code == 1 and out == ''
    assert err.count('\n') == 1
    assert err.startswith(f'error: {folder / "frame_0000.png"}: a colour image (8-bit, 3 '
                          'channels), not 16-bit depth')
    assert 'depth_N.png' in err and '--color-dir' in err
    assert not (tmp_path / 'out').exists()


def test_tum_on_a_folder_of_loose_frames_points_to_folder(
        tmp_path: Path, depths: list[np.ndarray], capsys: pytest.CaptureFixture[str]) -> None:
    root = write_pngs(tmp_path / 'desk', [tum_units(d) for d in depths[:2]], 'depth_{}.png')
    code, out, err = run(['tum', str(root), str(tmp_path / 'out')], capsys)
    assert code == 1 and err.count('\n') == 1
    assert f'bag_convert folder {root} OUTPUT --depth-scale 5000' in err


# --- ros1 given a rosbag2 bag ----------------------------------------------------------------


@pytest.fixture()
def rosbag2(tmp_path: Path, depths: list[np.ndarray]) -> Path:
    """Return a converted rosbag2 bag (sqlite3) of two frames."""
    folder = make_folder(tmp_path / 'frames', depths[:2], with_color=False)
    code = bag_convert.main(['folder', str(folder / 'depth'), str(tmp_path / 'bag2'), '--quiet',
                             '--intrinsics', str(write_intrinsics(tmp_path / 'k.yaml'))])
    assert code == 0
    return tmp_path / 'bag2'


def test_ros1_given_a_rosbag2_folder_says_it_needs_no_conversion(
        rosbag2: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(['ros1', str(rosbag2), str(tmp_path / 'out')], capsys)
    assert code == 1 and out == ''
    assert err == (f'error: {rosbag2}: a rosbag2 bag, not a ROS 1 bag: it needs no conversion '
                   '(bag_play, bag_process and pictures --bag read it)\n')
    assert not (tmp_path / 'out').exists()


def test_ros1_given_a_rosbag2_storage_file_is_refused(
        rosbag2: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db3 = next(rosbag2.glob('*.db3'))
    code, out, err = run(['ros1', str(db3), str(tmp_path / 'out')], capsys)
    assert code == 1 and out == ''
    assert err == (f'error: {db3}: a rosbag2 storage file, not a ROS 1 bag: its folder '
                   f'{rosbag2} is a rosbag2 bag already and needs no conversion (bag_play, '
                   'bag_process and pictures --bag read it)\n')
    assert not (tmp_path / 'out').exists()


def test_ros1_given_another_file_is_refused(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / 'notes.bag').write_text('hello')
    code, out, err = run(['ros1', str(tmp_path / 'notes.bag'), str(tmp_path / 'out')], capsys)
    assert code == 1
    assert err == (f'error: {tmp_path / "notes.bag"}: not a ROS 1 bag (no "#ROSBAG V2.0" '
                   'header)\n')


def test_help_texts_hold_no_internal_words(capsys: pytest.CaptureFixture[str]) -> None:
    for source in ('tum', 'diml', 'folder', 'ros1'):
        with pytest.raises(SystemExit):
            bag_convert.main([source, '-h'])
        text = capsys.readouterr().out
        for word in (':func:', 'Error)', 'EvaluationError', '``', 'issue '):
            assert word not in text, (source, word)
