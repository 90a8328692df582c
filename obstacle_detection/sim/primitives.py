"""The primitives of the ray-cast scene generator, in the ground frame [m] (docs/scenes.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Union

import numpy as np

from obstacle_detection.labels import GT_OBSTACLE, GT_TRAVERSABLE

#: Hits farther than this ray parameter (depth) [m] count as no hit (the horizon).
MAX_TRACE_M = 50.0
#: The bumpy floor is root-found up to this depth [m]; beyond it, its hit is the flat z = 0 one.
BUMPY_TRACE_M = 12.0
#: Regula falsi steps refining each bumpy-floor hit after the march.
REFINE_STEPS = 4

_EPS_T = 1e-9


@dataclass(frozen=True)
class Rays:
    """Camera rays in the ground frame: one origin, directions with optical z = 1 (t = depth)."""

    origin: tuple[float, float, float]
    dx: np.ndarray
    dy: np.ndarray
    dz: np.ndarray


#: A primitive's hit labels: one label for every hit, or an array of one per ray.
LabelValue = Union[int, np.ndarray]
#: Axis-aligned bounds ((x_min, y_min, z_min), (x_max, y_max, z_max)) [m], None if unbounded.
Bounds = Union[tuple[tuple[float, float, float], tuple[float, float, float]], None]


@dataclass(frozen=True)
class Patch:
    """A drivable planar piece of a primitive: ``z = z0_m + rise * (x - x0_m)`` [m].

    ``tolerance_m``: how far the real surface may lie off it; ``owner``: its primitive's index.
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


def label_of(traversable: bool) -> int:
    return GT_TRAVERSABLE if traversable else GT_OBSTACLE


def check(owner: str, rule: str, ok: Callable[[float], bool], **values: float) -> None:
    """Raise ValueError naming ``owner`` and ``rule`` unless each value is finite and ``ok``."""
    for name, value in values.items():
        if not (math.isfinite(value) and ok(value)):
            raise ValueError(f'{owner}: {name}={value!r} must be {rule}')


def _plane_t(offset: float, rate: np.ndarray) -> np.ndarray:
    """Return t solving ``offset + t * rate = 0``; inf if parallel or behind the camera."""
    with np.errstate(divide='ignore', invalid='ignore'):
        t = np.divide(-offset, rate)
    t[~(t > _EPS_T)] = np.inf
    return t


@dataclass(frozen=True, kw_only=True)
class Primitive:
    """What the renderer needs from a primitive; ``dark``: the sensor's dark-surface model."""

    dark: bool = False
    name: str = ''
    traversable = False

    def bounds(self) -> Bounds:
        """Axis-aligned bounds used to cull rays, None for an unbounded primitive."""
        return None

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """Ray parameter of the first hit, shaped like rays.dx (inf where none), and label(s)."""
        raise NotImplementedError

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Its surfaces a robot could drive on (upward, slope <= max_slope_rad), if reached."""
        return ()

    def _hit(self, t: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, LabelValue]:
        """Return ``t`` with inf where not ``inside``, and the primitive's label."""
        t[~inside] = np.inf
        return t, label_of(self.traversable)


@dataclass(frozen=True)
class Floor(Primitive):
    """Infinite ground z = 0, optionally bumpy: ``z = amplitude * f(x, y)``, ``|f| <= 1``."""

    bump_amplitude_m: float = 0.0
    bump_wavelength_m: float = 1.5
    bump_phase_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    traversable: bool = True

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return the whole plane z = 0, within the bump amplitude (gentler than theta)."""
        return (Patch(-math.inf, math.inf, -math.inf, math.inf, 0.0,
                      tolerance_m=self.bump_amplitude_m),)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground height z(x, y) [m] of a bumpy floor, shaped like x and y."""
        k = 2.0 * math.pi / self.bump_wavelength_m
        p0, p1, p2 = self.bump_phase_rad
        pattern = np.sin(k * x + p0)
        pattern *= np.cos((0.8 * k) * y + p1)
        pattern += np.sin((0.78 * k) * x - (1.04 * k) * y + p2)
        pattern *= 0.5 * self.bump_amplitude_m
        return pattern

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        """First hit: z = 0, or a march and regula falsi through the bumps' band."""
        ox, oy, oz = rays.origin
        label = label_of(self.traversable)
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
        dx, dy, dz = (d.reshape(-1)[active].astype(np.float32)
                      for d in (rays.dx, rays.dy, rays.dz))
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
class Box(Primitive):
    """Axis-aligned box between corners ``min_m`` and ``max_m`` (x, y, z) [m]; slab method."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    traversable: bool = False

    @classmethod
    def on_floor(cls, x_m: float, y_m: float, size_x_m: float, size_y_m: float,
                 size_z_m: float, **kwargs: Any) -> 'Box':
        """Return a box standing on z = 0, centred on (x_m, y_m), of the given sizes [m]."""
        return cls((x_m - size_x_m / 2, y_m - size_y_m / 2, 0.0),
                   (x_m + size_x_m / 2, y_m + size_y_m / 2, size_z_m), **kwargs)

    def bounds(self) -> Bounds:
        return self.min_m, self.max_m

    def walk_patches(self, max_slope_rad: float) -> tuple[Patch, ...]:
        """Return the top face."""
        (x0, y0, _), (x1, y1, z1) = self.min_m, self.max_m
        return (Patch(x0, x1, y0, y1, z1),)

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
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
        return self._hit(t_near, (t_near <= t_far) & (t_near > _EPS_T))


@dataclass(frozen=True)
class Wall(Primitive):
    """Vertical plane segment from (x0, y0) to (x1, y1), between z_min and z_max [m]."""

    x0_m: float
    y0_m: float
    x1_m: float
    y1_m: float
    z_min_m: float = 0.0
    z_max_m: float = 2.5
    traversable: bool = False

    def bounds(self) -> Bounds:
        return ((min(self.x0_m, self.x1_m), min(self.y0_m, self.y1_m), self.z_min_m),
                (max(self.x0_m, self.x1_m), max(self.y0_m, self.y1_m), self.z_max_m))

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        ex, ey = self.x1_m - self.x0_m, self.y1_m - self.y0_m
        length = math.hypot(ex, ey)
        ex, ey = ex / length, ey / length
        ox, oy, oz = rays.origin
        # plane: n . (p - p0) = 0 with the horizontal normal n = (-ey, ex)
        t = _plane_t(-ey * (ox - self.x0_m) + ex * (oy - self.y0_m), ex * rays.dy - ey * rays.dx)
        with np.errstate(invalid='ignore'):
            s = ex * (ox - self.x0_m + t * rays.dx) + ey * (oy - self.y0_m + t * rays.dy)
            z = oz + t * rays.dz
            return self._hit(t, (s >= 0.0) & (s <= length) & (z >= self.z_min_m)
                             & (z <= self.z_max_m))


@dataclass(frozen=True)
class Ramp(Primitive):
    """Planar strip rising from the floor: ``z = (x - x_start) tan(slope)``."""

    x_start_m: float
    y_center_m: float
    width_m: float
    length_m: float
    slope_rad: float

    @property
    def traversable(self) -> bool:
        """True when the slope is passable: no steeper than the seed's theta, pi/6."""
        return self.slope_rad <= math.pi / 6

    @property
    def top_height_m(self) -> float:
        """Height of the ramp's far edge [m]."""
        return self.length_m * math.tan(self.slope_rad)

    def bounds(self) -> Bounds:
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
        tan = math.tan(self.slope_rad)
        ox, oy, oz = rays.origin
        # plane: z - tan * (x - x_start) = 0
        t = _plane_t(oz - tan * (ox - self.x_start_m), rays.dz - tan * rays.dx)
        with np.errstate(invalid='ignore'):
            x = ox + t * rays.dx
            y = oy + t * rays.dy
            return self._hit(t, (x >= self.x_start_m) & (x <= self.x_start_m + self.length_m)
                             & (np.abs(y - self.y_center_m) <= self.width_m / 2))


@dataclass(frozen=True)
class RampSide(Primitive):
    """The open side of a solid ramp: a vertical triangle in the plane ``y = y_m``."""

    x_start_m: float
    y_m: float
    length_m: float
    slope_rad: float
    traversable: bool = False

    def bounds(self) -> Bounds:
        top = self.length_m * math.tan(self.slope_rad)
        return ((self.x_start_m, self.y_m, 0.0),
                (self.x_start_m + self.length_m, self.y_m, top))

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
        ox, oy, oz = rays.origin
        t = _plane_t(oy - self.y_m, rays.dy)
        with np.errstate(invalid='ignore'):
            x = ox + t * rays.dx
            z = oz + t * rays.dz
            return self._hit(t, (x >= self.x_start_m) & (x <= self.x_start_m + self.length_m)
                             & (z >= 0.0) & (z <= (x - self.x_start_m) * math.tan(self.slope_rad)))


@dataclass(frozen=True)
class Cylinder(Primitive):
    """Vertical cylinder (a person, a trunk) on (x_m, y_m), from base_z_m to base + height."""

    x_m: float
    y_m: float
    radius_m: float
    height_m: float
    base_z_m: float = 0.0
    traversable: bool = False

    def bounds(self) -> Bounds:
        r = self.radius_m
        return ((self.x_m - r, self.y_m - r, self.base_z_m),
                (self.x_m + r, self.y_m + r, self.base_z_m + self.height_m))

    def intersect(self, rays: Rays) -> tuple[np.ndarray, LabelValue]:
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
            t, label = self._hit(t, (t > _EPS_T) & (z >= z0) & (z <= z1))
        for cap_z in (z0, z1):
            t_cap = _plane_t(oz - cap_z, dz)
            with np.errstate(invalid='ignore'):
                px = t_cap * dx - cx
                py = t_cap * dy - cy
                t_cap[~(px * px + py * py <= r * r)] = np.inf
            np.minimum(t, t_cap, out=t)
        return t, label


@dataclass(frozen=True)
class StepDown(Primitive):
    """Floor at z = 0 for x < x_m, a drop of depth_m there, lower floor at z = -depth_m beyond.

    Use it instead of ``Floor``; the seed's label: the lower floor is an obstacle past 0.1 m.
    """

    x_m: float
    depth_m: float

    @property
    def traversable(self) -> bool:
        """Label of the lower floor: True when the drop is small enough to drive down."""
        return self.depth_m <= 0.1

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
        labels = np.full(t.shape, label_of(self.traversable), dtype=np.uint8)
        labels[t == t_up] = GT_TRAVERSABLE
        labels[(t == t_riser) & (t != t_up)] = GT_OBSTACLE
        return t, labels
