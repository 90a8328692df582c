"""The named scenes of the generator: ``build_scene`` and ``render_scene`` by name."""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from obstacle_detection.pipeline.params import (DetectorParams, Intrinsics, KINECT_V2_SD,
                                                KINECT_V2_SD_SIZE)

from .noise import NoiseModel
from .primitives import Box, Cylinder, Floor, Ramp, RampSide, StepDown, Wall
from .render import Scene, SceneFrame, check_render_args, render
from .truth import TruthRules

#: Walking speed [m/s] and frame rate [Hz] of the 'person_walking' sequence.
WALK_SPEED_M_S = 1.0
WALK_FRAME_RATE_HZ = 30.0
#: Lateral extent of one crossing in 'person_walking' (then it starts again on the left) [m].
WALK_SPAN_M = 3.2

def _corridor_walls(rng: np.random.Generator, **left_kwargs: bool) -> tuple[Wall, Wall]:
    half = 0.7 + rng.uniform(-0.05, 0.05)      # 1.3-1.5 m apart: in view from ~1 m ahead
    return (Wall(-1.0, half, 12.0, half, 0.0, 2.5, **left_kwargs),
            Wall(-1.0, -half, 12.0, -half, 0.0, 2.5))


def _corridor(rng: np.random.Generator, frame_index: int) -> Scene:
    walls = _corridor_walls(rng)
    boxes = (
        Box.on_floor(0.9 + rng.uniform(0.0, 0.1), 0.25 + rng.uniform(-0.05, 0.05),
                     0.3, 0.3, 0.25 + rng.uniform(0.0, 0.05), name='box_1'),
        Box.on_floor(1.4 + rng.uniform(-0.05, 0.05), -0.3 + rng.uniform(-0.05, 0.05),
                     0.4, 0.3, 0.45 + rng.uniform(0.0, 0.05), name='box_2'),
        Box.on_floor(1.85 + rng.uniform(-0.05, 0.05), 0.2 + rng.uniform(-0.05, 0.05),
                     0.25, 0.25, 0.2 + rng.uniform(0.0, 0.05), name='box_3'),
    )
    return Scene('corridor', (Floor(),) + walls + boxes)


def _ramps(rng: np.random.Generator, frame_index: int) -> Scene:
    gentle = Ramp(x_start_m=1.1 + rng.uniform(-0.05, 0.05), y_center_m=0.45, width_m=0.7,
                  length_m=1.5, slope_rad=math.radians(15.0), name='ramp')
    steep = Ramp(x_start_m=1.2 + rng.uniform(-0.05, 0.05), y_center_m=-0.45, width_m=0.7,
                 length_m=0.8, slope_rad=math.radians(45.0), name='steep_ramp')
    return Scene('ramps', (Floor(), gentle, steep))


def _people(rng: np.random.Generator, frame_index: int) -> Scene:
    count = 2 + int(rng.integers(0, 2))
    slots = [(1.6, 0.6), (2.2, -0.5), (3.0, 0.1)]
    people = tuple(
        Cylinder(x + rng.uniform(-0.1, 0.1), y + rng.uniform(-0.1, 0.1),
                 radius_m=0.2 + rng.uniform(-0.02, 0.02), height_m=1.7 + rng.uniform(-0.1, 0.1),
                 name=f'person_{i + 1}')
        for i, (x, y) in enumerate(slots[:count]))
    return Scene('people', (Floor(),) + people)


def _tree_rows(rng: np.random.Generator, wavelength_m: float, row_y: float, count: int,
               x0: float, spacing: float, radius_m: float, height_m: float) -> tuple:
    """Return a bumpy floor and two rows of trunks at y = +-row_y [m], positions jittered."""
    ground = Floor(bump_amplitude_m=0.03, bump_wavelength_m=wavelength_m,
                   bump_phase_rad=tuple(float(p) for p in rng.uniform(0, 2 * math.pi, 3)))
    trunks = []
    for side, y in (('left', row_y), ('right', -row_y)):
        for i in range(count):
            trunks.append(Cylinder(x0 + spacing * i + rng.uniform(-0.05, 0.05),
                                   y + rng.uniform(-0.05, 0.05),
                                   radius_m=radius_m + rng.uniform(-0.02, 0.02),
                                   height_m=height_m, base_z_m=-0.1, name=f'trunk_{side}_{i + 1}'))
    return (ground,) + tuple(trunks)


def _farm_row(rng: np.random.Generator, frame_index: int) -> Scene:
    return Scene('farm_row', _tree_rows(rng, 1.5, 0.75, 7, 1.0, 0.8, 0.1, 1.6))


def _pitched_floor(rng: np.random.Generator, frame_index: int) -> Scene:
    return Scene('pitched_floor', (Floor(),), pitch_rad=math.radians(30.0))


def _flat_floor(rng: np.random.Generator, frame_index: int) -> Scene:
    return Scene('flat_floor', (Floor(),))


def _step_down(rng: np.random.Generator, frame_index: int) -> Scene:
    step = StepDown(x_m=1.25 + rng.uniform(-0.03, 0.03), depth_m=0.3, name='drop')
    box = Box.on_floor(0.9, -0.35 + rng.uniform(-0.05, 0.05), 0.25, 0.3, 0.3, name='box')
    return Scene('step_down', (step, box))


def _dark_materials(rng: np.random.Generator, frame_index: int) -> Scene:
    walls = _corridor_walls(rng, dark=True)
    boxes = (
        Box.on_floor(1.1 + rng.uniform(-0.05, 0.05), 0.2 + rng.uniform(-0.05, 0.05),
                     0.35, 0.35, 0.4, dark=True, name='dark_box'),
        Box.on_floor(1.6 + rng.uniform(-0.05, 0.05), -0.3 + rng.uniform(-0.05, 0.05),
                     0.3, 0.3, 0.3, name='box'),
    )
    return Scene('dark_materials', (Floor(),) + walls + boxes)


def _person_walking(rng: np.random.Generator, frame_index: int) -> Scene:
    x = 2.0 + rng.uniform(-0.1, 0.1)
    # y from +WALK_SPAN_M / 2 (left, out of view) to -WALK_SPAN_M / 2, then again; frame 0 has
    # the person in view at y = +1.0 m
    walked = 0.6 + rng.uniform(-0.05, 0.05) + WALK_SPEED_M_S * frame_index / WALK_FRAME_RATE_HZ
    y = WALK_SPAN_M / 2 - walked % WALK_SPAN_M
    wall = Wall(3.6, 4.0, 3.6, -4.0, 0.0, 2.5)
    person = Cylinder(x, y, radius_m=0.2, height_m=1.75, name='person')
    return Scene('person_walking', (Floor(), wall, person))


# -- issue 9 scenes: robot-level obstacles (flat tops, overhangs, drops, steps)

def table(x_m: float, y_m: float, size_x_m: float, size_y_m: float, height_m: float, *,
          leg_m: float = 0.04, name: str = 'table', dark: bool = False) -> tuple[Box, ...]:
    """Return a table centred on (x_m, y_m): a 3 cm top, its upper face ``height_m`` up, legs."""
    hx, hy, under = size_x_m / 2, size_y_m / 2, height_m - 0.03
    parts = [Box((x_m - hx, y_m - hy, under), (x_m + hx, y_m + hy, height_m), dark=dark,
                 name=name)]
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            cx, cy = x_m + sx * (hx - leg_m / 2), y_m + sy * (hy - leg_m / 2)
            parts.append(Box((cx - leg_m / 2, cy - leg_m / 2, 0.0),
                             (cx + leg_m / 2, cy + leg_m / 2, under), dark=dark, name=name))
    return tuple(parts)


def chair(x_m: float, y_m: float, *, leg_m: float = 0.03, name: str = 'chair',
          dark: bool = False) -> tuple[Box, ...]:
    """Return a chair centred on (x_m, y_m): a 0.42 m seat 0.46 m up, its back at +x to 0.9 m."""
    back = Box((x_m + 0.21 - 0.03, y_m - 0.21, 0.46), (x_m + 0.21, y_m + 0.21, 0.9), dark=dark,
               name=name)
    return table(x_m, y_m, 0.42, 0.42, 0.46, leg_m=leg_m, name=name, dark=dark) + (back,)


def _jitter(rng: np.random.Generator) -> Callable[[], float]:
    """Return a draw of the furniture scenes' position jitter, +-0.04 m."""
    return lambda: float(rng.uniform(-0.04, 0.04))


def _office(rng: np.random.Generator, frame_index: int, *, dark: bool = False) -> Scene:
    jitter = _jitter(rng)
    walls = (Wall(2.7, 2.5, 2.7, -2.5, 0.0, 2.5, dark=dark),
             Wall(-1.0, 1.5 + jitter(), 2.7, 1.5, 0.0, 2.5))
    boxes = (Box.on_floor(1.25 + jitter(), 0.65 + jitter(), 0.3, 0.3, 0.3, dark=dark,
                          name='box_small'),
             Box.on_floor(1.75 + jitter(), -0.85 + jitter(), 0.4, 0.35, 0.45,
                          name='box_large'))
    furniture = (table(1.8 + jitter(), 0.1 + jitter(), 0.6, 0.7, 0.72)
                 + chair(1.15 + jitter(), -0.3 + jitter(), dark=dark))
    return Scene('dark_office' if dark else 'office', (Floor(),) + walls + boxes + furniture)


def _dark_office(rng: np.random.Generator, frame_index: int) -> Scene:
    return _office(rng, frame_index, dark=True)


def _ramp_landing(rng: np.random.Generator, frame_index: int) -> Scene:
    x0 = 1.1 + rng.uniform(-0.05, 0.05)
    ramp = Ramp(x_start_m=x0, y_center_m=0.35, width_m=0.8, length_m=0.6,
                slope_rad=math.radians(10.0), name='ramp')
    landing = Box((x0 + ramp.length_m, -0.05, 0.0), (x0 + ramp.length_m + 1.5, 0.75,
                                                     ramp.top_height_m), name='landing')
    steep = Ramp(x_start_m=1.25 + rng.uniform(-0.05, 0.05), y_center_m=-0.6, width_m=0.5,
                 length_m=0.35, slope_rad=math.radians(40.0), name='steep_ramp')
    return Scene('ramp_landing', (Floor(), ramp, landing, steep))


def _dock_edge(rng: np.random.Generator, frame_index: int) -> Scene:
    edge = StepDown(x_m=1.45 + rng.uniform(-0.05, 0.05), depth_m=0.3, name='dock_edge')
    return Scene('dock_edge', (edge,))


def _dock_edge_high(rng: np.random.Generator, frame_index: int) -> Scene:
    edge = StepDown(x_m=1.3 + rng.uniform(-0.05, 0.05), depth_m=0.3, name='dock_edge')
    return Scene('dock_edge_high', (edge,), height_m=1.0, pitch_rad=math.radians(25.0))


def _curb_sill(rng: np.random.Generator, frame_index: int) -> Scene:
    x = 1.35 + rng.uniform(-0.05, 0.05)
    curb = Box((x, -1.2, 0.0), (x + 0.15, -0.15, 0.10), name='curb')
    sill = Box((x + 0.05, 0.1, 0.0), (x + 0.13, 0.9, 0.03), name='sill')
    return Scene('curb_sill', (Floor(), curb, sill))


def _shelf(rng: np.random.Generator, frame_index: int) -> Scene:
    x = 1.3 + rng.uniform(-0.05, 0.05)
    board = Box((x, -0.45, 0.33), (x + 0.35, 0.45, 0.35), name='shelf')
    panels = (Box((x, -0.47, 0.0), (x + 0.35, -0.45, 0.35), name='shelf'),
              Box((x, 0.45, 0.0), (x + 0.35, 0.47, 0.35), name='shelf'))
    overhang = Box((1.2, 0.7, 1.15), (1.8, 1.3, 1.2), name='overhang')
    return Scene('shelf', (Floor(), board) + panels + (overhang,))


def _orchard(rng: np.random.Generator, frame_index: int) -> Scene:
    rows = _tree_rows(rng, 1.2, 0.85, 6, 1.2, 0.9, 0.08, 1.9)
    bushes = (Cylinder(1.5 + rng.uniform(-0.05, 0.05), -0.25 + rng.uniform(-0.05, 0.05),
                       radius_m=0.22, height_m=0.35 + rng.uniform(0.0, 0.1), base_z_m=-0.05,
                       name='bush_1'),
              Cylinder(1.85 + rng.uniform(-0.05, 0.05), 0.4 + rng.uniform(-0.05, 0.05),
                       radius_m=0.18, height_m=0.3 + rng.uniform(0.0, 0.1), base_z_m=-0.05,
                       name='bush_2'))
    return Scene('orchard', rows + bushes)


# -- issue 22 scenes: open-sided ramps, dark blobs on furniture, thin legs

#: The open-sided ramp of issue 22: slope [deg] and the height of its platform [m].
OPEN_RAMP_SLOPE_DEG = 12.0
OPEN_RAMP_RISE_M = 0.18


def open_ramp(x_m: float, y_center_m: float, width_m: float, platform_m: float, *,
              side_y: float | None = None) -> tuple:
    """Return an open-sided ramp up to a platform, the ramp's foot at x_m [m].

    ``side_y``: the y [m] of an open side modelled as its own primitives (listed first).
    """
    slope = math.radians(OPEN_RAMP_SLOPE_DEG)
    run = OPEN_RAMP_RISE_M / math.tan(slope)
    ramp = Ramp(x_start_m=x_m, y_center_m=y_center_m, width_m=width_m, length_m=run,
                slope_rad=slope, name='ramp')
    half = width_m / 2
    platform = Box((x_m + run, y_center_m - half, 0.0),
                   (x_m + run + platform_m, y_center_m + half, OPEN_RAMP_RISE_M),
                   name='platform')
    if side_y is None:
        return ramp, platform
    return (RampSide(x_m, side_y, run, slope, name='ramp_side'),
            Wall(x_m + run, side_y, x_m + run + platform_m, side_y, 0.0, OPEN_RAMP_RISE_M,
                 name='platform_side'), ramp, platform)


def _open_ramp(rng: np.random.Generator, frame_index: int) -> Scene:
    x0 = 1.0 + rng.uniform(-0.05, 0.05)
    yc = 0.65 + rng.uniform(-0.05, 0.05)
    box = Box.on_floor(1.3 + rng.uniform(-0.05, 0.05), -0.5, 0.3, 0.3, 0.3, name='box')
    return Scene('open_ramp', (Floor(),) + open_ramp(x0, yc, 0.8, 1.2, side_y=yc - 0.4)
                 + (box,))


def _open_ramp_ahead(rng: np.random.Generator, frame_index: int) -> Scene:
    x0 = 0.9 + rng.uniform(-0.05, 0.05)
    yc = rng.uniform(-0.05, 0.05)
    box = Box.on_floor(1.6 + rng.uniform(-0.05, 0.05), -0.85, 0.3, 0.3, 0.3, name='box')
    return Scene('open_ramp_ahead', (Floor(),) + open_ramp(x0, yc, 0.9, 1.5) + (box,))


def _dark_furniture(rng: np.random.Generator, frame_index: int) -> Scene:
    jitter = _jitter(rng)
    wall = Wall(2.9, 2.5, 2.9, -2.5, 0.0, 2.5)
    sofa = Box.on_floor(1.3 + jitter(), 0.75 + jitter(), 0.5, 0.6, 0.45, dark=True,
                        name='sofa')
    cabinet = Box.on_floor(2.0 + jitter(), -0.9 + jitter(), 0.4, 0.5, 0.8, dark=True,
                           name='cabinet')
    furniture = (table(1.9 + jitter(), 0.15 + jitter(), 0.7, 0.8, 0.72, dark=True)
                 + chair(1.2 + jitter(), -0.35 + jitter(), dark=True))
    return Scene('dark_furniture', (Floor(), wall, sofa, cabinet) + furniture)


def _thin_legs(rng: np.random.Generator, frame_index: int) -> Scene:
    jitter = _jitter(rng)
    wall = Wall(3.0, 2.5, 3.0, -2.5, 0.0, 2.5)
    furniture = (table(1.8 + jitter(), 0.2 + jitter(), 0.6, 0.8, 0.72, leg_m=0.02)
                 + chair(1.1 + jitter(), -0.45 + jitter(), leg_m=0.02, name='chair_1')
                 + chair(1.4 + jitter(), 0.65 + jitter(), leg_m=0.02, name='chair_2')
                 + table(1.5 + jitter(), -1.0 + jitter(), 0.3, 0.3, 0.6, leg_m=0.02,
                         name='stool'))
    return Scene('thin_legs', (Floor(), wall) + furniture)


#: Names accepted by ``build_scene`` and ``render_scene``.
SCENE_NAMES: tuple[str, ...] = ('corridor', 'ramps', 'people', 'farm_row', 'pitched_floor',
                                'flat_floor', 'step_down', 'dark_materials', 'person_walking',
                                'office', 'dark_office', 'ramp_landing', 'dock_edge',
                                'dock_edge_high', 'curb_sill', 'shelf', 'orchard', 'open_ramp',
                                'open_ramp_ahead', 'dark_furniture', 'thin_legs')
_BUILDERS: dict[str, Callable[[np.random.Generator, int], Scene]] = {
    name: globals()['_' + name] for name in SCENE_NAMES}


def scene_params(frame: SceneFrame, base: DetectorParams | None = None) -> DetectorParams:
    """Return ``base`` (default ``DetectorParams()``) with the frame's camera mount."""
    return (base or DetectorParams()).replace(camera_height_m=frame.height_m,
                                              camera_pitch_rad=frame.pitch_rad,
                                              camera_roll_rad=frame.roll_rad)


def build_scene(name: str, *, seed: int = 0, frame_index: int = 0) -> Scene:
    """Return the named scene's primitives and default mount; positions jitter with ``seed``."""
    if name not in _BUILDERS:
        raise ValueError(f'unknown scene {name!r}; known: {", ".join(SCENE_NAMES)}')
    check_render_args(seed, (1, 1), frame_index)
    rng = np.random.default_rng([int(seed), 0x5CE7E])
    return _BUILDERS[name](rng, int(frame_index))


def render_scene(name: str, *, seed: int = 0, intrinsics: Intrinsics = KINECT_V2_SD,
                 size: tuple[int, int] = KINECT_V2_SD_SIZE, height_m: float | None = None,
                 pitch_rad: float | None = None, roll_rad: float | None = None,
                 noise: bool | NoiseModel = True, frame_index: int = 0,
                 rules: TruthRules | DetectorParams | None = None) -> SceneFrame:
    """Render a named scene (``SCENE_NAMES``); mount arguments override its defaults.

    Raises ValueError for an unknown name, a bad seed, size or frame index, or a bad mount.
    """
    mount = {'height_m': height_m, 'pitch_rad': pitch_rad, 'roll_rad': roll_rad}
    scene = dataclasses.replace(build_scene(name, seed=seed, frame_index=frame_index),
                                **{k: v for k, v in mount.items() if v is not None})
    return render(scene, seed=seed, intrinsics=intrinsics, size=size, noise=noise,
                  frame_index=frame_index, rules=rules)
