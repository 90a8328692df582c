"""Ray-cast depth frames with a ground-truth label per pixel (tests, benchmark, demo).

A scene is a tuple of primitives (floor, boxes, wall segments, ramps, vertical cylinders, a step
down; tables and chairs are made of boxes) in the ground frame (x forward, y left, z up, origin
on the ground under the camera) seen from a camera mounted at a height, pitch and roll. Every
pixel's ray is intersected with every primitive at once (numpy, no per-pixel loop); the nearest
hit wins and gives the pixel its true depth, its true ground-frame point, the index of the
primitive hit (``object_ids``; primitives may carry a ``name``, those of one name form one
object) and two labels:

* ``labels``, the robot-level truth (issue 9), computed from the primitives' geometry with
  ``TruthRules`` (theta, step up, step down, robot height; read from detector parameters when
  given). Each primitive offers its drivable patches (``walk_patches``: the floor, box and cap
  tops, ramps no steeper than theta, both floors of a step down); a breadth-first search from
  the patch under the robot over patches that touch with a height difference within a step up
  or down finds the reachable ones. A hit on a reachable patch is ``GT_TRAVERSABLE``, as is
  every hit on a primitive no higher than a step whose patches are all reachable (a door sill,
  its sides too); a hit higher than the robot above the reachable ground under it is
  ``GT_ABOVE_ROBOT``; every other hit is ``GT_OBSTACLE`` (walls, box and table tops and
  undersides, legs, curbs, too-steep ramps, people, trunks, the lower floor beyond a drop).
  ``drop_edge`` flags the reachable ground within ``DROP_EDGE_BAND_M`` of a drop: the truth
  costmap marks where the floor ends.
* ``labels_seed``, the seed's slope-only truth: each primitive's own ``traversable`` flag
  (boxes are obstacles, a ramp is ground up to its ``max_passable_slope_rad``, the lower floor
  of a step down deeper than its ``max_drop_m`` is an obstacle).

Rays use ``obstacle_detection.pipeline.geometry.mount_transform``, the pipeline's own
convention: the ray
of pixel (u, v) has the optical direction ``((u - cx)/fx, (v - cy)/fy, 1)``, ground-frame
direction ``R @`` that and origin ``(0, 0, height)``. Because the optical z component is 1, the
ray parameter t of a hit is its depth (optical z) in metres.

Sensor model (``NoiseModel``, Kinect v2 like; all draws from one generator seeded by
``(seed, frame_index)``, vectorised):

0. time-of-flight flying pixels (``KINECT_V2_TOF_NOISE``; off in the default model): a pixel
   within one pixel of a depth edge (true depths in its 3 x 3 window differ by more than
   5 cm and 8 % of the nearest) becomes a mix of the nearest and farthest depth of its window
   with probability 50 %, 25 % two pixels away (5 x 5 window). A flying pixel is not a
   surface: both labels are ``GT_NO_RETURN`` there (not scored), ``flying`` flags it, and
   ``points_ground`` keeps the ray's true hit;
1. Gaussian depth noise ``sigma(z) = sigma_base + sigma_quad * (z - z_ref)^2`` with defaults
   1.5 mm + 1.5 mm/m^2 * (z - 0.5 m)^2 (1.5 mm at 0.5 m, 4.9 mm at 2 m, 25.5 mm at 4.5 m),
   times ``dark_sigma_factor`` on a ``dark`` primitive (2 in the time-of-flight model);
2. millimetre quantisation (``depth_mm`` is uint16, rounded to nearest);
3. no return outside the valid band: quantised depth below 0.5 m or above 4.5 m becomes 0;
4. pepper dropouts: each pixel is set to 0 with probability 0.75 %, or 40 % on a primitive
   flagged ``dark`` (low-reflectance material), plus ``far_dropout_rate`` reached at 4.5 m,
   linearly from 3 m (10 % in the time-of-flight model);
5. an invalid border: the outer 4 pixel rows and columns are 0.

``noise=False`` keeps only steps 2 and 3 (exact depth, millimetre quantised, valid band).
``labels`` and ``labels_seed`` are ``GT_NO_RETURN`` wherever ``depth_mm`` is 0 or the pixel
flies, the hit's label elsewhere; ``depth_true_m`` and ``points_ground`` are always the
noise-free hit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Union

import cv2
import numpy as np

from obstacle_detection.labels import GT_ABOVE_ROBOT, GT_NO_RETURN, GT_OBSTACLE, GT_TRAVERSABLE
from obstacle_detection.pipeline.geometry import mount_transform
from obstacle_detection.pipeline.params import (DetectorParams, Intrinsics, KINECT_V2_SD,
                                                KINECT_V2_SD_SIZE)


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


@dataclass(frozen=True)
class Patch:
    """A drivable planar piece of a primitive: ``z = z0_m + rise * (x - x0_m)`` [m].

    It covers ``x0_m <= x <= x1_m``, ``y0_m <= y <= y1_m`` (ground frame, bounds may be
    infinite when ``rise`` is 0); ``tolerance_m`` is how far the real surface may lie off the
    plane (a bumpy floor's amplitude). ``owner`` is the index of its primitive in the scene.
    """

    x0_m: float
    x1_m: float
    y0_m: float
    y1_m: float
    z0_m: float
    rise: float = 0.0
    tolerance_m: float = 0.0
    owner: int = -1

    def z_at(self, x: np.ndarray) -> np.ndarray:
        """Height of the plane at ground x [m], shaped like x."""
        x = np.asarray(x, dtype=np.float64)
        if self.rise == 0.0:   # also where x0_m is infinite
            return np.full(x.shape, self.z0_m)
        return self.z0_m + self.rise * (x - self.x0_m)

    def covers(self, x: np.ndarray, y: np.ndarray, margin_m: float = 1e-6) -> np.ndarray:
        """Bool mask: (x, y) inside the patch's rectangle, grown by ``margin_m`` [m]."""
        return ((x >= self.x0_m - margin_m) & (x <= self.x1_m + margin_m)
                & (y >= self.y0_m - margin_m) & (y <= self.y1_m + margin_m))


class Primitive(Protocol):
    """What the renderer needs from a primitive."""

    dark: bool
    name: str

    @property
    def traversable(self) -> bool:
        """True when the primitive's (main) surface is ground the robot may drive on."""

    def bounds(self) -> Bounds:
        """Axis-aligned bounds used to cull rays, None for an unbounded primitive."""

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Ray parameter of the first hit, shaped like rays.dx (inf where none), and label(s)."""

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Its surfaces a robot could drive on (upward, slope <= max_slope_rad), if reached."""


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
    name: str = ''

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

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return the whole plane z = 0, within the bump amplitude (gentler than theta)."""
        return (Patch(-math.inf, math.inf, -math.inf, math.inf, 0.0,
                      tolerance_m=self.bump_amplitude_m),)

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
    name: str = ''

    def __post_init__(self) -> None:
        if len(self.min_m) != 3 or len(self.max_m) != 3:
            raise ValueError(f'Box: min_m={self.min_m!r}, max_m={self.max_m!r} need 3 values')
        for axis, lo, hi in zip('xyz', self.min_m, self.max_m):
            _check_finite('Box', **{f'min_{axis}': lo, f'max_{axis}': hi})
            if not lo < hi:
                raise ValueError(f'Box: min_{axis}={lo!r} must be below max_{axis}={hi!r}')

    @classmethod
    def on_floor(cls, x_m: float, y_m: float, size_x_m: float, size_y_m: float,
                 size_z_m: float, **kwargs: Any) -> 'Box':
        """Return a box standing on z = 0, centred on (x_m, y_m), of the given sizes [m]."""
        _check_positive('Box', size_x_m=size_x_m, size_y_m=size_y_m, size_z_m=size_z_m)
        return cls((x_m - size_x_m / 2, y_m - size_y_m / 2, 0.0),
                   (x_m + size_x_m / 2, y_m + size_y_m / 2, size_z_m), **kwargs)

    def bounds(self) -> Bounds:
        """Return the box itself."""
        return self.min_m, self.max_m

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return the top face."""
        (x0, y0, _), (x1, y1, z1) = self.min_m, self.max_m
        return (Patch(x0, x1, y0, y1, z1),)

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
    name: str = ''

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

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return nothing: a wall is vertical (its top edge has no area)."""
        return ()

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
    name: str = ''

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

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return the strip, when its slope is at most ``max_slope_rad``."""
        if self.slope_rad > max_slope_rad:
            return ()
        half = self.width_m / 2
        return (Patch(self.x_start_m, self.x_start_m + self.length_m, self.y_center_m - half,
                      self.y_center_m + half, 0.0, math.tan(self.slope_rad)),)

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
    name: str = ''

    def __post_init__(self) -> None:
        _check_finite('Cylinder', x_m=self.x_m, y_m=self.y_m, base_z_m=self.base_z_m)
        _check_positive('Cylinder', radius_m=self.radius_m, height_m=self.height_m)

    def bounds(self) -> Bounds:
        """Bounding box of the cylinder."""
        r = self.radius_m
        return ((self.x_m - r, self.y_m - r, self.base_z_m),
                (self.x_m + r, self.y_m + r, self.base_z_m + self.height_m))

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return the top cap, as its bounding square (for connectivity)."""
        r = self.radius_m
        return (Patch(self.x_m - r, self.x_m + r, self.y_m - r, self.y_m + r,
                      self.base_z_m + self.height_m),)

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
    name: str = ''

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

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return the upper (x <= x_m, z = 0) and lower floor (x >= x_m, z = -depth_m)."""
        return (Patch(-math.inf, self.x_m, -math.inf, math.inf, 0.0),
                Patch(self.x_m, math.inf, -math.inf, math.inf, -self.depth_m))

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


# -- robot-level truth ------------------------------------------------------------------------

#: Two drivable patches whose rectangles are closer than this touch (connectivity) [m].
TOUCH_M = 1e-3
#: A hit lies on a patch when it is within this of the patch plane (plus its tolerance) [m].
ON_PATCH_M = 1e-4
#: Width of the band of reachable ground before a drop whose cells the truth marks [m].
DROP_EDGE_BAND_M = 0.03


@dataclass(frozen=True)
class TruthRules:
    """The robot-level truth's parameters (issue 9; ``DetectorParams`` fields of one name).

    max_slope_rad: theta, steepest drivable slope; max_step_height_m / max_step_down_m: the
    largest step up / down the robot drives over [m]; robot_height_m: surfaces higher than this
    above the ground under them do not block the robot [m].
    """

    max_slope_rad: float = math.pi / 6
    max_step_height_m: float = 0.05
    max_step_down_m: float = 0.05
    robot_height_m: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 < self.max_slope_rad < math.pi / 2:
            raise ValueError(f'TruthRules: max_slope_rad={self.max_slope_rad!r} must be in '
                             '(0, pi/2)')
        for name in ('max_step_height_m', 'max_step_down_m'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'TruthRules: {name}={value!r} must be a finite number >= 0')
        _check_positive('TruthRules', robot_height_m=self.robot_height_m)

    @classmethod
    def from_params(cls, params: Any) -> 'TruthRules':
        """Rules from detector parameters; fields they lack (older params) keep the defaults."""
        default = cls()
        return cls(**{name: float(getattr(params, name, getattr(default, name)))
                      for name in ('max_slope_rad', 'max_step_height_m', 'max_step_down_m',
                                   'robot_height_m')})


def _connects(a: Patch, b: Patch, rules: TruthRules) -> bool:
    """Return True when the robot on patch ``a`` can drive onto patch ``b``.

    That is: their rectangles touch, and somewhere where they meet b is at most a step up or
    down from a.
    """
    x0, x1 = max(a.x0_m, b.x0_m), min(a.x1_m, b.x1_m)
    y0, y1 = max(a.y0_m, b.y0_m), min(a.y1_m, b.y1_m)
    if x0 > x1 + TOUCH_M or y0 > y1 + TOUCH_M:
        return False
    xs = np.array([v for v in (x0, x1) if math.isfinite(v)] or [0.0])
    dz = b.z_at(xs) - a.z_at(xs)   # planar patches: the extremes are at the x ends
    return bool(dz.min() <= rules.max_step_height_m and dz.max() >= -rules.max_step_down_m)


def scene_patches(primitives: tuple[Primitive, ...], rules: TruthRules,
                  ) -> tuple[list[Patch], list[bool]]:
    """Every drivable patch of the scene (``owner`` set) and whether the robot reaches it.

    The robot stands at the ground-frame origin: the patches under it (within a step of
    z = 0) are reached; from them, a breadth-first search over ``_connects``.
    """
    patches = [dataclasses.replace(patch, owner=i) for i, primitive in enumerate(primitives)
               for patch in primitive.walk_patches(rules.max_slope_rad)]
    origin = np.zeros(1)
    reached = [bool(p.covers(origin, origin)[0])
               and abs(float(p.z_at(origin)[0])) <= rules.max_step_height_m + p.tolerance_m
               for p in patches]
    todo = [i for i, r in enumerate(reached) if r]
    while todo:
        a = patches[todo.pop()]
        for j, b in enumerate(patches):
            if not reached[j] and _connects(a, b, rules):
                reached[j] = True
                todo.append(j)
    return patches, reached


def _vertical_extent_m(primitive: Primitive) -> float:
    bounds = primitive.bounds()
    if bounds is not None:
        return bounds[1][2] - bounds[0][2]
    depth = getattr(primitive, 'depth_m', None)   # a step down: the riser's height
    return float(depth) if depth is not None else math.inf


def robot_labels(points: np.ndarray, owner: np.ndarray, primitives: tuple[Primitive, ...],
                 rules: TruthRules) -> tuple[np.ndarray, np.ndarray]:
    """Robot-level truth of hit points: ``(labels (N,) uint8 GT_*, drop_edge (N,) bool)``.

    points: (N, 3) float64 hit points, ground frame [m]; owner: (N,) index of the primitive
    hit (>= 0). A point on a reached patch is traversable, as is every point of a primitive
    whose patches are all reached and whose height is at most a step (a door sill, its sides
    included); a point higher than ``robot_height_m`` above the reached ground under it (the
    highest reached patch below it, else z = 0) is ``GT_ABOVE_ROBOT``; everything else is an
    obstacle. ``drop_edge`` flags reached ground within ``DROP_EDGE_BAND_M`` of a drop: where a
    reached patch meets an unreached one lower by more than ``max_step_down_m``.
    """
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    patches, reached = scene_patches(primitives, rules)
    ground = np.zeros(x.shape)
    on_reached = np.zeros(x.shape, dtype=bool)
    for patch, ok in zip(patches, reached):
        if not ok:
            continue
        covered = patch.covers(x, y)
        plane = patch.z_at(x)
        below = covered & (plane <= z + 0.01)
        np.maximum(ground, np.where(below, plane, -np.inf), out=ground)
        on_reached |= (covered & (owner == patch.owner)
                       & (np.abs(z - plane) <= patch.tolerance_m + ON_PATCH_M))
    labels = np.where(z - ground > rules.robot_height_m, GT_ABOVE_ROBOT,
                      GT_OBSTACLE).astype(np.uint8)
    labels[on_reached] = GT_TRAVERSABLE
    for i, primitive in enumerate(primitives):
        own = [ok for patch, ok in zip(patches, reached) if patch.owner == i]
        if own and all(own) and _vertical_extent_m(primitive) <= rules.max_step_height_m:
            labels[owner == i] = GT_TRAVERSABLE
    drop_edge = np.zeros(x.shape, dtype=bool)
    for a, a_ok in zip(patches, reached):
        if not a_ok:
            continue
        for b, b_ok in zip(patches, reached):
            if b_ok or not _is_drop(a, b, rules):
                continue
            near = Patch(max(a.x0_m, b.x0_m) - DROP_EDGE_BAND_M,
                         min(a.x1_m, b.x1_m) + DROP_EDGE_BAND_M,
                         max(a.y0_m, b.y0_m) - DROP_EDGE_BAND_M,
                         min(a.y1_m, b.y1_m) + DROP_EDGE_BAND_M, 0.0)
            drop_edge |= (near.covers(x, y) & a.covers(x, y) & (owner == a.owner)
                          & (np.abs(z - a.z_at(x)) <= a.tolerance_m + ON_PATCH_M))
    return labels, drop_edge


def _is_drop(a: Patch, b: Patch, rules: TruthRules) -> bool:
    """Return True when b touches a and lies lower than it by more than a step down."""
    x0, x1 = max(a.x0_m, b.x0_m), min(a.x1_m, b.x1_m)
    y0, y1 = max(a.y0_m, b.y0_m), min(a.y1_m, b.y1_m)
    if x0 > x1 + TOUCH_M or y0 > y1 + TOUCH_M:
        return False
    xs = np.array([v for v in (x0, x1) if math.isfinite(v)] or [0.0])
    return bool((b.z_at(xs) - a.z_at(xs)).max() < -rules.max_step_down_m)


@dataclass(frozen=True)
class NoiseModel:
    """Kinect v2 like sensor model (see the module docstring for the order of the steps).

    sigma(z) = depth_sigma_base_mm + depth_sigma_quad_mm_per_m2 * (z - depth_sigma_ref_m)^2
    [mm], z the true depth [m], times ``dark_sigma_factor`` on a ``dark`` primitive. Rates are
    per-pixel probabilities; ``far_dropout_rate`` is added to the dropout rate in full at
    ``max_range_m``, linearly from ``far_dropout_start_m`` on. Flying pixels: a pixel within
    one pixel of a depth edge (3 x 3 window whose true depths differ by more than
    ``max(flying_jump_m, flying_jump_ratio * nearest)``) becomes one with probability
    ``flying_pixel_rate``, a pixel two pixels away (5 x 5 window) with half of it.
    """

    depth_sigma_base_mm: float = 1.5
    depth_sigma_quad_mm_per_m2: float = 1.5
    depth_sigma_ref_m: float = 0.5
    dropout_rate: float = 0.0075
    dark_dropout_rate: float = 0.4
    border_px: int = 4
    min_range_m: float = 0.5
    max_range_m: float = 4.5
    dark_sigma_factor: float = 1.0
    far_dropout_start_m: float = 3.0
    far_dropout_rate: float = 0.0
    flying_pixel_rate: float = 0.0
    flying_jump_m: float = 0.05
    flying_jump_ratio: float = 0.08

    def __post_init__(self) -> None:
        for name in ('depth_sigma_base_mm', 'depth_sigma_quad_mm_per_m2', 'depth_sigma_ref_m',
                     'dark_sigma_factor', 'far_dropout_start_m', 'flying_jump_m',
                     'flying_jump_ratio'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'NoiseModel: {name}={value!r} must be a finite number >= 0')
        for name in ('dropout_rate', 'dark_dropout_rate', 'far_dropout_rate',
                     'flying_pixel_rate'):
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
        """Depth noise standard deviation [m] at true depth depth_m [m] (not dark)."""
        dz = np.asarray(depth_m) - self.depth_sigma_ref_m
        return 1e-3 * (self.depth_sigma_base_mm + self.depth_sigma_quad_mm_per_m2 * dz * dz)

    def far_dropout(self, depth_m: np.ndarray) -> np.ndarray:
        """Extra dropout probability at true depth depth_m [m] (0 up to far_dropout_start_m)."""
        span = max(self.max_range_m - self.far_dropout_start_m, 1e-9)
        ramp = np.clip((np.asarray(depth_m) - self.far_dropout_start_m) / span, 0.0, 1.0)
        return self.far_dropout_rate * ramp


#: The default sensor model (``noise=True``) and the exact one (``noise=False``). The default
#: has no time-of-flight artefacts, so that numbers measured before issue 9 stay comparable.
KINECT_V2_NOISE = NoiseModel()
EXACT = NoiseModel(depth_sigma_base_mm=0.0, depth_sigma_quad_mm_per_m2=0.0, dropout_rate=0.0,
                   dark_dropout_rate=0.0, border_px=0)
#: With time-of-flight artefacts (issue 9): flying pixels at depth edges (half of the pixels
#: next to an edge, a quarter of those two pixels away), twice the noise on dark surfaces,
#: dropouts rising from 0.75 % at 3 m to 10.75 % at 4.5 m. The robot-level suite uses it.
KINECT_V2_TOF_NOISE = NoiseModel(dark_sigma_factor=2.0, far_dropout_rate=0.1,
                                 flying_pixel_rate=0.5)
#: Sensor models by the names scenario lists use.
NOISE_MODELS = {'kinect_v2': KINECT_V2_NOISE, 'kinect_v2_tof': KINECT_V2_TOF_NOISE,
                'exact': EXACT}


def depth_edges(depth_m: np.ndarray, hit: np.ndarray, model: NoiseModel, window_px: int,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels with a depth edge in their ``window_px`` square window, and its depth range.

    depth_m: (H, W) true depth [m]; hit: (H, W) bool, pixels with a surface (others take no
    part). Returns (edge (H, W) bool, nearest (H, W), farthest (H, W) depth in the window [m]).
    """
    kernel = np.ones((window_px, window_px), np.uint8)
    nearest = cv2.erode(np.where(hit, depth_m, np.inf), kernel, borderType=cv2.BORDER_REPLICATE)
    farthest = cv2.dilate(np.where(hit, depth_m, 0.0), kernel,
                          borderType=cv2.BORDER_REPLICATE)
    with np.errstate(invalid='ignore'):
        edge = hit & (farthest - nearest > np.maximum(model.flying_jump_m,
                                                      model.flying_jump_ratio * nearest))
    return edge, nearest, farthest


def flying_pixels(depth_m: np.ndarray, hit: np.ndarray, model: NoiseModel,
                  select: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time-of-flight mixed pixels at depth edges: ``(depth (H, W) [m], flying (H, W) bool)``.

    A flying pixel's depth is a mix of the nearest and farthest true depth of its window,
    ``near + w (far - near)`` with ``w = 0.1 + 0.8 * weight``; select and weight: (H, W)
    uniform [0, 1) draws. Other pixels keep their depth.
    """
    ring1, near1, far1 = depth_edges(depth_m, hit, model, 3)
    ring2, near2, far2 = depth_edges(depth_m, hit, model, 5)
    ring2 &= ~ring1
    flying = (ring1 & (select < model.flying_pixel_rate)) | \
        (ring2 & (select < 0.5 * model.flying_pixel_rate))
    near = np.where(ring1, near1, near2)
    far = np.where(ring1, far1, far2)
    with np.errstate(invalid='ignore'):   # inf - inf where nothing is hit: not used
        mixed = near + (0.1 + 0.8 * weight.astype(np.float64)) * (far - near)
    return np.where(flying, mixed, depth_m), flying


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
    labels: (H, W) uint8 robot-level truth ``GT_*`` (issue 9: traversable, obstacle,
    above the robot); ``GT_NO_RETURN`` exactly where depth_mm == 0 or ``flying``.
    labels_seed: (H, W) uint8 the seed's slope-only truth (``GT_TRAVERSABLE``/``GT_OBSTACLE``
    by each primitive's own flag), masked like ``labels``.
    points_ground: (H, W, 3) float32 true hit points, ground frame [m], NaN where no hit.
    hit_labels, hit_labels_seed: (H, W) uint8 robot-level / seed label of the hit surface
    whether or not the sensor returned it (``GT_NO_RETURN`` only where nothing is hit).
    hit_index: (H, W) int16 index into ``primitives`` of the hit primitive, -1 where none
    (also ``object_ids``).
    flying: (H, W) bool flying (mixed) pixels: a depth between a foreground and a background
    surface, not a surface: labelled ``GT_NO_RETURN`` (not scored), ``points_ground`` keeps
    the true hit of the ray.
    drop_edge: (H, W) bool hit points on reachable ground within ``DROP_EDGE_BAND_M`` of a
    drop (the truth costmap marks their cells).
    truth_rules: the rules ``labels`` were made with.
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
    labels_seed: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    hit_labels_seed: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    flying: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    drop_edge: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    truth_rules: TruthRules = field(default_factory=lambda: TruthRules())

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return self.depth_mm.shape[1], self.depth_mm.shape[0]

    @property
    def depth_m(self) -> np.ndarray:
        """(H, W) float32 measured depth [m], 0 = no return."""
        return self.depth_mm.astype(np.float32) * np.float32(1e-3)

    @property
    def object_ids(self) -> np.ndarray:
        """(H, W) int16 index of the primitive hit, -1 where none (``hit_index``)."""
        return self.hit_index

    @property
    def object_names(self) -> tuple[str, ...]:
        """Name of each primitive ('' = unnamed); primitives of one name form one object."""
        return tuple(p.name for p in self.primitives)


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
           rules: TruthRules | DetectorParams | None = None,
           ) -> SceneFrame:
    """Ray-cast ``scene`` from its mount and apply the sensor model (see module docstring).

    noise: True for ``KINECT_V2_NOISE``, False for ``EXACT``, or a ``NoiseModel``. The noise
    generator is seeded by ``(seed, frame_index)``: equal arguments give equal frames.
    size: (width, height) [px]. pose: the robot's base frame in the scene's frame, (x [m],
    y [m], yaw [rad]) (a sequence's world, e.g. odom); None = the scene frame is the base
    frame. The primitives stay where they are in the scene; ``points_ground`` is always in
    the robot's base frame. rules: the robot-level truth's ``TruthRules``, or detector
    parameters to read them from; None = ``TruthRules()`` (theta 30 deg, steps 0.05 m, robot
    1.0 m high).
    """
    _check_render_args(seed, size, frame_index)
    model = noise if isinstance(noise, NoiseModel) else (KINECT_V2_NOISE if noise else EXACT)
    if rules is None:
        rules = TruthRules()
    elif not isinstance(rules, TruthRules):
        rules = TruthRules.from_params(rules)
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
    hit_labels_seed = label_lut[hit_index]
    for i, window, label in own_labels:
        np.copyto(hit_labels_seed[window], label, where=hit_index[window] == i)

    depth_true = np.where(hit, best_t, 0.0)
    t_or_nan = np.where(hit, best_t, np.nan)   # nan propagates to the points of missed rays
    points64 = np.empty((height, width, 3))
    for k, (o, d) in enumerate(zip(rays.origin, (rays.dx, rays.dy, rays.dz))):
        points64[:, :, k] = o + t_or_nan * d

    hit_labels = np.full((height, width), GT_NO_RETURN, dtype=np.uint8)
    drop_edge = np.zeros((height, width), dtype=bool)
    robot, edge = robot_labels(points64[hit], hit_index[hit].astype(np.intp),
                               scene.primitives, rules)   # the truth lives in the scene frame
    hit_labels[hit] = robot
    drop_edge[hit] = edge
    if pose is not None:   # scene frame -> the robot's base frame
        c, s = math.cos(float(pose[2])), math.sin(float(pose[2]))
        px = points64[:, :, 0] - float(pose[0])
        py = points64[:, :, 1] - float(pose[1])
        points64[:, :, 0] = c * px + s * py
        points64[:, :, 1] = -s * px + c * py
    points = points64.astype(np.float32)

    rng = np.random.default_rng([int(seed), int(frame_index), 0x4015E])
    dark = np.array([p.dark for p in scene.primitives] + [False])
    on_dark = dark[hit_index]
    gauss = dropout_draw = None
    if model.depth_sigma_base_mm > 0.0 or model.depth_sigma_quad_mm_per_m2 > 0.0:
        gauss = rng.standard_normal((height, width), dtype=np.float32)
    if model.dropout_rate > 0.0 or model.dark_dropout_rate > 0.0 or \
            model.far_dropout_rate > 0.0:
        dropout_draw = rng.random((height, width), dtype=np.float32)
    flying = np.zeros((height, width), dtype=bool)
    measured_m = depth_true
    if model.flying_pixel_rate > 0.0:
        select = rng.random((height, width), dtype=np.float32)
        weight = rng.random((height, width), dtype=np.float32)
        measured_m, flying = flying_pixels(depth_true, hit, model, select, weight)
    measured_mm = measured_m * 1e3
    if gauss is not None:
        offset = measured_m.astype(np.float32) - np.float32(model.depth_sigma_ref_m)
        sigma_mm = np.float32(model.depth_sigma_quad_mm_per_m2) * offset * offset
        sigma_mm += np.float32(model.depth_sigma_base_mm)
        if model.dark_sigma_factor != 1.0:
            sigma_mm[on_dark] *= np.float32(model.dark_sigma_factor)
        sigma_mm *= gauss
        measured_mm += sigma_mm
    np.rint(measured_mm, out=measured_mm)
    lo, hi = round(model.min_range_m * 1e3), round(model.max_range_m * 1e3)
    valid = hit & (measured_mm >= lo) & (measured_mm <= hi)
    if dropout_draw is not None:
        rates = np.where(dark, model.dark_dropout_rate, model.dropout_rate).astype(np.float32)
        rate = rates[hit_index]
        if model.far_dropout_rate > 0.0:
            rate += model.far_dropout(depth_true).astype(np.float32)
        valid &= dropout_draw >= rate
    b = model.border_px
    if b:
        valid[:b, :] = False
        valid[-b:, :] = False
        valid[:, :b] = False
        valid[:, -b:] = False
    depth_mm = np.where(valid, measured_mm, 0.0).astype(np.uint16)
    flying &= valid
    scored = valid & ~flying
    labels = np.where(scored, hit_labels, GT_NO_RETURN).astype(np.uint8)
    labels_seed = np.where(scored, hit_labels_seed, GT_NO_RETURN).astype(np.uint8)
    return SceneFrame(
        depth_mm=depth_mm, depth_true_m=depth_true.astype(np.float32), labels=labels,
        points_ground=points, intrinsics=intrinsics, height_m=scene.height_m,
        pitch_rad=scene.pitch_rad, roll_rad=scene.roll_rad, name=scene.name, seed=int(seed),
        frame_index=int(frame_index), hit_labels=hit_labels, hit_index=hit_index,
        primitives=scene.primitives, labels_seed=labels_seed, hit_labels_seed=hit_labels_seed,
        flying=flying, drop_edge=drop_edge, truth_rules=rules)


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
                     0.3, 0.3, 0.25 + rng.uniform(0.0, 0.05), name='box_1'),
        Box.on_floor(1.4 + rng.uniform(-0.05, 0.05), -0.3 + rng.uniform(-0.05, 0.05),
                     0.4, 0.3, 0.45 + rng.uniform(0.0, 0.05), name='box_2'),
        Box.on_floor(1.85 + rng.uniform(-0.05, 0.05), 0.2 + rng.uniform(-0.05, 0.05),
                     0.25, 0.25, 0.2 + rng.uniform(0.0, 0.05), name='box_3'),
    )
    return Scene('corridor', (Floor(), left, right) + boxes)


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


def _farm_row(rng: np.random.Generator, frame_index: int) -> Scene:
    ground = Floor(bump_amplitude_m=0.03, bump_wavelength_m=1.5,
                   bump_phase_rad=tuple(float(p) for p in rng.uniform(0, 2 * math.pi, 3)))
    trunks = []
    for side, row_y in (('left', 0.75), ('right', -0.75)):
        for i in range(7):
            trunks.append(Cylinder(1.0 + 0.8 * i + rng.uniform(-0.05, 0.05),
                                   row_y + rng.uniform(-0.05, 0.05),
                                   radius_m=0.1 + rng.uniform(-0.02, 0.02), height_m=1.6,
                                   base_z_m=-0.1, name=f'trunk_{side}_{i + 1}'))
    return Scene('farm_row', (ground,) + tuple(trunks))


def _pitched_floor(rng: np.random.Generator, frame_index: int) -> Scene:
    return Scene('pitched_floor', (Floor(),), pitch_rad=math.radians(30.0))


def _flat_floor(rng: np.random.Generator, frame_index: int) -> Scene:
    return Scene('flat_floor', (Floor(),))


def _step_down(rng: np.random.Generator, frame_index: int) -> Scene:
    step = StepDown(x_m=1.25 + rng.uniform(-0.03, 0.03), depth_m=0.3, name='drop')
    box = Box.on_floor(0.9, -0.35 + rng.uniform(-0.05, 0.05), 0.25, 0.3, 0.3, name='box')
    return Scene('step_down', (step, box))


def _dark_materials(rng: np.random.Generator, frame_index: int) -> Scene:
    left, right, _ = _corridor_walls(rng, dark=True)
    boxes = (
        Box.on_floor(1.1 + rng.uniform(-0.05, 0.05), 0.2 + rng.uniform(-0.05, 0.05),
                     0.35, 0.35, 0.4, dark=True, name='dark_box'),
        Box.on_floor(1.6 + rng.uniform(-0.05, 0.05), -0.3 + rng.uniform(-0.05, 0.05),
                     0.3, 0.3, 0.3, name='box'),
    )
    return Scene('dark_materials', (Floor(), left, right) + boxes)


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
          top_m: float = 0.03, leg_m: float = 0.04, name: str = 'table',
          dark: bool = False) -> tuple[Box, ...]:
    """Return a table: a top ``top_m`` thick whose upper face is ``height_m`` up, four legs.

    Centred on (x_m, y_m), sizes [m]; every part carries ``name``.
    """
    _check_positive('table', size_x_m=size_x_m, size_y_m=size_y_m, height_m=height_m,
                    top_m=top_m, leg_m=leg_m)
    if not (top_m < height_m and 2 * leg_m < min(size_x_m, size_y_m)):
        raise ValueError(f'table {name!r}: top_m={top_m!r} must be below height_m='
                         f'{height_m!r} and two legs of {leg_m!r} narrower than the top')
    hx, hy = size_x_m / 2, size_y_m / 2
    parts = [Box((x_m - hx, y_m - hy, height_m - top_m), (x_m + hx, y_m + hy, height_m),
                 dark=dark, name=name)]
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            cx, cy = x_m + sx * (hx - leg_m / 2), y_m + sy * (hy - leg_m / 2)
            parts.append(Box((cx - leg_m / 2, cy - leg_m / 2, 0.0),
                             (cx + leg_m / 2, cy + leg_m / 2, height_m - top_m),
                             dark=dark, name=name))
    return tuple(parts)


def chair(x_m: float, y_m: float, *, seat_m: float = 0.42, seat_height_m: float = 0.46,
          back_height_m: float = 0.9, name: str = 'chair', dark: bool = False,
          ) -> tuple[Box, ...]:
    """Return a chair centred on (x_m, y_m): a square seat on four legs, its back at +x."""
    parts = table(x_m, y_m, seat_m, seat_m, seat_height_m, top_m=0.03, leg_m=0.03, name=name,
                  dark=dark)
    half = seat_m / 2
    back = Box((x_m + half - 0.03, y_m - half, seat_height_m),
               (x_m + half, y_m + half, back_height_m), dark=dark, name=name)
    return parts + (back,)


def _office(rng: np.random.Generator, frame_index: int, *, dark: bool = False) -> Scene:
    def jitter() -> float:
        return float(rng.uniform(-0.04, 0.04))

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
    ground = Floor(bump_amplitude_m=0.03, bump_wavelength_m=1.2,
                   bump_phase_rad=tuple(float(p) for p in rng.uniform(0, 2 * math.pi, 3)))
    trunks = []
    for side, row_y in (('left', 0.85), ('right', -0.85)):
        for i in range(6):
            trunks.append(Cylinder(1.2 + 0.9 * i + rng.uniform(-0.05, 0.05),
                                   row_y + rng.uniform(-0.05, 0.05),
                                   radius_m=0.08 + rng.uniform(-0.02, 0.02), height_m=1.9,
                                   base_z_m=-0.1, name=f'trunk_{side}_{i + 1}'))
    bushes = (Cylinder(1.5 + rng.uniform(-0.05, 0.05), -0.25 + rng.uniform(-0.05, 0.05),
                       radius_m=0.22, height_m=0.35 + rng.uniform(0.0, 0.1), base_z_m=-0.05,
                       name='bush_1'),
              Cylinder(1.85 + rng.uniform(-0.05, 0.05), 0.4 + rng.uniform(-0.05, 0.05),
                       radius_m=0.18, height_m=0.3 + rng.uniform(0.0, 0.1), base_z_m=-0.05,
                       name='bush_2'))
    return Scene('orchard', (ground,) + tuple(trunks) + bushes)


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
    'office': _office,
    'dark_office': _dark_office,
    'ramp_landing': _ramp_landing,
    'dock_edge': _dock_edge,
    'dock_edge_high': _dock_edge_high,
    'curb_sill': _curb_sill,
    'shelf': _shelf,
    'orchard': _orchard,
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
                 noise: bool | NoiseModel = True, frame_index: int = 0,
                 rules: TruthRules | DetectorParams | None = None) -> SceneFrame:
    """Render a named scene (``SCENE_NAMES``); mount arguments override its defaults.

    rules: the robot-level truth's rules (see ``render``).

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
                  frame_index=frame_index, rules=rules)
