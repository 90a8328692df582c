"""Parameters of the pipeline, validated on construction (metres and radians), and presets.

Each field's description names the seed's parameter; the defaults are :func:`corridor`'s.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of the depth camera [pixels] (the seed's one f is fx = fy)."""

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in values) or min(self.fx, self.fy) <= 0.0:
            raise ValueError(f'intrinsics focal lengths must be > 0 and every value finite, '
                             f'got fx={self.fx!r}, fy={self.fy!r}, cx={self.cx!r}, cy={self.cy!r}')


#: Seed Table 4.1: Kinect v2 intrinsics used when no CameraInfo is known (f = 580, cx = 200,
#: cy = 130, calibrated for the DIML 480x270 depth frames).
SEED_TABLE_4_1 = Intrinsics(fx=580.0, fy=580.0, cx=200.0, cy=130.0)

#: Typical Kinect v2 SD depth intrinsics (512x424), used by the scene generator.
KINECT_V2_SD = Intrinsics(fx=365.0, fy=365.0, cx=256.0, cy=212.0)
KINECT_V2_SD_SIZE = (512, 424)  # (width, height) [px]


def _describe(text: str, **limits: Any) -> dict[str, Any]:
    return {'description': text, **limits}


@dataclass(frozen=True)
class DetectorParams:
    """All parameters of the pipeline; construction raises ValueError naming a bad value.

    Field metadata: a ``description`` and the range (``min``/``max``, inclusive unless
    ``open_min``/``open_max``), the ROS node's parameter descriptors.
    """

    # -- crop (seed 4.3.1 "Cropping step") [px]
    crop_top_px: int = field(default=0, metadata=_describe(
        'Crop: rows removed at the top border (seed 4.3.1 cropping step) [px]', min=0, max=2000))
    crop_bottom_px: int = field(default=0, metadata=_describe(
        'Crop: rows removed at the bottom border [px]', min=0, max=2000))
    crop_left_px: int = field(default=0, metadata=_describe(
        'Crop: columns removed at the left border [px]', min=0, max=2000))
    crop_right_px: int = field(default=0, metadata=_describe(
        'Crop: columns removed at the right border [px]', min=0, max=2000))
    # -- median filter (seed 4.3.1 "Filtering step")
    median_kernel: int = field(default=5, metadata=_describe(
        'Median filter size K (KxK window, odd; 1 = off). Seed 4.3.1: K=17, 9, 7', min=1, max=31,
        step=2))
    # -- camera mount: ground frame = REP 103 body frame on the ground under the camera
    camera_height_m: float = field(default=0.6, metadata=_describe(
        'Height of the depth camera optical centre above the ground [m]', min=0.0, max=5.0,
        open_min=True))
    camera_pitch_rad: float = field(default=0.0, metadata=_describe(
        'Camera pitch, positive looks down (seed: level camera, 0) [rad]',
        min=-math.pi / 2, max=math.pi / 2, open_min=True, open_max=True))
    camera_roll_rad: float = field(default=0.0, metadata=_describe(
        'Camera roll about the optical axis, positive tilts the image clockwise [rad]',
        min=-math.pi / 2, max=math.pi / 2, open_min=True, open_max=True))
    camera_x_m: float = field(default=0.0, metadata=_describe(
        'Not in the seed: camera position ahead of the base frame origin (x forward); the '
        'outputs are in the base frame [m]', min=-5.0, max=5.0))
    camera_y_m: float = field(default=0.0, metadata=_describe(
        'Not in the seed: camera position left of the base frame origin (y left) [m]',
        min=-5.0, max=5.0))
    camera_yaw_rad: float = field(default=0.0, metadata=_describe(
        'Not in the seed: camera heading in the base frame, positive turns it to the left '
        '(about z up) [rad]', min=-math.pi, max=math.pi))
    # -- region of interest (seed 4.3.3), ground frame
    max_range_m: float = field(default=2.0, metadata=_describe(
        'ROI: forward range kept in front of the robot (seed 4.3.3: 2 m) [m]', min=0.0, max=20.0,
        open_min=True))
    min_range_m: float = field(default=0.0, metadata=_describe(
        'ROI: points closer than this forward distance are dropped [m]', min=0.0, max=20.0))
    lateral_limit_m: float = field(default=2.0, metadata=_describe(
        'ROI: half-width kept left and right of the robot [m]', min=0.0, max=20.0,
        open_min=True))
    tdbg_m: float = field(default=-0.1, metadata=_describe(
        'ROI: TDBG, tolerated distance below the ground (seed: -0.1, negative ramps) [m]',
        min=-5.0, max=0.0))
    smar_m: float = field(default=0.8, metadata=_describe(
        'ROI: SMAR, margin kept above the sensor height (seed: 0.8) [m]', min=-5.0, max=5.0))
    # -- voxel grid (seed 4.3.4)
    voxel_x_m: float = field(default=0.025, metadata=_describe(
        'Voxel grid Vx, size along the forward axis (seed: 25 mm) [m]', min=0.001, max=1.0))
    voxel_y_m: float = field(default=0.025, metadata=_describe(
        'Voxel grid Vy, size along the lateral axis (seed: 25 mm) [m]', min=0.001, max=1.0))
    voxel_z_m: float = field(default=0.025, metadata=_describe(
        'Voxel grid Vz, size along the vertical axis (seed: 25 mm) [m]', min=0.001, max=1.0))
    # -- normals and slope test (seed 4.3.5)
    normal_neighbours: int = field(default=10, metadata=_describe(
        'N: nearest neighbours (the point itself included) whose covariance gives the normal '
        '(seed Table 4.2: 10)', min=3, max=400))
    max_slope_rad: float = field(default=math.pi / 6, metadata=_describe(
        'theta: maximum passable slope; obstacle where |n.up| < cos(theta) '
        '(seed Table 4.2: pi/6)', min=0.0, max=math.pi / 2, open_min=True, open_max=True))
    validation_neighbours: int = field(default=12, metadata=_describe(
        'N1: an obstacle point stays one only if its N1 nearest neighbours (itself excluded) are '
        'obstacles too; 0 = no validation (seed Table 4.2: 12)', min=0, max=400))
    # -- robot level (not in the seed): traversability by connectivity, step height and drops
    robot_level: bool = field(default=True, metadata=_describe(
        'Not in the seed: robot-level traversability. Ground is grown from the floor plane '
        'through steps <= max_step_height_m up / max_step_down_m down and slopes <= theta; '
        'other surfaces inside the robot height band (box and table tops, curbs) and drops are '
        'obstacles. false = the seed slope-only rule'))
    max_step_height_m: float = field(default=0.05, metadata=_describe(
        'Robot level: largest step up the robot drives over (door sill) [m]', min=0.0,
        max=1.0))
    max_step_down_m: float = field(default=0.05, metadata=_describe(
        'Robot level: largest step down the robot drives over; lower ground is a drop [m]',
        min=0.0, max=1.0))
    robot_height_m: float = field(default=1.0, metadata=_describe(
        'Robot level: surfaces higher than this above the local ground do not block the robot '
        '[m]', min=0.0, max=5.0, open_min=True))
    max_filter_shift: float = field(default=0.02, metadata=_describe(
        'Robot level: a pixel whose median-filtered depth moved more than this fraction of '
        'its depth away from the measured one takes the measured depth back (the filter '
        'smeared a depth edge onto it); holes filled across an edge and mixed (flying) pixels '
        'are dropped (no return never marks anything). 0 = the filtered depth as is, as the '
        'seed',
        min=0.0, max=1.0))
    drop_view_m: float = field(default=1.0, metadata=_describe(
        'Robot level: the region of interest reaches this far below the ground (instead of '
        'TDBG) so that the floor beyond a drop is seen [m]', min=0.0, max=5.0))
    refine_floor: bool = field(default=True, metadata=_describe(
        'Not in the seed: fit the floor plane to each frame (bounded by floor_max_tilt_deg and '
        'floor_max_offset_m around the configured mount; the mount is used when too little '
        'floor is seen)'))
    floor_max_tilt_rad: float = field(default=math.radians(5.0), metadata=_describe(
        'Floor refinement: largest tilt of the fitted floor from the configured mount [rad]',
        min=0.0, max=math.radians(20.0)))
    floor_max_offset_m: float = field(default=0.1, metadata=_describe(
        'Floor refinement: largest height offset of the fitted floor from the configured '
        'mount [m]', min=0.0, max=1.0))
    floor_min_points: int = field(default=60, metadata=_describe(
        'Floor refinement: fewest floor samples (of about 3000 pixels on a grid) for a fit; '
        'fewer keep the configured mount', min=3, max=100000))
    # -- costmap (seed 4.3.6), ground plane, x forward from the camera foot, centred in y
    costmap_resolution_m: float = field(default=0.05, metadata=_describe(
        'Costmap cell size [m/cell]', min=0.005, max=1.0))
    costmap_length_m: float = field(default=2.0, metadata=_describe(
        'Costmap extent forward of the camera foot point [m]', min=0.0, max=50.0,
        open_min=True))
    costmap_width_m: float = field(default=4.0, metadata=_describe(
        'Costmap extent across, centred on the camera [m]', min=0.0, max=50.0, open_min=True))
    # -- execution (not in the seed): the outputs are the same for every value, so it takes no
    # part in comparing two parameter sets
    compute_threads: int = field(default=1, compare=False, metadata=_describe(
        'Not in the seed: threads of the median filter (row bands), at most the CPUs the '
        'process may use; the outputs are identical to the bit for every value. 1 = all on '
        'the calling thread', min=1, max=8))

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            _check_field(f.name, value, f.type, f.metadata)
        if self.median_kernel % 2 != 1:
            raise ValueError(f'median_kernel={self.median_kernel} must be odd (K x K median)')
        if self.min_range_m >= self.max_range_m:
            raise ValueError(
                f'min_range_m={self.min_range_m} must be below max_range_m={self.max_range_m}')
        if self.max_step_height_m >= self.robot_height_m:
            raise ValueError(
                f'max_step_height_m={self.max_step_height_m} must be below '
                f'robot_height_m={self.robot_height_m} (a step the robot drives over cannot '
                f'be taller than the robot)')
        if self.camera_height_m + self.smar_m <= self.tdbg_m:
            raise ValueError(
                f'smar_m={self.smar_m} leaves an empty height band above tdbg_m={self.tdbg_m} '
                f'for camera_height_m={self.camera_height_m}')

    # Derived values -------------------------------------------------------------------------
    @property
    def voxel_size_m(self) -> tuple[float, float, float]:
        """(Vx, Vy, Vz) [m]."""
        return (self.voxel_x_m, self.voxel_y_m, self.voxel_z_m)

    @property
    def cos_max_slope(self) -> float:
        """cos(theta), the slope-test threshold on |n.up|."""
        return math.cos(self.max_slope_rad)

    @property
    def max_height_m(self) -> float:
        """Top of the region of interest above the ground: camera height + SMAR [m]."""
        return self.camera_height_m + self.smar_m

    def replace(self, **changes: Any) -> 'DetectorParams':
        """Return a validated copy with some fields changed (raises ValueError)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise ValueError(f'unknown parameter(s): {", ".join(sorted(unknown))}')
        return dataclasses.replace(self, **changes)

    def with_frame_mount(self, **changes: float) -> 'DetectorParams':
        """Return a copy with this frame's fitted mount or ROI floor set, not validated again.

        For the pipeline's per-frame changes only (values kept in range by the floor fit).
        """
        out = object.__new__(DetectorParams)
        out.__dict__.update(self.__dict__)
        out.__dict__.update({name: float(value) for name, value in changes.items()})
        return out

    def as_dict(self) -> dict[str, Any]:
        """Plain ``{name: value}`` of every field."""
        return dataclasses.asdict(self)


def _check_field(name: str, value: Any, type_name: Any, meta: Any) -> None:
    if type_name in ('bool', bool):
        if not isinstance(value, bool):
            raise ValueError(f'{name}={value!r} must be true or false')
        return
    is_int = type_name in ('int', int)
    if is_int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f'{name}={value!r} must be an integer')
    else:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f'{name}={value!r} must be a number')
        if not math.isfinite(value):
            raise ValueError(f'{name}={value!r} must be finite')
    low, high = meta.get('min'), meta.get('max')
    if low is not None and (value < low or (meta.get('open_min') and value == low)):
        bound = '>' if meta.get('open_min') else '>='
        raise ValueError(f'{name}={value!r} out of range: must be {bound} {low}')
    if high is not None and (value > high or (meta.get('open_max') and value == high)):
        bound = '<' if meta.get('open_max') else '<='
        raise ValueError(f'{name}={value!r} out of range: must be {bound} {high}')


#: What the robot-level additions are set to in the seed presets: off, the seed method exactly.
SEED_METHOD = dict(robot_level=False, refine_floor=False)


def table_4_2(**overrides: Any) -> DetectorParams:
    """Return the seed's Table 4.2 parameters (K = 17, slope only): params/seed_table_4_2.yaml."""
    base = dict(max_slope_rad=math.pi / 6, validation_neighbours=12, normal_neighbours=10,
                tdbg_m=-0.1, smar_m=0.8, max_range_m=2.0, median_kernel=17, **SEED_METHOD)
    base.update(overrides)
    return DetectorParams(**base)


def table_4_3(**overrides: Any) -> DetectorParams:
    """Return the seed's Table 4.3 parameters (corridor video), ``params/seed_table_4_3.yaml``."""
    base = dict(max_slope_rad=math.pi / 3, validation_neighbours=7, normal_neighbours=5,
                tdbg_m=-0.1, smar_m=0.8, max_range_m=1.0, median_kernel=7,
                costmap_length_m=1.0, **SEED_METHOD)
    base.update(overrides)
    return DetectorParams(**base)


def corridor(**overrides: Any) -> DetectorParams:
    """Return the navigation default ``params/corridor.yaml``: Table 4.2, K = 5, robot level."""
    return table_4_2(**{'robot_level': True, 'refine_floor': True, 'median_kernel': 5,
                        **overrides})


PRESETS = {'table_4_2': table_4_2, 'table_4_3': table_4_3, 'corridor': corridor}


# -- the frame budget (docs/budget.md) ---------------------------------------------------------
#: The frame the budget is computed for: Kinect v2 SD depth, 512 x 424 pixels, its intrinsics.
BUDGET_FRAME_SIZE = KINECT_V2_SD_SIZE
#: Limits of one frame's estimated time [ms] and peak memory [MiB] (docs/budget.md).
MAX_FRAME_MS = 100.0
MAX_FRAME_MIB = 256.0
#: Surface a frame sees in the region of interest, per square root of its depth [m^2 / m^0.5],
#: and the share of the pixels that can fall in it: the voxel estimate (docs/budget.md).
SEEN_SURFACE_M2 = 3.2
ROI_PIXEL_SHARE = 0.78
#: Milliseconds and MiB per unit of each term of :func:`frame_budget`, fitted on the
#: measurements of docs/budget.md (tools/budget_bench.py, CPU time of one thread).
BUDGET_MS = {'frame': 2.3, 'median': 2.8e-06, 'voxels': 0.00047, 'knn': 0.0, 'knn2': 2.2e-07,
             'lattice': 4.5e-07, 'ground_cells': 0.0, 'costmap_cells': 1.4e-05,
             'fused_cells': 3.5e-05, 'clearing_rays': 0.0}
BUDGET_MIB = {'frame': 7.1, 'median': 0.0, 'voxels': 0.00021, 'knn': 3.6e-06, 'knn2': 2.1e-08,
              'lattice': 3.1e-07, 'ground_cells': 8.8e-06, 'costmap_cells': 2e-05,
              'fused_cells': 3.4e-05, 'clearing_rays': 3.1e-05}
#: The parameters behind each term, named when it makes up most of a refused estimate.
_TERM_PARAMETERS = {
    'frame': (),
    'median': ('median_kernel',),
    'voxels': ('voxel_x_m', 'voxel_y_m', 'voxel_z_m', 'max_range_m'),
    'knn': ('normal_neighbours', 'validation_neighbours', 'voxel_x_m', 'voxel_y_m',
            'voxel_z_m'),
    'knn2': ('normal_neighbours', 'validation_neighbours', 'voxel_x_m', 'voxel_y_m',
             'voxel_z_m'),
    'lattice': ('voxel_x_m', 'voxel_y_m', 'voxel_z_m', 'max_range_m', 'lateral_limit_m'),
    'ground_cells': ('voxel_x_m', 'voxel_y_m', 'max_range_m', 'lateral_limit_m'),
    'costmap_cells': ('costmap_length_m', 'costmap_width_m', 'costmap_resolution_m'),
    'fused_cells': ('fused_size_m', 'fused_resolution_m'),
    'clearing_rays': ('clearing_stride_px',),
}


@dataclass(frozen=True)
class FrameBudget:
    """One frame's time and peak memory estimated from the parameters (docs/budget.md)."""

    terms: dict[str, float]    #: the sizes the estimate is made of (BUDGET_MS's keys)
    values: dict[str, Any]     #: the parameter values it was made from, by ROS name

    @property
    def ms(self) -> float:
        """Estimated time of a frame on the machine of docs/budget.md [ms]."""
        return sum(BUDGET_MS[name] * size for name, size in self.terms.items())

    @property
    def mib(self) -> float:
        """Estimated memory a frame adds at its peak [MiB]."""
        return sum(BUDGET_MIB[name] * size for name, size in self.terms.items())

    def problem(self) -> str | None:
        """One line naming the parameters, the estimate and the limits; None within them."""
        if self.ms <= MAX_FRAME_MS and self.mib <= MAX_FRAME_MIB:
            return None
        coefficients = BUDGET_MS if self.ms / MAX_FRAME_MS >= self.mib / MAX_FRAME_MIB \
            else BUDGET_MIB
        parts = sorted(((coefficients[name] * size, name) for name, size in self.terms.items()),
                       reverse=True)
        total, covered, causes, names = sum(part for part, _ in parts), 0.0, [], []
        for part, name in parts:   # the terms that make up most of the estimate
            if covered > 0.5 * total or not _TERM_PARAMETERS[name]:
                break
            covered += part
            causes.append(self._describe(name))
            names += [n for n in _TERM_PARAMETERS[name] if n not in names]
        named = ', '.join(f'{name}={self.values[name]!r}' for name in names)
        return (f'{named} ({"; ".join(causes)}) would make a frame take about '
                f'{_amount(self.ms, "ms")} and {_amount(self.mib, "MiB")}, above the limits of '
                f'{MAX_FRAME_MS:g} ms and {MAX_FRAME_MIB:g} MiB a frame (docs/budget.md)')

    def _describe(self, term: str) -> str:
        t = self.terms
        k = max(self.values['normal_neighbours'], self.values['validation_neighbours'] + 1)
        return {
            'median': f'a {self.values["median_kernel"]} x {self.values["median_kernel"]} '
                      f'median over {BUDGET_FRAME_SIZE[0]} x {BUDGET_FRAME_SIZE[1]} pixels',
            'voxels': f'about {t["voxels"]:,.0f} voxels a frame',
            'knn': f'{k} neighbours for about {t["voxels"]:,.0f} voxels',
            'knn2': f'{k} neighbours for about {t["voxels"]:,.0f} voxels',
            'lattice': f'a lattice of {t["lattice"]:.3g} voxels over the region of interest',
            'ground_cells': f'{t["ground_cells"]:,} ground cells',
            'costmap_cells': f'{t["costmap_cells"]:,} costmap cells',
            'fused_cells': f'{t["fused_cells"]:,} fused costmap cells',
            'clearing_rays': f'{t["clearing_rays"]:,} clearing rays',
        }[term]


def _amount(value: float, unit: str) -> str:
    """'3.2 s' / '85 ms', '2.3 GiB' / '310 MiB'."""
    if value >= 1000.0:
        return f'{value / 1024.0 if unit == "MiB" else value / 1000.0:.3g} ' \
               f'{"GiB" if unit == "MiB" else "s"}'
    return f'{value:.3g} {unit}'


def frame_budget(params: DetectorParams, *, fused_size_m: float = 0.0,
                 fused_resolution_m: float = 0.05, clearing_stride_px: int = 0) -> FrameBudget:
    """Estimate a frame's time and peak memory (frame of ``BUDGET_FRAME_SIZE``, docs/budget.md).

    The node's own outputs: the fused costmap (``fused_size_m`` > 0 when on) and the clearing
    cloud (``clearing_stride_px`` > 0 when on).
    """
    p = params
    width, height = BUDGET_FRAME_SIZE
    pixels = width * height
    depth = p.max_range_m - p.min_range_m
    # the width the camera sees at the far end of the ROI, at most the ROI's
    across = min(2.0 * p.lateral_limit_m,
                 p.max_range_m * width / KINECT_V2_SD.fx)
    low_z = min(p.tdbg_m, -p.drop_view_m) if p.robot_level else p.tdbg_m
    lattice = (math.ceil(depth / p.voxel_x_m) * math.ceil(across / p.voxel_y_m)
               * math.ceil((p.max_height_m - low_z) / p.voxel_z_m))
    # voxels: the surface seen at the voxels' size, at most one a pixel in the ROI
    face_m2 = (p.voxel_x_m * p.voxel_y_m * p.voxel_z_m) ** (2.0 / 3.0)
    voxels = 1.0 / (face_m2 / (SEEN_SURFACE_M2 * math.sqrt(depth))
                    + 1.0 / (ROI_PIXEL_SHARE * pixels))
    k = max(p.normal_neighbours, p.validation_neighbours + 1)
    cell = 2.0 * max(p.voxel_x_m, p.voxel_y_m)   # the robot level's ground cells
    res = p.costmap_resolution_m
    fused = math.ceil(fused_size_m / fused_resolution_m - 1e-9) if fused_size_m > 0.0 else 0
    stride = clearing_stride_px
    terms = {
        'frame': 1,
        'median': pixels * p.median_kernel if p.median_kernel > 1 else 0,
        'voxels': voxels, 'knn': voxels * k, 'knn2': voxels * k * k,
        'lattice': lattice if p.robot_level else 0,
        'ground_cells': (math.ceil(depth / cell) * math.ceil(across / cell)
                         if p.robot_level else 0),
        'costmap_cells': (math.ceil(p.costmap_length_m / res - 1e-9)
                          * math.ceil(p.costmap_width_m / res - 1e-9)),
        'fused_cells': fused * fused,
        'clearing_rays': math.ceil(width / stride) * math.ceil(height / stride) if stride else 0,
    }
    values = {**p.as_dict(), 'fused_size_m': fused_size_m,
              'fused_resolution_m': fused_resolution_m, 'clearing_stride_px': stride}
    return FrameBudget(terms, values)
