"""Tests of the /diagnostics rules (obstacle_detection.ros.diagnostics) on hand-made periods."""

from __future__ import annotations

from collections import Counter

import pytest

from obstacle_detection.ros.diagnostics import (
    ERROR,
    OK,
    WARN,
    Context,
    HealthWindow,
    Period,
    health_status,
    status_name,
)

#: the fallback_fx/fy/cx/cy defaults (the seed's Table 4.1), as the node writes them
FALLBACK = 'fx=580 fy=580 cx=200 cy=130'

NAME = status_name('/obstacle_detector')


def _context(**changes: object) -> Context:
    values = dict(uptime_s=10.0, depth_topic='/depth/image_raw',
                  code_path='compiled numba kernels', mount='parameters: height 0.6 m',
                  camera_info_topic='/depth/camera_info', fallback_intrinsics=FALLBACK)
    values.update(changes)
    return Context(**values)


def _period(**changes: object) -> Period:
    period = Period(seconds=1.0, received=30, processed=30, since_last_frame_s=0.03,
                    sum_ms=300.0)
    for name, value in changes.items():
        setattr(period, name, value)
    return period


def _values(status: object) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_a_healthy_stream_is_ok_with_its_figures() -> None:
    status = health_status(_period(), _context(), name=NAME,
                           hardware_id='kinect2_ir_optical_frame')
    assert status.level == OK and status.message == '30.0 frames/s processed'
    values = _values(status)
    assert values['input rate [Hz]'] == '30.0' and values['processing mean [ms]'] == '10.0'
    assert values['mount'] == 'parameters: height 0.6 m'
    assert values['intrinsics'] == 'CameraInfo on /depth/camera_info'
    assert status.hardware_id == 'kinect2_ir_optical_frame'


@pytest.mark.parametrize('period, context, level, message', [
    (_period(received=0, processed=0, since_last_frame_s=None),
     _context(uptime_s=3.0), ERROR, 'no depth frame received on /depth/image_raw yet'),
    (_period(received=0, processed=0, since_last_frame_s=None),
     _context(uptime_s=1.0), OK, '0.0 frames/s processed'),           # just started
    (_period(received=0, processed=0, since_last_frame_s=2.5),
     _context(), ERROR, 'no depth frame for 2.5 s on /depth/image_raw'),
    (_period(processed=14, skipped=Counter(encoding=16)), _context(), ERROR,
     '16 of 30 frames skipped for bad input (encoding 16)'),
    (_period(processed=15, skipped=Counter(encoding=15)), _context(), WARN,   # exactly half
     '15 of 30 frames skipped for bad input (encoding 15)'),
    (_period(errors=1), _context(), ERROR, 'the pipeline failed on 1 frame(s) (see the log)'),
    (_period(processed=23, dropped=7), _context(), WARN,
     '7 of 30 frames replaced before processing: the node does not keep up with the camera'),
    (_period(processed=24, dropped=6), _context(), OK, '24.0 frames/s processed'),   # 20 %
    (_period(), _context(code_path='numpy path while ...'), WARN,
     'numpy path while ...'),
])
def test_levels_follow_the_thresholds(period: Period, context: Context, level: int,
                                      message: str) -> None:
    status = health_status(period, context, name=NAME, hardware_id='/depth/image_raw')
    assert (status.level, status.message) == (level, message)


@pytest.mark.parametrize(('fallback', 'intrinsics'), [
    (30, f'fallback {FALLBACK} (no CameraInfo on /depth/camera_info)'),
    (3, f'CameraInfo on /depth/camera_info; 3 frame(s): fallback {FALLBACK} '
        '(no CameraInfo on /depth/camera_info)'),
])
def test_frames_on_the_fallback_intrinsics_warn_and_say_which(fallback: int,
                                                             intrinsics: str) -> None:
    status = health_status(_period(fallback=fallback), _context(), name=NAME,
                           hardware_id='/depth/image_raw')

    assert status.level == WARN
    assert status.message == (f'{fallback} of 30 frames used the fallback intrinsics '
                              f'{FALLBACK}: no CameraInfo on /depth/camera_info')
    assert _values(status)['intrinsics'] == intrinsics


def test_a_period_without_a_processed_frame_names_no_intrinsics_nor_times() -> None:
    values = _values(health_status(_period(received=0, processed=0, sum_ms=0.0), _context(),
                                   name=NAME, hardware_id='/depth/image_raw'))

    assert values['intrinsics'] == values['processing max [ms]'] == '-'


def test_the_slowest_frame_of_the_period_is_reported_beside_the_mean() -> None:
    window = HealthWindow(now=0.0)
    for elapsed_ms in (9.0, 11.0, 250.0, 10.0):
        window.count('received', now=0.5)
        window.processed(elapsed_ms, fallback=elapsed_ms > 100.0)
    period = window.take(now=1.0)

    values = _values(health_status(period, _context(), name=NAME, hardware_id='/d'))

    assert (values['processing mean [ms]'], values['processing max [ms]']) == ('70.0', '250.0')
    assert period.fallback == 1
    assert window.take(now=2.0).max_ms == 0.0   # a new period starts from nothing


def test_window_counts_one_period_then_starts_again() -> None:
    window = HealthWindow(now=100.0)
    window.count('received', now=100.2)
    window.count('received', now=100.4)
    window.count('dropped')
    window.processed(12.0)
    window.skipped('size')
    period = window.take(now=101.0)
    assert (period.seconds, period.received, period.processed, period.dropped) == (
        pytest.approx(1.0), 2, 1, 1)
    assert period.skipped == {'size': 1} and period.since_last_frame_s == pytest.approx(0.6)
    later = window.take(now=103.0)
    assert later.received == 0 and later.since_last_frame_s == pytest.approx(2.6)


def test_the_status_is_named_as_diagnostic_updater_names_a_task() -> None:
    # Updater.publish: stat.name = self.node_name + ': ' + stat.name
    assert status_name('obstacle_detector') == 'obstacle_detector: depth obstacle detection'


def test_the_status_is_named_after_the_node_that_reports_it() -> None:
    front = health_status(_period(), _context(), name=status_name('/front/obstacle_detector'),
                          hardware_id='front_depth_optical')
    rear = health_status(_period(), _context(), name=status_name('/rear/obstacle_detector'),
                         hardware_id='rear_depth_optical')

    assert front.name == '/front/obstacle_detector: depth obstacle detection'
    assert rear.name == '/rear/obstacle_detector: depth obstacle detection'
