"""The mount against the floor in view (obstacle_detection.ros.mount_check) on made-up fits."""

from __future__ import annotations

import math

import pytest

from obstacle_detection.pipeline.floor import FloorFit
from obstacle_detection.ros import mount_check
from obstacle_detection.ros.diagnostics import WARN, Context, Period, health_status
from obstacle_detection.ros.mount_check import MountCheck

CAUSE = ('the URDF (TF base_footprint <- depth_optical)', 'correct the URDF')


def _fit(d_pitch_deg: float, d_height_m: float = 0.0, d_roll_deg: float = 0.0) -> FloorFit:
    return FloorFit(True, 0.6 + d_height_m, math.radians(d_pitch_deg), math.radians(d_roll_deg),
                    d_height_m=d_height_m, d_pitch_deg=d_pitch_deg, d_roll_deg=d_roll_deg,
                    samples=300)


def _frames(check: MountCheck, fits: list[FloorFit], fps: float = 30.0) -> float:
    """Add the fits at ``fps`` from t = 0; return the time of the last."""
    for i, fit in enumerate(fits):
        check.add(fit, now=i / fps)
    return (len(fits) - 1) / fps


def test_a_body_pitching_about_a_right_mount_averages_out() -> None:
    """+-2 deg at 0.5 Hz, +-1 cm: the mean over the window is near zero, no warning."""
    check = MountCheck()
    fits = [_fit(2.0 * math.sin(2 * math.pi * 0.5 * i / 30), 0.01 * math.cos(i / 10))
            for i in range(600)]

    agreement = check.agreement(*CAUSE, now=_frames(check, fits))

    assert agreement.warning == ''
    assert abs(agreement.pitch_deg) < 0.2 and abs(agreement.height_m) < 0.005


def test_a_urdf_1_5_deg_and_3_cm_off_is_warned_with_its_angle_and_offset() -> None:
    check = MountCheck()
    fits = [_fit(1.5 + 2.0 * math.sin(2 * math.pi * 0.5 * i / 30), -0.03) for i in range(600)]

    agreement = check.agreement(*CAUSE, now=_frames(check, fits))

    assert 'pitch +1.5 deg, roll +0.0 deg, height -3.0 cm' in agreement.warning
    assert 'the URDF (TF base_footprint <- depth_optical) is likely wrong' in agreement.warning
    assert 'tools/estimate_mount.py' in agreement.warning
    assert agreement.values()['floor minus mount: pitch [deg]'] == '+1.50'
    assert agreement.values()['floor minus mount: height [cm]'] == '-3.0'


@pytest.mark.parametrize(('pitch', 'height', 'warned'), [
    (0.9, 0.0, False), (1.1, 0.0, True), (0.0, 0.019, False), (0.0, -0.021, True)])
def test_the_thresholds(pitch: float, height: float, warned: bool) -> None:
    check = MountCheck()
    now = _frames(check, [_fit(pitch, height)] * 30)

    assert bool(check.agreement(*CAUSE, now=now).warning) is warned


def test_only_the_last_window_counts_and_too_few_fits_say_nothing() -> None:
    check = MountCheck()
    for i in range(300):                      # 10 s off by 3 deg...
        check.add(_fit(3.0), now=i / 30)
    for i in range(300):                      # ...then 10 s right
        check.add(_fit(0.0), now=10.0 + i / 30)
    assert check.agreement(*CAUSE, now=20.0).warning == ''

    few = MountCheck()
    now = _frames(few, [_fit(3.0)] * (mount_check.MIN_FRAMES - 1) + [None] * 50)
    agreement = few.agreement(*CAUSE, now=now)
    assert agreement.warning == ''
    assert agreement.values() == {'mount vs floor': 'too few floor fits (9 of 59 frames in 10 s)'}


def test_a_floor_beyond_the_fits_bounds_is_warned() -> None:
    beyond = FloorFit(False, 0.6, 0.0, 0.0,
                      reason='fitted floor tilted 6.2 deg > floor_max_tilt_deg')
    check = MountCheck()

    agreement = check.agreement(*CAUSE, now=_frames(check, [beyond] * 20))

    assert agreement.warning.startswith('the floor in view lies beyond what the floor fit may '
                                        'correct in 20 of 20 frames (fitted floor tilted 6.2')


def test_the_warning_is_the_diagnostics_level_and_message() -> None:
    check = MountCheck()
    agreement = check.agreement(*CAUSE, now=_frames(check, [_fit(-1.5)] * 30))
    period = Period(seconds=1.0, received=30, processed=30, since_last_frame_s=0.03,
                    sum_ms=300.0)
    context = Context(uptime_s=10.0, depth_topic='/depth/image_raw',
                      code_path='compiled numba kernels', mount='TF: ...',
                      mount_check=agreement.values(), mount_warning=agreement.warning)

    status = health_status(period, context, name='n', hardware_id='h')

    assert status.level == WARN and status.message == agreement.warning
    assert {kv.key: kv.value for kv in status.values}['floor minus mount: pitch [deg]'] == \
        '-1.50'
