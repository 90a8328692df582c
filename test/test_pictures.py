"""Side-by-side pictures, contact sheets, tools/pictures.py (and its --readme)."""

import argparse
import math
import re

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from obstacle_detection.labels import (CELL_OCCUPIED, CELL_UNKNOWN, LABEL_GROUND, LABEL_OBSTACLE,
                                       LABEL_OUTSIDE_ROI)
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.viz import pictures
from obstacle_detection.pipeline.costmap import Costmap, costmap_geometry
from obstacle_detection.viz.overlay import (NO_RETURN_RGB, OBSTACLE_ALPHA, OBSTACLE_RGB,
                                       OCCUPIED_RGB, ROBOT_RGB, UNKNOWN_RGB, render_overlay)
from obstacle_detection.pipeline.params import (KINECT_V2_SD, KINECT_V2_SD_SIZE, PRESETS,
                                               table_4_2)
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.sim.scenes import render_scene
from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli import picture_jobs
from obstacle_detection.cli import bag_writer
from obstacle_detection.tools import bag_process
from obstacle_detection.tools import pictures as pictures_tool

from eval_helpers import MIN_TEXT_PX, is_obstacle_rgb, text_height_px

SIZE = (160, 132)


@pytest.fixture(scope='module')
def corridor():
    scenario = evaluation.Scenario('corridor', 'corridor', seeds=(0,))
    frame = next(evaluation.scenario_frames(scenario, size=SIZE))
    result = Detector(frame.params(table_4_2())).process(frame.depth, frame.intrinsics)
    return frame, result


def test_overlay_half_has_the_frame_size_and_marks_obstacles(corridor):
    frame, result = corridor
    image = pictures.side_by_side(result, frame.params(table_4_2()), caption='corridor seed 0')
    height, width = frame.depth.shape
    assert image.dtype == np.uint8 and image.shape[0] > height and image.shape[1] > width
    overlay = image[:height, :width]
    np.testing.assert_array_equal(overlay, pictures.depth_overlay(result.depth_m, result.labels))
    obstacle = result.labels == LABEL_OBSTACLE
    assert obstacle.any() and (~obstacle).any()
    assert is_obstacle_rgb(overlay[obstacle]).all()
    # outside the region of interest: the plain depth grey; ground inside it: tinted green
    plain = render_overlay(result.depth_m, result.labels)
    outside = result.labels == LABEL_OUTSIDE_ROI
    ground = result.labels == LABEL_GROUND
    assert outside.any() and ground.any()
    np.testing.assert_array_equal(overlay[outside], plain[outside])
    tint = overlay[ground].astype(int)
    assert (tint[:, 1] > tint[:, 0]).all() and (tint[:, 1] > tint[:, 2]).all()


def test_truth_panel_colours_hits_false_alarms_and_misses():
    labels = np.array([[3, 3, 2, 2]], np.uint8)
    truth = np.array([[2, 1, 2, 1]], np.uint8)
    image = pictures.truth_comparison(labels, truth, np.ones((1, 4), np.float32))
    assert tuple(image[0, 0]) == pictures.HIT_RGB
    assert tuple(image[0, 1]) == pictures.FALSE_ALARM_RGB
    assert tuple(image[0, 2]) == pictures.MISS_RGB
    assert len(set(image[0, 3])) == 1  # grey


def test_png_written_and_read_back(tmp_path, corridor):
    frame, result = corridor
    image = pictures.side_by_side(result, frame.params(table_4_2()), caption='x',
                                  truth_labels=frame.truth_labels)
    path = tmp_path / 'sub' / 'frame.png'
    pictures.write_png(path, image)
    back = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(back, image)


def test_labelled_tile_grid_size():
    images = [np.full((50, 100 - 10 * (i % 2), 3), i * 40, np.uint8) for i in range(5)]
    sheet = pictures.tile(images, labels=[f'#{i}' for i in range(5)], columns=3)
    assert sheet.shape[1] == 3 * (100 + 6)
    assert sheet.shape[0] % 2 == 0 and sheet.shape[0] >= 2 * (50 + 6 + 12)
    # a narrower image is padded white, not stretched; its label under it
    assert (sheet[:50, 106 + 90:106 + 100] == 255).all() and (sheet[50:70, :100] < 128).any()


def test_tool_draws_a_scene_frame(tmp_path, capsys):
    out = tmp_path / 'corridor.png'
    assert pictures_tool.main(['--scene', 'ramps', '--out', str(out)]) == 0
    image = cv2.imread(str(out))
    assert image is not None and image.shape[0] > 424 and image.shape[1] > 512


def test_tool_draws_a_depth_png_with_intrinsics_and_a_mount(tmp_path, corridor, capsys):
    frame, _ = corridor
    cv2.imwrite(str(tmp_path / 'd.png'), frame.depth)
    intr = frame.intrinsics
    out = tmp_path / 'd_out.png'
    assert pictures_tool.main(['--depth', str(tmp_path / 'd.png'), '--intrinsics',
                               f'{intr.fx},{intr.fy},{intr.cx},{intr.cy}', '--set',
                               f'camera_height_m={frame.height_m}', '--out', str(out)]) == 0
    image = cv2.imread(str(out))
    assert image.shape[1] > SIZE[0]
    assert f'mount: height {frame.height_m:.2f} m' in capsys.readouterr().err


def test_tool_needs_out_or_readme(capsys):
    assert pictures_tool.main(['--scene', 'ramps']) == 2
    assert capsys.readouterr().err == ('pictures: error: argument --out is required (except '
                                       'with --readme)\n')


def _write_bag(path, frame, count, depth_topic='/depth', info_topic='/info'):
    store = get_typestore(Stores.ROS2_JAZZY)
    Image = store.types['sensor_msgs/msg/Image']
    Info = store.types['sensor_msgs/msg/CameraInfo']
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']
    Roi = store.types['sensor_msgs/msg/RegionOfInterest']
    height, width = frame.depth.shape
    intr = frame.intrinsics
    with Writer(path, version=9) as writer:
        image_conn = writer.add_connection(depth_topic, Image.__msgtype__, typestore=store)
        info_conn = (writer.add_connection(info_topic, Info.__msgtype__, typestore=store)
                     if info_topic else None)
        for k in range(count):
            header = Header(stamp=Time(sec=k, nanosec=0), frame_id='camera')
            info = Info(header=header, height=height, width=width, distortion_model='plumb_bob',
                        d=np.zeros(5), k=np.array([intr.fx, 0, intr.cx, 0, intr.fy, intr.cy,
                                                   0, 0, 1.0]),
                        r=np.eye(3).reshape(-1), p=np.zeros(12), binning_x=0, binning_y=0,
                        roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
            image = Image(header=header, height=height, width=width, encoding='16UC1',
                          is_bigendian=0, step=2 * width,
                          data=np.frombuffer(frame.depth.astype('<u2').tobytes(), np.uint8))
            stamp = (k + 1) * 10**9
            if info_conn is not None:
                writer.write(info_conn, stamp, store.serialize_cdr(info, Info.__msgtype__))
            writer.write(image_conn, stamp + 1, store.serialize_cdr(image, Image.__msgtype__))


def test_bag_frames_carry_depth_and_camera_info(tmp_path, corridor):
    frame, _ = corridor
    _write_bag(tmp_path / 'bag', frame, 3)
    frames = list(picture_jobs.bag_frames(tmp_path / 'bag', '/depth', '/info',
                                          picture_jobs.parse_frames('0:3:2')))
    assert [name.split(" ")[1].rstrip(",") for name, *_ in frames] == ["#0", "#2"]
    np.testing.assert_array_equal(frames[0][1], frame.depth)
    assert frames[0][2].fx == pytest.approx(frame.intrinsics.fx)


@pytest.mark.parametrize('text', ['0:4:0', '0:4:-1', 'a:b', '1:2:3:4', ''])
def test_frames_option_refuses_what_is_not_a_range(text):
    with pytest.raises(argparse.ArgumentTypeError, match='expected start:stop'):
        picture_jobs.parse_frames(text)


def test_tool_draws_a_contact_sheet_of_a_bag(tmp_path, corridor):
    frame, _ = corridor
    _write_bag(tmp_path / 'bag', frame, 2)
    out = tmp_path / 'sheet.png'
    assert pictures_tool.main(['--bag', str(tmp_path / 'bag'), '--depth-topic', '/depth',
                               '--info-topic', '/info', '--set',
                               f'camera_height_m={frame.height_m}', '--out', str(out)]) == 0
    assert cv2.imread(str(out)).shape[1] == 2 * (picture_jobs.SHEET_THUMB_PX + 6)


def test_tool_says_when_frames_selects_none(tmp_path, corridor, capsys):
    _write_bag(tmp_path / 'bag', corridor[0], 2)
    assert pictures_tool.main(['--bag', str(tmp_path / 'bag'), '--depth-topic', '/depth',
                               '--info-topic', '/info', '--frames', '5:9',
                               '--out', str(tmp_path / 'x.png')]) == 1
    assert capsys.readouterr().err.startswith('error: no frames to draw: --frames selects none')
    assert not (tmp_path / 'x.png').exists()


def test_tool_reports_a_missing_topic(tmp_path, corridor, capsys):
    _write_bag(tmp_path / 'bag', corridor[0], 1)
    assert pictures_tool.main(['--bag', str(tmp_path / 'bag'), '--depth-topic', '/nope',
                               '--out', str(tmp_path / 'x.png')]) == 1
    err = capsys.readouterr().err
    assert err == (f"error: {tmp_path / 'bag'}: no topic '/nope'; its sensor_msgs/msg/Image "
                   'topics: /depth (use --depth-topic)\n')


def test_tool_bag_defaults_are_the_bag_tools_and_camera_info_is_found_by_type(
        tmp_path, corridor, capsys):
    # a bag written by bag_convert has the default depth topic; its CameraInfo topic here has
    # another name: found by its type, not replaced by the seed's Table 4.1 intrinsics
    frame, _ = corridor
    _write_bag(tmp_path / 'bag', frame, 2, depth_topic=tool_support.DEFAULT_DEPTH_TOPIC,
               info_topic='/camera/depth/camera_info')
    args = picture_jobs.build_parser().parse_args(['--bag', str(tmp_path / 'bag'), '--out',
                                                    'x.png'])
    jobs = list(picture_jobs.jobs(args, table_4_2()))
    assert len(jobs) == 2
    assert jobs[0].intrinsics.fx == pytest.approx(frame.intrinsics.fx)
    assert jobs[0].intrinsics.cx == pytest.approx(frame.intrinsics.cx)
    assert any('CameraInfo on /camera/depth/camera_info (found by type' in line
               for line in jobs[0].extra_lines)
    assert bag_writer.DEFAULT_DEPTH_TOPIC == tool_support.DEFAULT_DEPTH_TOPIC
    assert bag_process.build_parser().parse_args(['a', 'b']).depth_topic == \
        args.depth_topic == tool_support.DEFAULT_DEPTH_TOPIC


def test_tool_refuses_a_bag_without_camera_info(tmp_path, corridor, capsys):
    frame, _ = corridor
    _write_bag(tmp_path / 'bag', frame, 1, info_topic=None)
    assert pictures_tool.main(['--bag', str(tmp_path / 'bag'), '--depth-topic', '/depth',
                               '--out', str(tmp_path / 'x.png')]) == 1
    assert capsys.readouterr().err == (f"error: {tmp_path / 'bag'}: no intrinsics: the bag has "
                                       'no CameraInfo topic\n')
    assert not (tmp_path / 'x.png').exists()


def test_tool_bag_path_that_is_not_a_bag_is_one_line(tmp_path, capsys):
    (tmp_path / 'pngs').mkdir()
    assert pictures_tool.main(['--bag', str(tmp_path / 'pngs'), '--out',
                               str(tmp_path / 'x.png')]) == 1
    assert capsys.readouterr().err == (
        f'error: {tmp_path / "pngs"}: not a bag: no metadata.yaml in the folder; expected a '
        'rosbag2 folder (holding metadata.yaml) or a ROS 1 .bag file\n')
    assert not (tmp_path / 'x.png').exists()


@pytest.fixture(scope='module')
def tilted_floor(tmp_path_factory):
    """Write a flat floor seen from a tilted, rolled mount: a 16-bit PNG [mm], its intrinsics."""
    # full size: smaller frames have too few points per voxel for the noise at Table 4.2
    intrinsics = KINECT_V2_SD
    frame = render_scene('flat_floor', height_m=0.9, pitch_rad=math.radians(30),
                         roll_rad=math.radians(4))
    path = tmp_path_factory.mktemp('tilted') / 'floor.png'
    assert cv2.imwrite(str(path), frame.depth_mm)
    return path, ','.join(repr(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                           intrinsics.cy))


def _red_pixels(path, height, width):
    rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    # a one-line title above the panels
    top = pictures.caption_band(['title'], width, scale=pictures.TITLE_SCALE, bold=True).shape[0]
    return int(np.count_nonzero(is_obstacle_rgb(rgb[top:top + height, :width]))), rgb


def test_tool_estimates_the_mount_of_a_depth_png(tmp_path, tilted_floor, capsys):
    depth, intrinsics = tilted_floor
    width, height = KINECT_V2_SD_SIZE
    # the preset's mount is not the camera's: the tilted floor comes out as obstacles
    assert pictures_tool.main(['--depth', str(depth), '--intrinsics', intrinsics,
                               '--out', str(tmp_path / 'preset.png')]) == 0
    red, preset = _red_pixels(tmp_path / 'preset.png', height, width)
    assert red > 200
    # ... and it is said, with what the floor says and the command that estimates the mount
    err = capsys.readouterr().err
    assert re.search(r'warning: the floor in view \(\d+% of the points\) puts the camera at '
                     r'height 0\.90 m, pitch 30\.0 deg, roll 4\.0 deg, but the mount used is '
                     r'height 0\.60 m, pitch 0\.0 deg, roll 0\.0 deg', err)
    assert 'python tools/estimate_mount.py --params-out mount.yaml, then --params-file' in err
    assert "mount: height 0.60 m, pitch 0.0 deg, roll 0.0 deg (the parameters' " \
        '--preset corridor, --params-file, --set); depth 1000 units/m (millimetres, the default' \
        in err
    assert pictures_tool.main(['--depth', str(depth), '--intrinsics', intrinsics,
                               '--estimate-mount', '--out', str(tmp_path / 'est.png')]) == 0
    red, estimated = _red_pixels(tmp_path / 'est.png', height, width)
    assert red == 0
    err = capsys.readouterr().err
    assert 'warning' not in err
    assert 'mount estimated from the floor: h 0.90 m, pitch 30.0 deg, roll 4.0 deg' in err


def test_tool_estimate_is_used_and_in_the_caption(tilted_floor):
    depth, intrinsics = tilted_floor
    args = picture_jobs.build_parser().parse_args(
        ['--depth', str(depth), '--intrinsics', intrinsics, '--estimate-mount',
         '--depth-scale', '1000', '--set', 'camera_height_m=1.2', '--out', 'x.png'])
    job = picture_jobs.depth_job(args, table_4_2())
    assert job.params.camera_height_m == pytest.approx(0.9, abs=0.01)
    assert job.params.camera_pitch_rad == pytest.approx(math.radians(30), abs=0.01)
    assert job.params.camera_roll_rad == pytest.approx(math.radians(4), abs=0.01)
    assert job.depth_scale == 1000.0
    assert job.extra_lines[0].startswith('mount estimated from the floor: h 0.90 m')


def test_tool_depth_needs_intrinsics(tmp_path, tilted_floor, capsys):
    depth, _ = tilted_floor
    assert pictures_tool.main(['--depth', str(depth), '--out', str(tmp_path / 'x.png')]) == 2
    assert '--depth needs --intrinsics FX,FY,CX,CY' in capsys.readouterr().err
    assert not (tmp_path / 'x.png').exists()


def test_tool_reports_a_frame_without_a_floor(tmp_path, tilted_floor, capsys):
    depth, intrinsics = tilted_floor
    assert pictures_tool.main(['--depth', str(depth), '--intrinsics', intrinsics,
                               '--depth-scale', '100', '--estimate-mount',
                               '--out', str(tmp_path / 'x.png')]) == 1  # all beyond 4 m
    err = capsys.readouterr().err
    assert 'cannot estimate the mount: too few points' in err
    assert err.startswith('error: ') and err.count('\n') == 1


def test_readme_pictures_are_made_again(tmp_path, capsys):
    out = tmp_path / 'out'
    assert pictures_tool.main(['--readme', str(out),
                               '--real-dir', str(tmp_path / 'no_such_dir')]) == 0
    corridor = cv2.imread(str(out / 'corridor.png'))
    width, height = KINECT_V2_SD_SIZE
    # overlay, costmap and truth panels over a caption band
    assert corridor.shape[0] > height and corridor.shape[1] > 2 * width + 2 * 6
    assert [p.name for p in out.iterdir()] == ['corridor.png']
    assert 'no real frames' in capsys.readouterr().err


def test_readme_real_pictures_skip_missing_frames(tmp_path, tilted_floor, capsys, monkeypatch):
    monkeypatch.setattr(pictures_tool, 'SYNTHETIC', {})
    real = tmp_path / 'real'
    (real / 'tum_office').mkdir(parents=True)
    depth_mm = cv2.imread(str(tilted_floor[0]), cv2.IMREAD_UNCHANGED)
    tum = np.minimum(depth_mm.astype(np.uint32) * 5, 65535).astype(np.uint16)  # 1/5000 m
    assert cv2.imwrite(str(real / 'tum_office' / 'depth.png'), tum)
    out = tmp_path / 'out'
    assert pictures_tool.main(['--readme', str(out), '--real-dir', str(real)]) == 0
    assert [p.name for p in out.iterdir()] == ['real_tum_office.png']
    image = cv2.imread(str(out / 'real_tum_office.png'))
    assert image.shape[1] == pictures_tool.REAL_WIDTH_PX
    err = capsys.readouterr().err
    assert 'real_tum_fr2_desk.png skipped' in err and 'real_dining_room.png skipped' in err
    assert 'mount estimated from the floor' in err


def test_tool_warns_when_the_depth_looks_like_another_unit(tmp_path, tilted_floor, capsys):
    depth, intrinsics = tilted_floor
    depth_mm = cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)
    tum = np.minimum(depth_mm.astype(np.uint32) * 5, 65535).astype(np.uint16)  # 1/5000 m
    assert cv2.imwrite(str(tmp_path / 'tum.png'), tum)
    assert pictures_tool.main(['--depth', str(tmp_path / 'tum.png'), '--intrinsics', intrinsics,
                               '--out', str(tmp_path / 'x.png')]) == 0
    err = capsys.readouterr().err
    median_m = float(np.median(depth_mm[depth_mm > 0])) / 1000
    assert 'warning: the depth looks like another unit: read at 1000 units/m, 5% of it ' in err
    assert f'--depth-scale 5000 (TUM RGB-D format, 0.2 mm) the median would be {median_m:.2f} m' \
        in err


# --------------------------------------------------------------------------------------------
# Pictures a robotics user reads without the README: metre axes, camera, view, legend


def _empty_costmap(params):
    origin, nx, ny = costmap_geometry(params)
    return Costmap(np.full((ny, nx), CELL_UNKNOWN, np.int8), params.costmap_resolution_m,
                   origin)


def test_costmap_panel_axes_are_in_metres_from_the_camera():
    params = table_4_2()  # 2 m forward, 4 m across, 5 cm cells
    costmap = _empty_costmap(params)
    data = costmap.data.copy()
    ix = int((1.02 - costmap.origin_xy_m[0]) / costmap.resolution_m)
    iy = int((0.52 - costmap.origin_xy_m[1]) / costmap.resolution_m)
    data[iy, ix] = CELL_OCCUPIED  # the cell x 1.00-1.05 m, y 0.50-0.55 m
    costmap = Costmap(data, costmap.resolution_m, costmap.origin_xy_m)
    scale = 5  # 100 px per metre
    panel = pictures.costmap_panel(costmap, scale=scale)
    robot = np.argwhere((panel == ROBOT_RGB).all(axis=-1))
    apex_row = robot[:, 0].min()
    apex_col = int(round(robot[robot[:, 0] == apex_row][:, 1].mean()))
    occupied = np.argwhere((panel == OCCUPIED_RGB).all(axis=-1))
    # the camera marker's apex is the ground-frame origin: the cell lies 1.00 m ahead of it
    # (its near edge) and 0.50 m to its left (its right edge), at 100 px per metre
    assert apex_row - (occupied[:, 0].max() + 1) == 100
    assert apex_col - (occupied[:, 1].max() + 1) == 50
    # ticks every 0.5 m on the forward axis, left of the grid (the grid spans y 2 .. -2 m)
    grid_left = apex_col - 200
    tick_col = grid_left - 4
    for k in range(5):
        assert tuple(panel[apex_row - 50 * k, tick_col]) == pictures.AXIS_RGB
    assert tuple(panel[apex_row - 25, tick_col]) == pictures.BACKGROUND_RGB
    # ... and every metre across, below it (y = 2, 1, -1, -2 m; 0 is under the camera)
    ticks = np.flatnonzero((panel[apex_row + 3] == pictures.AXIS_RGB).all(axis=-1))
    assert {grid_left + 100 * k for k in (0, 1, 3, 4)} <= set(ticks)
    assert grid_left + 50 not in set(ticks)


def test_picture_has_a_legend_for_every_colour(corridor):
    frame, result = corridor
    params = frame.params(table_4_2())
    bare = pictures.side_by_side(result, params, with_legend=False,
                                 truth_labels=frame.truth_labels)
    image = pictures.side_by_side(result, params, truth_labels=frame.truth_labels)
    height = frame.depth.shape[0]
    assert image.shape[0] > bare.shape[0]
    below = image[height:]
    for colour in (*pictures.depth_shades(OBSTACLE_RGB, OBSTACLE_ALPHA),
                   pictures.over_grey(pictures.GROUND_RGB, pictures.GROUND_TINT), NO_RETURN_RGB,
                   OCCUPIED_RGB, UNKNOWN_RGB, ROBOT_RGB, pictures.HIT_RGB,
                   pictures.FALSE_ALARM_RGB, pictures.MISS_RGB):
        assert (below == colour).all(axis=-1).any(), colour


def test_contact_sheet_has_one_legend_under_the_thumbnails(tmp_path):
    out = tmp_path / 'sheet.png'
    # the seed method's legend (the robot-level one has more lines, so its swatches start
    # higher up the sheet)
    assert pictures_tool.main(['--scene', 'person_walking', '--frames', '0:2', '--out',
                               str(out), '--preset', 'table_4_2']) == 0
    sheet = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    ground = pictures.over_grey(pictures.GROUND_RGB, pictures.GROUND_TINT)
    legend_rows = np.flatnonzero((sheet == ground).all(axis=-1).any(axis=1))
    # the full-size legend (its swatches exactly coloured) lies below every thumbnail; no
    # truth panel, though the scene has a truth
    assert sheet.shape[1] == 2 * (picture_jobs.SHEET_THUMB_PX + 6) and legend_rows.size
    assert legend_rows.max() > 0.6 * sheet.shape[0]
    assert not (sheet == pictures.MISS_RGB).all(axis=-1).any()


def test_text_is_at_least_11_px_high_as_drawn():
    # capitals of every text (ticks, legends, captions) are MIN_TEXT_PX high, and the sheets
    # draw their text at the size they are shown (tile pads, fit_width scales rasters)
    assert text_height_px(pictures.TEXT_SCALE) >= MIN_TEXT_PX == 11
    assert text_height_px(pictures.TITLE_SCALE) > MIN_TEXT_PX
    narrow = np.zeros((10, 50, 3), np.uint8)
    assert pictures.tile([narrow, np.zeros((10, 80, 3), np.uint8)])[:10, :50].sum() == 0


def test_fit_width_scales_the_images_not_the_text(corridor):
    frame, result = corridor
    params = frame.params(table_4_2())
    full = pictures.side_by_side(result, params, caption='corridor')
    fitted = pictures.fit_width(lambda s: pictures.side_by_side(result, params, caption='corridor',
                                                                image_scale=s),
                                full.shape[1] - 60)
    assert fitted.shape[1] == full.shape[1] - 60
    # the caption 'corridor' is written in both at the same size: its band's ink is found
    word = pictures.caption_band(['corridor'], 100)
    ink = np.flatnonzero((word < 128).any(axis=(1, 2)))
    patch = word[ink[0]:ink[-1] + 1]

    def has_word(image):
        return any((image[r:r + patch.shape[0], :100] == patch).all()
                   for r in range(image.shape[0] - patch.shape[0]))
    assert has_word(full) and has_word(fitted)


def test_above_robot_surfaces_have_their_own_colour(corridor):
    frame, _ = corridor
    params = frame.params(PRESETS['corridor']())  # robot level: walls above 1 m are passable
    result = Detector(params).process(frame.depth, frame.intrinsics)
    above = pictures.above_robot_pixels(result, params)
    assert above is not None and above.any()
    assert (result.labels[above] == LABEL_GROUND).all()
    heights = result.voxel_height_m[result.pixel_voxel[above]]
    assert (heights > params.robot_height_m).all()
    rgb = pictures.depth_overlay(result.depth_m, result.labels, above_robot=above)
    plain = pictures.depth_overlay(result.depth_m, result.labels)
    blue = rgb[above].astype(int)
    assert (blue[:, 2] > blue[:, 1]).all() and (blue[:, 2] > blue[:, 0]).all()
    np.testing.assert_array_equal(rgb[~above], plain[~above])
    # the seed's slope test knows no robot height: nothing is called above the robot
    assert pictures.above_robot_pixels(result, table_4_2()) is None


# --- What a picture says is what it draws (issue 32) ------------------------------------------


def _red_shape_aspect(image: np.ndarray) -> float:
    """Width over height of the ROBOT_RGB pixels' bounding box."""
    red = np.argwhere((image == ROBOT_RGB).all(axis=-1))
    return (np.ptp(red[:, 1]) + 1) / (np.ptp(red[:, 0]) + 1)


def test_the_robot_swatch_is_the_shape_drawn_on_the_grid():
    panel = pictures.costmap_panel(_empty_costmap(table_4_2()), scale=8)   # facing up (+x)
    legend = pictures.node_outputs_legend([300, 300])   # one robot swatch
    assert _red_shape_aspect(legend) == pytest.approx(_red_shape_aspect(panel), rel=0.1)


@pytest.mark.parametrize('which', ['node outputs', 'side by side'])
def test_the_legend_shows_the_reds_the_overlay_draws(which, corridor):
    # an obstacle pixel is red over its depth grey: dark red near, light red far; the legend
    # showed one red
    from obstacle_detection.viz.overlay import MIN_GREY, blend

    if which == 'node outputs':
        legend = pictures.node_outputs_legend([300, 300])
    else:
        frame, _ = corridor
        legend = pictures.legend_row([300, 300], frame.params(table_4_2()), truth=False,
                                     above_robot=False)
    for grey in (MIN_GREY, 255):
        colour = tuple(int(v) for v in blend(OBSTACLE_RGB, grey, OBSTACLE_ALPHA))
        assert (legend == colour).all(axis=-1).any(), (grey, colour)


def test_the_fused_grid_is_drawn_at_the_costmaps_scale():
    # a 4 m fused window of 80 cells beside the costmap's 4 m was drawn half as wide (80 px,
    # one tick): both grids are in metres, at one scale
    params = table_4_2()
    costmap = _empty_costmap(params)
    costmap = Costmap(np.full_like(costmap.data, CELL_OCCUPIED), costmap.resolution_m,
                      costmap.origin_xy_m)
    fused = Costmap(np.full((80, 80), CELL_UNKNOWN, np.int8), 0.05, (-2.0, -2.0))
    overlay = np.full((145, 176, 3), 200, np.uint8)
    image = pictures.node_outputs(overlay, costmap, caption=['x'], fused=fused,
                                  with_legend=False)
    occupied = np.argwhere((image == OCCUPIED_RGB).all(axis=-1))   # the costmap only
    grey = np.argwhere((image == UNKNOWN_RGB).all(axis=-1))
    grey = grey[grey[:, 1] > occupied[:, 1].max()]                 # the fused grid (text aside)
    for axis in (0, 1):   # the rows and columns of the grid, not stray text pixels
        values, counts = np.unique(grey[:, axis], return_counts=True)
        grey = grey[np.isin(grey[:, axis], values[counts > 50])]
    assert np.ptp(grey[:, 1]) == np.ptp(occupied[:, 1]) > 100      # 4 m across each
    ticks = np.flatnonzero((image[grey[:, 0].max() + 3] == pictures.AXIS_RGB).all(axis=-1))
    assert np.count_nonzero(ticks >= grey[:, 1].min() - 1) >= 3    # -2, 0, 2 m across


def test_bag_frames_are_named_by_their_time_in_the_bag(tmp_path, corridor):
    # "t=1796623475.000000000" read as a date; a frame's seconds since the first one read
    frame, _ = corridor
    _write_bag(tmp_path / 'bag', frame, 3)
    names = [name for name, *_ in picture_jobs.bag_frames(tmp_path / 'bag', '/depth', '/info')]
    assert names == ['/depth #0, t = 0.000 s', '/depth #1, t = 1.000 s',
                     '/depth #2, t = 2.000 s']
    assert tool_support.time_text(1_796_279_833_666_666_667, 1_796_279_832_000_000_000) == \
        't = 1.667 s'


def test_a_contact_sheet_says_the_shared_lines_once(tmp_path, corridor, monkeypatch):
    # every thumbnail repeated the same mount and intrinsics lines (a 30-frame sheet 5,498 px)
    frame, _ = corridor
    _write_bag(tmp_path / 'bag', frame, 3)
    drawn: list[str] = []
    band = pictures.caption_band

    def recorded(lines, *args, **kwargs):
        drawn.extend(lines)
        return band(lines, *args, **kwargs)
    monkeypatch.setattr(pictures, 'caption_band', recorded)
    assert pictures_tool.main(['--bag', str(tmp_path / 'bag'), '--depth-topic', '/depth',
                               '--info-topic', '/info', '--set',
                               f'camera_height_m={frame.height_m}', '--out',
                               str(tmp_path / 'sheet.png')]) == 0
    shared = [line for line in drawn if line.startswith(('mount', 'intrinsics'))]
    assert shared and len(shared) == len(set(shared))
