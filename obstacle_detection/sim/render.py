"""Ray-cast depth frames with a ground-truth label per pixel (tests, benchmark, demo)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from obstacle_detection.labels import GT_NO_RETURN
from obstacle_detection.pipeline.geometry import mount_transform
from obstacle_detection.pipeline.params import (DetectorParams, Intrinsics, KINECT_V2_SD,
                                                KINECT_V2_SD_SIZE)

from .noise import EXACT, KINECT_V2_NOISE, NoiseModel, measure
from .primitives import MAX_TRACE_M, Bounds, Primitive, Rays, check, label_of
from .truth import TruthRules, robot_labels

#: Near plane [m] for projecting a primitive's bounding box into the image.
_NEAR_M = 0.05

@dataclass(frozen=True)
class Scene:
    """Primitives plus the default camera mount (height [m], pitch and roll [rad])."""

    name: str
    primitives: tuple[Primitive, ...]
    height_m: float = 0.6
    pitch_rad: float = 0.0
    roll_rad: float = 0.0

    def __post_init__(self) -> None:
        check('Scene', 'a finite number > 0', lambda v: v > 0.0, height_m=self.height_m)
        check('Scene', 'within (-pi/2, pi/2)', lambda v: abs(v) < math.pi / 2,
              pitch_rad=self.pitch_rad, roll_rad=self.roll_rad)


@dataclass(frozen=True)
class SceneFrame:
    """One rendered frame with its ground truth (H, W arrays; docs/scenes.md).

    depth_mm: measured [mm], 0 = no return; depth_true_m: noise-free depth, 0 where no hit;
    labels / labels_seed: robot-level / seed truth ``GT_*``, ``GT_NO_RETURN`` where depth_mm is 0
    or the pixel flies; points_ground: true hit points, base frame [m], NaN where no hit;
    hit_labels: the hit surface's robot-level label; hit_index: primitive hit (int16), -1 none;
    flying: mixed pixels; drop_edge: reachable ground at a drop's edge.
    """

    depth_mm: np.ndarray
    depth_true_m: np.ndarray
    labels: np.ndarray
    points_ground: np.ndarray
    intrinsics: Intrinsics
    height_m: float
    pitch_rad: float
    roll_rad: float
    hit_labels: np.ndarray
    hit_index: np.ndarray
    primitives: tuple[Primitive, ...]
    labels_seed: np.ndarray
    flying: np.ndarray
    drop_edge: np.ndarray

    @property
    def object_names(self) -> tuple[str, ...]:
        """Name of each primitive ('' = unnamed); primitives of one name form one object."""
        return tuple(p.name for p in self.primitives)


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
    """Pixel window (rows, cols) holding the image of ``bounds``; None when it is empty."""
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


def check_count(name: str, value: int) -> int:
    """Return ``value`` as an int; ValueError unless it is an int (not a bool) >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f'{name}={value!r} must be an int >= 0')
    return int(value)


def check_render_args(seed: int, size: tuple[int, int], frame_index: int) -> None:
    check_count('seed', seed)
    check_count('frame_index', frame_index)
    if len(size) != 2 or any(isinstance(n, bool) or not isinstance(n, (int, np.integer))
                             or n < 1 for n in size):
        raise ValueError(f'size={size!r} must be (width, height), positive ints')


def _posed_rays(rays: Rays, rot: np.ndarray, pose: tuple[float, float, float],
                ) -> tuple[Rays, np.ndarray]:
    """Move base-frame rays and rotation to a robot at ``pose`` (x, y, yaw) in the scene."""
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    ox, oy, oz = rays.origin
    yaw_rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rays((x + c * ox - s * oy, y + s * ox + c * oy, oz), c * rays.dx - s * rays.dy,
                s * rays.dx + c * rays.dy, rays.dz), yaw_rot @ rot


def _nearest_hits(scene: Scene, rays: Rays, rot: np.ndarray, intrinsics: Intrinsics,
                  size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hit per pixel: (ray parameter, primitive index, seed label)."""
    width, height = size
    best_t = np.full((height, width), np.inf)
    hit_index = np.full((height, width), -1, dtype=np.int16)
    label_lut = np.array([label_of(p.traversable) for p in scene.primitives] + [GT_NO_RETURN],
                         dtype=np.uint8)
    own_labels = []   # (index, window, per-ray labels) of primitives with mixed labels
    for i, primitive in enumerate(scene.primitives):
        window = _image_window(primitive.bounds(), rays, rot, intrinsics, size)
        if window is None:
            continue
        t, label = primitive.intersect(Rays(rays.origin, rays.dx[window], rays.dy[window],
                                            rays.dz[window]))
        closer = t < best_t[window]
        np.copyto(best_t[window], t, where=closer)
        np.copyto(hit_index[window], i, where=closer)
        if isinstance(label, np.ndarray):
            own_labels.append((i, window, label))
    hit_index[~(best_t <= MAX_TRACE_M)] = -1
    hit_labels_seed = label_lut[hit_index]
    for i, window, label in own_labels:
        np.copyto(hit_labels_seed[window], label, where=hit_index[window] == i)

    return best_t, hit_index, hit_labels_seed


def render(scene: Scene, *, seed: int = 0, intrinsics: Intrinsics = KINECT_V2_SD,
           size: tuple[int, int] = KINECT_V2_SD_SIZE, noise: bool | NoiseModel = True,
           frame_index: int = 0, pose: tuple[float, float, float] | None = None,
           rules: TruthRules | DetectorParams | None = None,
           ) -> SceneFrame:
    """Ray-cast ``scene`` from its mount and apply the sensor model.

    noise: True (``KINECT_V2_NOISE``), False (``EXACT``) or a ``NoiseModel``, seeded by
    ``(seed, frame_index)``; pose: the robot's (x, y, yaw) in the scene (None: at the origin);
    rules: ``TruthRules`` or detector parameters (None: the defaults).
    """
    check_render_args(seed, size, frame_index)
    model = noise if isinstance(noise, NoiseModel) else (KINECT_V2_NOISE if noise else EXACT)
    rules = TruthRules() if rules is None else TruthRules.from_params(rules)
    width, height = size
    size = (int(width), int(height))
    rays, rot = camera_rays(intrinsics, size, scene.height_m, scene.pitch_rad, scene.roll_rad)
    if pose is not None:
        rays, rot = _posed_rays(rays, rot, pose)

    best_t, hit_index, hit_labels_seed = _nearest_hits(scene, rays, rot, intrinsics, size)
    hit = hit_index >= 0
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

    dark = np.array([p.dark for p in scene.primitives] + [False])
    depth_mm, valid, flying = measure(depth_true, hit_index, dark, model,
                                      (int(seed), int(frame_index)))
    flying &= valid
    scored = valid & ~flying
    labels = np.where(scored, hit_labels, GT_NO_RETURN).astype(np.uint8)
    labels_seed = np.where(scored, hit_labels_seed, GT_NO_RETURN).astype(np.uint8)
    return SceneFrame(
        depth_mm=depth_mm, depth_true_m=depth_true.astype(np.float32), labels=labels,
        points_ground=points, intrinsics=intrinsics, height_m=scene.height_m,
        pitch_rad=scene.pitch_rad, roll_rad=scene.roll_rad, hit_labels=hit_labels,
        hit_index=hit_index, primitives=scene.primitives, labels_seed=labels_seed,
        flying=flying, drop_edge=drop_edge)
