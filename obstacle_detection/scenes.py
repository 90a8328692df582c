"""Ray-cast depth frames with a ground-truth label per pixel (tests, benchmark, demo).

A scene is a tuple of primitives (floor, boxes, wall segments, ramps, vertical cylinders, a step
down) in the ground frame (x forward, y left, z up, origin on the ground under the camera) seen
from a camera mounted at a height, pitch and roll. Every pixel's ray is intersected with every
primitive at once (numpy, no per-pixel loop); the nearest hit wins and gives the pixel its true
depth, its true ground-frame point and its label (``GT_TRAVERSABLE`` or ``GT_OBSTACLE``).

Rays use ``obstacle_detection.geometry.mount_transform``, the pipeline's own convention: the ray
of pixel (u, v) has the optical direction ``((u - cx)/fx, (v - cy)/fy, 1)``, ground-frame
direction ``R @`` that and origin ``(0, 0, height)``. Because the optical z component is 1, the
ray parameter t of a hit is its depth (optical z) in metres.

Sensor model (``NoiseModel``, Kinect v2 like; all draws from one generator seeded by
``(seed, frame_index)``):

1. Gaussian depth noise ``sigma(z) = sigma_base + sigma_quad * (z - z_ref)^2`` with defaults
   1.5 mm + 1.5 mm/m^2 * (z - 0.5 m)^2 (1.5 mm at 0.5 m, 4.9 mm at 2 m, 25.5 mm at 4.5 m);
2. millimetre quantisation (``depth_mm`` is uint16, rounded to nearest);
3. no return outside the valid band: quantised depth below 0.5 m or above 4.5 m becomes 0;
4. pepper dropouts: each pixel is set to 0 with probability 0.75 %, or 40 % on a primitive
   flagged ``dark`` (low-reflectance material);
5. an invalid border: the outer 4 pixel rows and columns are 0.

``noise=False`` keeps only steps 2 and 3 (exact depth, millimetre quantised, valid band).
``labels`` is ``GT_NO_RETURN`` wherever ``depth_mm`` is 0 and the hit primitive's label
elsewhere; ``depth_true_m`` and ``points_ground`` are always the noise-free hit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Protocol, Union

import numpy as np

from .geometry import mount_transform
from .params import DetectorParams, Intrinsics, KINECT_V2_SD, KINECT_V2_SD_SIZE

#: Ground-truth pixel labels: no return (no surface, out of band, dropout, border), traversable
#: ground, obstacle. Same values as ``obstacle_detection.metrics``.
GT_NO_RETURN = 0
GT_TRAVERSABLE = 1
GT_OBSTACLE = 2

#: Hits farther than this ray parameter (depth) [m] count as no hit (the horizon).
MAX_TRACE_M = 50.0
#: The bumpy floor is root-found up to this depth [m]; beyond it, its hit is the flat z = 0 one.
BUMPY_TRACE_M = 12.0
#: Regula falsi steps refining each bumpy-floor hit after the march.
REFINE_STEPS = 4
#: Default camera height of the named scenes [m].
DEFAULT_HEIGHT_M = 0.6
#: Walking speed [m/s] and frame rate [Hz] of the 'person_walking' sequence.
WALK_SPEED_M_S = 1.0
WALK_FRAME_RATE_HZ = 30.0
#: Lateral extent of one crossing in 'person_walking' (then it starts again on the left) [m].
WALK_SPAN_M = 3.2

_EPS_T = 1e-9
#: Near plane [m] for projecting a primitive's bounding box into the image.
_NEAR_M = 0.05


@dataclass(frozen=True)
class Rays:
    """Camera rays in the ground frame: one origin, directions as same-shape arrays.

    origin: (x, y, z) [m]; dx, dy, dz: direction components, any (equal) shape, float64, with
    optical z = 1 so that a hit's ray parameter t is its depth [m].
    """

    origin: tuple[float, float, float]
    dx: np.ndarray
    dy: np.ndarray
    dz: np.ndarray

    def window(self, rows: slice, cols: slice) -> 'Rays':
        """Return the rays of an image window (views of 2-D direction arrays)."""
        return Rays(self.origin, self.dx[rows, cols], self.dy[rows, cols], self.dz[rows, cols])

    def flat(self, index: np.ndarray) -> 'Rays':
        """Return the rays at flat indices ``index`` (copies, 1-D)."""
        return Rays(self.origin, self.dx.reshape(-1)[index], self.dy.reshape(-1)[index],
                    self.dz.reshape(-1)[index])


#: A primitive's hit labels: one label for every hit, or an array of one per ray.
LabelValue = Union[int, np.ndarray]
#: Axis-aligned bounds ((x_min, y_min, z_min), (x_max, y_max, z_max)) [m], None if unbounded.
Bounds = Union[tuple[tuple[float, float, float], tuple[float, float, float]], None]


class Primitive(Protocol):
    """What the renderer needs from a primitive."""

    dark: bool

    @property
    def traversable(self) -> bool:
        """True when the primitive's (main) surface is ground the robot may drive on."""

    def bounds(self) -> Bounds:
        """Axis-aligned bounds used to cull rays, None for an unbounded primitive."""

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Ray parameter of the first hit, shaped like rays.dx (inf where none), and label(s)."""


def _label(traversable: bool) -> int:
    return GT_TRAVERSABLE if traversable else GT_OBSTACLE


def _check_positive(owner: str, **values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f'{owner}: {name}={value!r} must be a finite number > 0')


def _check_finite(owner: str, **values: float) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(f'{owner}: {name}={value!r} must be finite')


def _plane_t(offset: float, rate: np.ndarray) -> np.ndarray:
    """Return t solving ``offset + t * rate = 0``; inf if parallel or behind the camera."""
    with np.errstate(divide='ignore', invalid='ignore'):
        t = np.divide(-offset, rate)
    t[~(t > _EPS_T)] = np.inf
    return t


@dataclass(frozen=True)
class Floor:
    """Infinite ground z = 0, optionally bumpy: ``z = amplitude * f(x, y)``, ``|f| <= 1``.

    ``f`` is a smooth sum of two sinusoidal patterns of wavelength ``bump_wavelength_m`` with
    phases ``bump_phase_rad``; its slope is at most ``1.29 * amplitude * 2 pi / wavelength``
    (0.16, 9 degrees, for 3 cm over 1.5 m). A bumpy hit is found by marching each ray through
    the band ``|z| <= amplitude`` in steps of a tenth of a wavelength and refining the first
    sign change by regula falsi; beyond ``BUMPY_TRACE_M`` the flat z = 0 hit is used.
    """

    bump_amplitude_m: float = 0.0
    bump_wavelength_m: float = 1.5
    bump_phase_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    traversable: bool = True
    dark: bool = False

    def __post_init__(self) -> None:
        _check_finite('Floor', bump_amplitude_m=self.bump_amplitude_m)
        if self.bump_amplitude_m < 0.0:
            raise ValueError(f'Floor: bump_amplitude_m={self.bump_amplitude_m!r} must be >= 0')
        _check_positive('Floor', bump_wavelength_m=self.bump_wavelength_m)
        if len(self.bump_phase_rad) != 3:
            raise ValueError(f'Floor: bump_phase_rad={self.bump_phase_rad!r} needs 3 phases')

    def bounds(self) -> Bounds:
        """Unbounded."""
        return None

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground height z(x, y) [m], shaped like x and y."""
        if self.bump_amplitude_m == 0.0:
            return np.zeros(np.broadcast(x, y).shape)
        k = 2.0 * math.pi / self.bump_wavelength_m
        p0, p1, p2 = self.bump_phase_rad
        pattern = np.sin(k * x + p0)
        pattern *= np.cos((0.8 * k) * y + p1)
        pattern += np.sin((0.78 * k) * x - (1.04 * k) * y + p2)
        pattern *= 0.5 * self.bump_amplitude_m
        return pattern

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """First hit with the floor (inf where none) and the floor's label."""
        ox, oy, oz = rays.origin
        label = _label(self.traversable)
        t_flat = _plane_t(oz, rays.dz)
        amp = self.bump_amplitude_m
        if amp == 0.0:
            return t_flat, label
        shape = t_flat.shape
        t_flat = t_flat.reshape(-1)
        dz_all = rays.dz.reshape(-1)
        with np.errstate(divide='ignore'):
            t_enter = (oz - amp) / -dz_all
        # rays that go down and enter the band |z| <= amp early enough
        active = np.flatnonzero((dz_all < 0.0) & (t_enter < BUMPY_TRACE_M))
        # float32 from here: sin/cos are many times faster, and 1e-6 relative is plenty
        sub = rays.flat(active)
        dx, dy, dz = (d.astype(np.float32) for d in (sub.dx, sub.dy, sub.dz))
        t_end = np.minimum((oz + amp) / -dz, BUMPY_TRACE_M)   # below every bump from here on
        step = 0.1 * self.bump_wavelength_m / np.maximum(np.hypot(dx, dy), 1e-6)

        def gap(t: np.ndarray, i: np.ndarray) -> np.ndarray:
            # ray height above the surface at t: > 0 above, <= 0 on or below
            return oz + t * dz[i] - self.height(ox + t * dx[i], oy + t * dy[i])

        t_out = t_flat.copy()
        lo_t = np.maximum(t_enter[active], _EPS_T).astype(np.float32)
        lo_g = gap(lo_t, np.arange(active.size))
        live = np.arange(active.size)
        brackets = []
        while live.size:
            hi_t = np.minimum(lo_t + step[live], t_end[live])
            hi_g = gap(hi_t, live)
            crossed = hi_g <= 0.0
            brackets.append((live[crossed], lo_t[crossed], lo_g[crossed], hi_t[crossed],
                             hi_g[crossed]))
            going = ~crossed & (hi_t < t_end[live])   # no crossing before BUMPY_TRACE_M: flat
            live, lo_t, lo_g = live[going], hi_t[going], hi_g[going]
        if brackets:
            idx, a, ga, b, gb = (np.concatenate(parts) for parts in zip(*brackets))
            # Illinois regula falsi on ga > 0 >= gb: when one end is kept twice in a row, its
            # weight is halved so that the bracket shrinks from both sides
            wa, wb = ga.copy(), gb.copy()
            kept_b = np.zeros(idx.size, dtype=bool)
            kept_a = np.zeros(idx.size, dtype=bool)
            for _ in range(REFINE_STEPS):
                c = b - wb * (b - a) / (wb - wa)
                gc = gap(c, idx)
                above = gc > 0.0
                wb = np.where(above & kept_b, 0.5 * wb, wb)
                wa = np.where(~above & kept_a, 0.5 * wa, wa)
                a, ga, wa = np.where(above, c, a), np.where(above, gc, ga), np.where(above, gc, wa)
                b, gb, wb = np.where(above, b, c), np.where(above, gb, gc), np.where(above, wb, gc)
                kept_b, kept_a = above, ~above
            with np.errstate(divide='ignore', invalid='ignore'):
                root = np.where(gb < 0.0, b - gb * (b - a) / (gb - ga), b)
            t_out[active[idx]] = root
        return t_out.reshape(shape), label


@dataclass(frozen=True)
class Box:
    """Axis-aligned box between corners ``min_m`` and ``max_m`` (x, y, z) [m]; slab method.

    Every face carries the box's label (an obstacle by default).
    """

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    traversable: bool = False
    dark: bool = False

    def __post_init__(self) -> None:
        if len(self.min_m) != 3 or len(self.max_m) != 3:
            raise ValueError(f'Box: min_m={self.min_m!r}, max_m={self.max_m!r} need 3 values')
        for axis, lo, hi in zip('xyz', self.min_m, self.max_m):
            _check_finite('Box', **{f'min_{axis}': lo, f'max_{axis}': hi})
            if not lo < hi:
                raise ValueError(f'Box: min_{axis}={lo!r} must be below max_{axis}={hi!r}')

    @classmethod
    def on_floor(cls, x_m: float, y_m: float, size_x_m: float, size_y_m: float,
                 size_z_m: float, **kwargs: bool) -> 'Box':
        """Return a box standing on z = 0, centred on (x_m, y_m), of the given sizes [m]."""
        _check_positive('Box', size_x_m=size_x_m, size_y_m=size_y_m, size_z_m=size_z_m)
        return cls((x_m - size_x_m / 2, y_m - size_y_m / 2, 0.0),
                   (x_m + size_x_m / 2, y_m + size_y_m / 2, size_z_m), **kwargs)

    def bounds(self) -> Bounds:
        """Return the box itself."""
        return self.min_m, self.max_m

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Entry ray parameter into the box (inf where the ray misses it) and its label."""
        t_near = np.full(rays.dx.shape, -np.inf)
        t_far = np.full(rays.dx.shape, np.inf)
        with np.errstate(divide='ignore', invalid='ignore'):
            for o, d, lo, hi in zip(rays.origin, (rays.dx, rays.dy, rays.dz), self.min_m,
                                    self.max_m):
                inv = 1.0 / d
                t0 = (lo - o) * inv
                t1 = (hi - o) * inv
                np.maximum(t_near, np.minimum(t0, t1), out=t_near)
                np.minimum(t_far, np.maximum(t0, t1), out=t_far)
        # a ray parallel to a slab and outside it gives an empty interval or nan: no hit
        t_near[~((t_near <= t_far) & (t_near > _EPS_T))] = np.inf
        return t_near, _label(self.traversable)


@dataclass(frozen=True)
class Wall:
    """Vertical plane segment from (x0, y0) to (x1, y1), between z_min and z_max [m]."""

    x0_m: float
    y0_m: float
    x1_m: float
    y1_m: float
    z_min_m: float = 0.0
    z_max_m: float = 2.5
    traversable: bool = False
    dark: bool = False

    def __post_init__(self) -> None:
        _check_finite('Wall', x0_m=self.x0_m, y0_m=self.y0_m, x1_m=self.x1_m, y1_m=self.y1_m,
                      z_min_m=self.z_min_m, z_max_m=self.z_max_m)
        if self.x0_m == self.x1_m and self.y0_m == self.y1_m:
            raise ValueError(f'Wall: end points ({self.x0_m}, {self.y0_m}) coincide')
        if not self.z_min_m < self.z_max_m:
            raise ValueError(f'Wall: z_min_m={self.z_min_m!r} must be below '
                             f'z_max_m={self.z_max_m!r}')

    def bounds(self) -> Bounds:
        """Bounding box of the segment."""
        return ((min(self.x0_m, self.x1_m), min(self.y0_m, self.y1_m), self.z_min_m),
                (max(self.x0_m, self.x1_m), max(self.y0_m, self.y1_m), self.z_max_m))

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Hit ray parameter on the segment (inf where none) and the wall's label."""
        ex, ey = self.x1_m - self.x0_m, self.y1_m - self.y0_m
        length = math.hypot(ex, ey)
        ex, ey = ex / length, ey / length
        ox, oy, oz = rays.origin
        # plane: n . (p - p0) = 0 with the horizontal normal n = (-ey, ex)
        t = _plane_t(-ey * (ox - self.x0_m) + ex * (oy - self.y0_m), ex * rays.dy - ey * rays.dx)
        with np.errstate(invalid='ignore'):
            s = ex * (ox - self.x0_m + t * rays.dx) + ey * (oy - self.y0_m + t * rays.dy)
            z = oz + t * rays.dz
            inside = (s >= 0.0) & (s <= length) & (z >= self.z_min_m) & (z <= self.z_max_m)
        t[~inside] = np.inf
        return t, _label(self.traversable)


@dataclass(frozen=True)
class Ramp:
    """Planar strip rising from the floor: ``z = (x - x_start) tan(slope)``.

    It spans ``x_start_m <= x <= x_start_m + length_m`` (``length_m`` is the horizontal run)
    and ``|y - y_center_m| <= width_m / 2``. Traversable iff ``slope_rad <=
    max_passable_slope_rad`` (default pi/6, the seed's theta). Seen from a camera above its
    plane, the strip hides exactly what a solid wedge would; the wedge's vertical sides are
    not modelled.
    """

    x_start_m: float
    y_center_m: float
    width_m: float
    length_m: float
    slope_rad: float
    max_passable_slope_rad: float = math.pi / 6
    dark: bool = False

    def __post_init__(self) -> None:
        _check_finite('Ramp', x_start_m=self.x_start_m, y_center_m=self.y_center_m)
        _check_positive('Ramp', width_m=self.width_m, length_m=self.length_m)
        if not 0.0 < self.slope_rad < math.pi / 2:
            raise ValueError(f'Ramp: slope_rad={self.slope_rad!r} must be in (0, pi/2)')

    @property
    def traversable(self) -> bool:
        """True when the slope is passable."""
        return self.slope_rad <= self.max_passable_slope_rad

    @property
    def top_height_m(self) -> float:
        """Height of the ramp's far edge [m]."""
        return self.length_m * math.tan(self.slope_rad)

    def bounds(self) -> Bounds:
        """Bounding box of the strip."""
        half = self.width_m / 2
        return ((self.x_start_m, self.y_center_m - half, 0.0),
                (self.x_start_m + self.length_m, self.y_center_m + half, self.top_height_m))

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Hit ray parameter on the strip (inf where none) and the ramp's label."""
        tan = math.tan(self.slope_rad)
        ox, oy, oz = rays.origin
        # plane: z - tan * (x - x_start) = 0
        t = _plane_t(oz - tan * (ox - self.x_start_m), rays.dz - tan * rays.dx)
        with np.errstate(invalid='ignore'):
            x = ox + t * rays.dx
            y = oy + t * rays.dy
            inside = ((x >= self.x_start_m) & (x <= self.x_start_m + self.length_m)
                      & (np.abs(y - self.y_center_m) <= self.width_m / 2))
        t[~inside] = np.inf
        return t, _label(self.traversable)


@dataclass(frozen=True)
class Cylinder:
    """Vertical cylinder (a person, a trunk) on (x_m, y_m), from base_z_m to base + height."""

    x_m: float
    y_m: float
    radius_m: float
    height_m: float
    base_z_m: float = 0.0
    traversable: bool = False
    dark: bool = False

    def __post_init__(self) -> None:
        _check_finite('Cylinder', x_m=self.x_m, y_m=self.y_m, base_z_m=self.base_z_m)
        _check_positive('Cylinder', radius_m=self.radius_m, height_m=self.height_m)

    def bounds(self) -> Bounds:
        """Bounding box of the cylinder."""
        r = self.radius_m
        return ((self.x_m - r, self.y_m - r, self.base_z_m),
                (self.x_m + r, self.y_m + r, self.base_z_m + self.height_m))

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Hit ray parameter on the side or a cap (inf where none) and the label."""
        ox, oy, oz = rays.origin
        cx, cy = self.x_m - ox, self.y_m - oy   # centre relative to the ray origin
        r = self.radius_m
        z0, z1 = self.base_z_m, self.base_z_m + self.height_m
        dx, dy, dz = rays.dx, rays.dy, rays.dz
        # |t d_xy - c|^2 = r^2  ->  a t^2 - 2 b t + c0 = 0, entry root (b - sqrt(b^2 - a c0)) / a
        a = dx * dx + dy * dy
        b = dx * cx + dy * cy
        c0 = cx * cx + cy * cy - r * r
        with np.errstate(divide='ignore', invalid='ignore'):
            t = (b - np.sqrt(b * b - a * c0)) / a
            z = oz + t * dz
            ok = (t > _EPS_T) & (z >= z0) & (z <= z1)
        t[~ok] = np.inf
        for cap_z in (z0, z1):
            t_cap = _plane_t(oz - cap_z, dz)
            with np.errstate(invalid='ignore'):
                px = t_cap * dx - cx
                py = t_cap * dy - cy
                t_cap[~(px * px + py * py <= r * r)] = np.inf
            np.minimum(t, t_cap, out=t)
        return t, _label(self.traversable)


@dataclass(frozen=True)
class StepDown:
    """Floor at z = 0 for x < x_m, a drop of depth_m there, lower floor at z = -depth_m beyond.

    Use it instead of ``Floor``. The upper floor is traversable; the vertical riser at x = x_m
    (facing +x, so hidden from a camera on the upper floor) is an obstacle; the lower floor is
    an obstacle when ``depth_m > max_drop_m`` (default 0.1 m: a drop the robot must not drive
    off), traversable otherwise.
    """

    x_m: float
    depth_m: float
    max_drop_m: float = 0.1
    dark: bool = False

    def __post_init__(self) -> None:
        _check_finite('StepDown', x_m=self.x_m, max_drop_m=self.max_drop_m)
        _check_positive('StepDown', depth_m=self.depth_m)

    @property
    def traversable(self) -> bool:
        """Label of the lower floor: True when the drop is small enough to drive down."""
        return self.depth_m <= self.max_drop_m

    def bounds(self) -> Bounds:
        """Unbounded."""
        return None

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Nearest hit among upper floor, riser and lower floor, and per-ray labels."""
        ox, _, oz = rays.origin
        with np.errstate(invalid='ignore'):
            t_up = _plane_t(oz, rays.dz)
            t_up[~(ox + t_up * rays.dx < self.x_m)] = np.inf
            t_low = _plane_t(oz + self.depth_m, rays.dz)
            t_low[~(ox + t_low * rays.dx >= self.x_m)] = np.inf
            t_riser = _plane_t(ox - self.x_m, rays.dx)
            z = oz + t_riser * rays.dz
            t_riser[~((z >= -self.depth_m) & (z <= 0.0))] = np.inf
        t = np.minimum(np.minimum(t_up, t_riser), t_low)
        labels = np.full(t.shape, _label(self.traversable), dtype=np.uint8)
        labels[t == t_up] = GT_TRAVERSABLE
        labels[(t == t_riser) & (t != t_up)] = GT_OBSTACLE
        return t, labels


@dataclass(frozen=True)
class NoiseModel:
    """Kinect v2 like sensor model (see the module docstring for the order of the steps).

    sigma(z) = depth_sigma_base_mm + depth_sigma_quad_mm_per_m2 * (z - depth_sigma_ref_m)^2
    [mm], z the true depth [m]. Rates are per-pixel probabilities.
    """

    depth_sigma_base_mm: float = 1.5
    depth_sigma_quad_mm_per_m2: float = 1.5
    depth_sigma_ref_m: float = 0.5
    dropout_rate: float = 0.0075
    dark_dropout_rate: float = 0.4
    border_px: int = 4
    min_range_m: float = 0.5
    max_range_m: float = 4.5

    def __post_init__(self) -> None:
        for name in ('depth_sigma_base_mm', 'depth_sigma_quad_mm_per_m2', 'depth_sigma_ref_m'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'NoiseModel: {name}={value!r} must be a finite number >= 0')
        for name in ('dropout_rate', 'dark_dropout_rate'):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f'NoiseModel: {name}={value!r} must be within [0, 1]')
        if isinstance(self.border_px, bool) or not isinstance(self.border_px, int) or \
                self.border_px < 0:
            raise ValueError(f'NoiseModel: border_px={self.border_px!r} must be an int >= 0')
        if not 0.0 <= self.min_range_m < self.max_range_m <= 65.535:
            raise ValueError(f'NoiseModel: need 0 <= min_range_m={self.min_range_m!r} < '
                             f'max_range_m={self.max_range_m!r} <= 65.535')

    def sigma_m(self, depth_m: np.ndarray) -> np.ndarray:
        """Depth noise standard deviation [m] at true depth depth_m [m]."""
        dz = np.asarray(depth_m) - self.depth_sigma_ref_m
        return 1e-3 * (self.depth_sigma_base_mm + self.depth_sigma_quad_mm_per_m2 * dz * dz)


#: The default sensor model (``noise=True``) and the exact one (``noise=False``).
KINECT_V2_NOISE = NoiseModel()
EXACT = NoiseModel(depth_sigma_base_mm=0.0, depth_sigma_quad_mm_per_m2=0.0, dropout_rate=0.0,
                   dark_dropout_rate=0.0, border_px=0)


@dataclass(frozen=True)
class Scene:
    """Primitives plus the default camera mount (height [m], pitch and roll [rad])."""

    name: str
    primitives: tuple[Primitive, ...]
    height_m: float = DEFAULT_HEIGHT_M
    pitch_rad: float = 0.0
    roll_rad: float = 0.0

    def __post_init__(self) -> None:
        _check_positive('Scene', height_m=self.height_m)
        for name in ('pitch_rad', 'roll_rad'):
            value = getattr(self, name)
            if not (math.isfinite(value) and abs(value) < math.pi / 2):
                raise ValueError(f'Scene: {name}={value!r} must be within (-pi/2, pi/2)')
        if not self.primitives:
            raise ValueError(f'Scene {self.name!r} has no primitives')


@dataclass(frozen=True)
class SceneFrame:
    """One rendered frame with its ground truth.

    depth_mm: (H, W) uint16 measured depth [mm], 0 = no return.
    depth_true_m: (H, W) float32 noise-free depth (optical z) of the nearest hit [m], 0 where
    no surface is hit within ``MAX_TRACE_M`` (no band, border or dropout applied).
    labels: (H, W) uint8 ``GT_*``; ``GT_NO_RETURN`` exactly where depth_mm == 0.
    points_ground: (H, W, 3) float32 true hit points, ground frame [m], NaN where no hit.
    hit_labels: (H, W) uint8 label of the hit surface whether or not the sensor returned it
    (``GT_NO_RETURN`` only where nothing is hit).
    hit_index: (H, W) int16 index into ``primitives`` of the hit primitive, -1 where none.
    """

    depth_mm: np.ndarray
    depth_true_m: np.ndarray
    labels: np.ndarray
    points_ground: np.ndarray
    intrinsics: Intrinsics
    height_m: float
    pitch_rad: float
    roll_rad: float
    name: str
    seed: int
    frame_index: int = 0
    hit_labels: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    hit_index: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.int16))
    primitives: tuple[Primitive, ...] = ()

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return self.depth_mm.shape[1], self.depth_mm.shape[0]

    @property
    def depth_m(self) -> np.ndarray:
        """(H, W) float32 measured depth [m], 0 = no return."""
        return self.depth_mm.astype(np.float32) * np.float32(1e-3)


def scene_params(frame: SceneFrame, base: DetectorParams | None = None) -> DetectorParams:
    """Return ``base`` (default ``DetectorParams()``) with the frame's camera mount."""
    return (base or DetectorParams()).replace(camera_height_m=frame.height_m,
                                              camera_pitch_rad=frame.pitch_rad,
                                              camera_roll_rad=frame.roll_rad)


def camera_rays(intrinsics: Intrinsics, size: tuple[int, int], height_m: float,
                pitch_rad: float, roll_rad: float) -> tuple[Rays, np.ndarray]:
    """Rays of every pixel, directions (H, W) each, and the optical->ground rotation (3, 3)."""
    width, height = size
    rot, trans = mount_transform(height_m, pitch_rad, roll_rad)
    ru = (np.arange(width, dtype=np.float64) - intrinsics.cx) / intrinsics.fx
    rv = (np.arange(height, dtype=np.float64) - intrinsics.cy) / intrinsics.fy
    components = []
    for k in range(3):
        d = np.empty((height, width))
        np.add((rot[k, 1] * rv + rot[k, 2])[:, None], (rot[k, 0] * ru)[None, :], out=d)
        components.append(d)
    origin = (float(trans[0]), float(trans[1]), float(trans[2]))
    return Rays(origin, *components), rot


def _image_window(bounds: Bounds, rays: Rays, rot: np.ndarray, intrinsics: Intrinsics,
                  size: tuple[int, int]) -> tuple[slice, slice] | None:
    """Pixel window (rows, cols) holding the image of ``bounds``; None when it is empty.

    The whole image when the bounds are unbounded or reach behind the near plane. The image of
    a convex body in front of the camera lies in the convex hull of its box corners' images.
    """
    width, height = size
    everything = (slice(0, height), slice(0, width))
    if bounds is None:
        return everything
    lo, hi = bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])]) - np.array(rays.origin)
    optical = corners @ rot   # rows: R^T (p - t)
    if np.any(optical[:, 2] < _NEAR_M):
        return everything
    u = intrinsics.fx * optical[:, 0] / optical[:, 2] + intrinsics.cx
    v = intrinsics.fy * optical[:, 1] / optical[:, 2] + intrinsics.cy
    u0, u1 = max(int(math.floor(u.min())) - 1, 0), min(int(math.ceil(u.max())) + 2, width)
    v0, v1 = max(int(math.floor(v.min())) - 1, 0), min(int(math.ceil(v.max())) + 2, height)
    if u0 >= u1 or v0 >= v1:
        return None
    return slice(v0, v1), slice(u0, u1)


def _check_render_args(seed: int, size: tuple[int, int], frame_index: int) -> None:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f'seed={seed!r} must be an int >= 0')
    if isinstance(frame_index, bool) or not isinstance(frame_index, (int, np.integer)) or \
            frame_index < 0:
        raise ValueError(f'frame_index={frame_index!r} must be an int >= 0')
    if len(size) != 2 or any(isinstance(n, bool) or not isinstance(n, (int, np.integer))
                             or n < 1 for n in size):
        raise ValueError(f'size={size!r} must be (width, height), positive ints')


def _posed_rays(rays: Rays, rot: np.ndarray, pose: tuple[float, float, float],
                ) -> tuple[Rays, np.ndarray]:
    """Move base-frame rays and rotation to a robot at ``pose`` (x, y, yaw) in the scene."""
    x, y, yaw = (float(v) for v in pose)
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise ValueError(f'pose={pose!r} must be finite (x [m], y [m], yaw [rad])')
    c, s = math.cos(yaw), math.sin(yaw)
    ox, oy, oz = rays.origin
    yaw_rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rays((x + c * ox - s * oy, y + s * ox + c * oy, oz), c * rays.dx - s * rays.dy,
                s * rays.dx + c * rays.dy, rays.dz), yaw_rot @ rot


def render(scene: Scene, *, seed: int = 0, intrinsics: Intrinsics = KINECT_V2_SD,
           size: tuple[int, int] = KINECT_V2_SD_SIZE, noise: bool | NoiseModel = True,
           frame_index: int = 0, pose: tuple[float, float, float] | None = None,
           ) -> SceneFrame:
    """Ray-cast ``scene`` from its mount and apply the sensor model (see module docstring).

    noise: True for ``KINECT_V2_NOISE``, False for ``EXACT``, or a ``NoiseModel``. The noise
    generator is seeded by ``(seed, frame_index)``: equal arguments give equal frames.
    size: (width, height) [px]. pose: the robot's base frame in the scene's frame, (x [m],
    y [m], yaw [rad]) (a sequence's world, e.g. odom); None = the scene frame is the base
    frame. The primitives stay where they are in the scene; ``points_ground`` is always in
    the robot's base frame.
    """
    _check_render_args(seed, size, frame_index)
    model = noise if isinstance(noise, NoiseModel) else (KINECT_V2_NOISE if noise else EXACT)
    width, height = size
    size = (int(width), int(height))
    rays, rot = camera_rays(intrinsics, size, scene.height_m, scene.pitch_rad, scene.roll_rad)
    if pose is not None:
        rays, rot = _posed_rays(rays, rot, pose)

    best_t = np.full((height, width), np.inf)
    hit_index = np.full((height, width), -1, dtype=np.int16)
    label_lut = np.array([_label(p.traversable) for p in scene.primitives] + [GT_NO_RETURN],
                         dtype=np.uint8)
    own_labels = []   # (index, window, per-ray labels) of primitives with mixed labels
    for i, primitive in enumerate(scene.primitives):
        window = _image_window(primitive.bounds(), rays, rot, intrinsics, size)
        if window is None:
            continue
        t, label = primitive.intersect(rays.window(*window))
        closer = t < best_t[window]
        np.copyto(best_t[window], t, where=closer)
        np.copyto(hit_index[window], i, where=closer)
        if isinstance(label, np.ndarray):
            own_labels.append((i, window, label))
    hit_index[~(best_t <= MAX_TRACE_M)] = -1
    hit = hit_index >= 0
    hit_labels = label_lut[hit_index]
    for i, window, label in own_labels:
        np.copyto(hit_labels[window], label, where=hit_index[window] == i)

    depth_true = np.where(hit, best_t, 0.0)
    t_or_nan = np.where(hit, best_t, np.nan)   # nan propagates to the points of missed rays
    points = np.empty((height, width, 3), dtype=np.float32)
    for k, (o, d) in enumerate(zip(rays.origin, (rays.dx, rays.dy, rays.dz))):
        points[:, :, k] = o + t_or_nan * d
    if pose is not None:   # scene frame -> the robot's base frame
        c, s = math.cos(float(pose[2])), math.sin(float(pose[2]))
        px = points[:, :, 0] - np.float32(pose[0])
        py = points[:, :, 1] - np.float32(pose[1])
        points[:, :, 0] = np.float32(c) * px + np.float32(s) * py
        points[:, :, 1] = np.float32(-s) * px + np.float32(c) * py

    rng = np.random.default_rng([int(seed), int(frame_index), 0x4015E])
    measured_mm = depth_true * 1e3
    if model.depth_sigma_base_mm > 0.0 or model.depth_sigma_quad_mm_per_m2 > 0.0:
        offset = depth_true.astype(np.float32) - np.float32(model.depth_sigma_ref_m)
        sigma_mm = np.float32(model.depth_sigma_quad_mm_per_m2) * offset * offset
        sigma_mm += np.float32(model.depth_sigma_base_mm)
        sigma_mm *= rng.standard_normal((height, width), dtype=np.float32)
        measured_mm += sigma_mm
    np.rint(measured_mm, out=measured_mm)
    lo, hi = round(model.min_range_m * 1e3), round(model.max_range_m * 1e3)
    valid = hit & (measured_mm >= lo) & (measured_mm <= hi)
    if model.dropout_rate > 0.0 or model.dark_dropout_rate > 0.0:
        dark = np.array([p.dark for p in scene.primitives] + [False])
        rates = np.where(dark, model.dark_dropout_rate, model.dropout_rate).astype(np.float32)
        valid &= rng.random((height, width), dtype=np.float32) >= rates[hit_index]
    b = model.border_px
    if b:
        valid[:b, :] = False
        valid[-b:, :] = False
        valid[:, :b] = False
        valid[:, -b:] = False
    depth_mm = np.where(valid, measured_mm, 0.0).astype(np.uint16)
    labels = np.where(valid, hit_labels, GT_NO_RETURN).astype(np.uint8)
    return SceneFrame(
        depth_mm=depth_mm, depth_true_m=depth_true.astype(np.float32), labels=labels,
        points_ground=points, intrinsics=intrinsics, height_m=scene.height_m,
        pitch_rad=scene.pitch_rad, roll_rad=scene.roll_rad, name=scene.name, seed=int(seed),
        frame_index=int(frame_index), hit_labels=hit_labels, hit_index=hit_index,
        primitives=scene.primitives)


# -- named scenes -----------------------------------------------------------------------------

def _corridor_walls(rng: np.random.Generator, **left_kwargs: bool) -> tuple[Wall, Wall, float]:
    half = 0.7 + rng.uniform(-0.05, 0.05)      # 1.3-1.5 m apart: in view from ~1 m ahead
    left = Wall(-1.0, half, 12.0, half, 0.0, 2.5, **left_kwargs)
    right = Wall(-1.0, -half, 12.0, -half, 0.0, 2.5)
    return left, right, half


def _corridor(rng: np.random.Generator, frame_index: int) -> Scene:
    left, right, _ = _corridor_walls(rng)
    boxes = (
        Box.on_floor(0.9 + rng.uniform(0.0, 0.1), 0.25 + rng.uniform(-0.05, 0.05),
                     0.3, 0.3, 0.25 + rng.uniform(0.0, 0.05)),
        Box.on_floor(1.4 + rng.uniform(-0.05, 0.05), -0.3 + rng.uniform(-0.05, 0.05),
                     0.4, 0.3, 0.45 + rng.uniform(0.0, 0.05)),
        Box.on_floor(1.85 + rng.uniform(-0.05, 0.05), 0.2 + rng.uniform(-0.05, 0.05),
                     0.25, 0.25, 0.2 + rng.uniform(0.0, 0.05)),
    )
    return Scene('corridor', (Floor(), left, right) + boxes)


def _ramps(rng: np.random.Generator, frame_index: int) -> Scene:
    gentle = Ramp(x_start_m=1.1 + rng.uniform(-0.05, 0.05), y_center_m=0.45, width_m=0.7,
                  length_m=1.5, slope_rad=math.radians(15.0))
    steep = Ramp(x_start_m=1.2 + rng.uniform(-0.05, 0.05), y_center_m=-0.45, width_m=0.7,
                 length_m=0.8, slope_rad=math.radians(45.0))
    return Scene('ramps', (Floor(), gentle, steep))


def _people(rng: np.random.Generator, frame_index: int) -> Scene:
    count = 2 + int(rng.integers(0, 2))
    slots = [(1.6, 0.6), (2.2, -0.5), (3.0, 0.1)]
    people = tuple(
        Cylinder(x + rng.uniform(-0.1, 0.1), y + rng.uniform(-0.1, 0.1),
                 radius_m=0.2 + rng.uniform(-0.02, 0.02), height_m=1.7 + rng.uniform(-0.1, 0.1))
        for x, y in slots[:count])
    return Scene('people', (Floor(),) + people)


def _farm_row(rng: np.random.Generator, frame_index: int) -> Scene:
    ground = Floor(bump_amplitude_m=0.03, bump_wavelength_m=1.5,
                   bump_phase_rad=tuple(float(p) for p in rng.uniform(0, 2 * math.pi, 3)))
    trunks = []
    for row_y in (0.75, -0.75):
        for i in range(7):
            trunks.append(Cylinder(1.0 + 0.8 * i + rng.uniform(-0.05, 0.05),
                                   row_y + rng.uniform(-0.05, 0.05),
                                   radius_m=0.1 + rng.uniform(-0.02, 0.02), height_m=1.6,
                                   base_z_m=-0.1))
    return Scene('farm_row', (ground,) + tuple(trunks))


def _pitched_floor(rng: np.random.Generator, frame_index: int) -> Scene:
    return Scene('pitched_floor', (Floor(),), pitch_rad=math.radians(30.0))


def _flat_floor(rng: np.random.Generator, frame_index: int) -> Scene:
    return Scene('flat_floor', (Floor(),))


def _step_down(rng: np.random.Generator, frame_index: int) -> Scene:
    step = StepDown(x_m=1.25 + rng.uniform(-0.03, 0.03), depth_m=0.3)
    box = Box.on_floor(0.9, -0.35 + rng.uniform(-0.05, 0.05), 0.25, 0.3, 0.3)
    return Scene('step_down', (step, box))


def _dark_materials(rng: np.random.Generator, frame_index: int) -> Scene:
    left, right, _ = _corridor_walls(rng, dark=True)
    boxes = (
        Box.on_floor(1.1 + rng.uniform(-0.05, 0.05), 0.2 + rng.uniform(-0.05, 0.05),
                     0.35, 0.35, 0.4, dark=True),
        Box.on_floor(1.6 + rng.uniform(-0.05, 0.05), -0.3 + rng.uniform(-0.05, 0.05),
                     0.3, 0.3, 0.3),
    )
    return Scene('dark_materials', (Floor(), left, right) + boxes)


def _person_walking(rng: np.random.Generator, frame_index: int) -> Scene:
    x = 2.0 + rng.uniform(-0.1, 0.1)
    # y from +WALK_SPAN_M / 2 (left, out of view) to -WALK_SPAN_M / 2, then again; frame 0 has
    # the person in view at y = +1.0 m
    walked = 0.6 + rng.uniform(-0.05, 0.05) + WALK_SPEED_M_S * frame_index / WALK_FRAME_RATE_HZ
    y = WALK_SPAN_M / 2 - walked % WALK_SPAN_M
    wall = Wall(3.6, 4.0, 3.6, -4.0, 0.0, 2.5)
    person = Cylinder(x, y, radius_m=0.2, height_m=1.75)
    return Scene('person_walking', (Floor(), wall, person))


_BUILDERS: dict[str, Callable[[np.random.Generator, int], Scene]] = {
    'corridor': _corridor,
    'ramps': _ramps,
    'people': _people,
    'farm_row': _farm_row,
    'pitched_floor': _pitched_floor,
    'flat_floor': _flat_floor,
    'step_down': _step_down,
    'dark_materials': _dark_materials,
    'person_walking': _person_walking,
}

#: Names accepted by ``build_scene`` and ``render_scene``.
SCENE_NAMES: tuple[str, ...] = tuple(_BUILDERS)


def build_scene(name: str, *, seed: int = 0, frame_index: int = 0) -> Scene:
    """Return the named scene's primitives and default mount; positions jitter with ``seed``.

    Only 'person_walking' depends on ``frame_index``: a person about 2 m ahead walks from left
    to right (ground y decreasing, image column increasing) at ``WALK_SPEED_M_S``, one frame
    every 1 / ``WALK_FRAME_RATE_HZ`` s, starting in view at y = +1.0 m. Each crossing spans
    ``WALK_SPAN_M`` (y = +1.6 to -1.6 m, the edges of a Kinect v2 view at 2 m), then the next
    one starts on the left.
    """
    if name not in _BUILDERS:
        raise ValueError(f'unknown scene {name!r}; known: {", ".join(SCENE_NAMES)}')
    _check_render_args(seed, (1, 1), frame_index)
    rng = np.random.default_rng([int(seed), 0x5CE7E])
    return _BUILDERS[name](rng, int(frame_index))


def render_scene(name: str, *, seed: int = 0, intrinsics: Intrinsics = KINECT_V2_SD,
                 size: tuple[int, int] = KINECT_V2_SD_SIZE, height_m: float | None = None,
                 pitch_rad: float | None = None, roll_rad: float | None = None,
                 noise: bool | NoiseModel = True, frame_index: int = 0) -> SceneFrame:
    """Render a named scene (``SCENE_NAMES``); mount arguments override its defaults.

    Raises ValueError for an unknown name, a bad seed, size or frame index, or a bad mount.
    """
    scene = build_scene(name, seed=seed, frame_index=frame_index)
    overrides = {key: value for key, value in
                 (('height_m', height_m), ('pitch_rad', pitch_rad), ('roll_rad', roll_rad))
                 if value is not None}
    if overrides:
        scene = Scene(scene.name, scene.primitives, **{
            'height_m': scene.height_m, 'pitch_rad': scene.pitch_rad,
            'roll_rad': scene.roll_rad, **overrides})
    return render(scene, seed=seed, intrinsics=intrinsics, size=size, noise=noise,
                  frame_index=frame_index)
