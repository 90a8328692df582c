"""Estimate the camera mount (height, pitch, roll) from one depth frame by finding the floor.

The method and its limits: docs/method.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import back_project, mount_rotation
from .params import Intrinsics

#: Fewest valid points (within range) the estimate starts from.
MIN_POINTS = 500
#: Points in the subsample every candidate plane is scored against.
SCORE_POINTS = 4000
#: Most least-squares refinement rounds on the chosen plane's inliers (stops when they settle).
REFINE_ROUNDS = 12
#: A point more than this many ``INLIER_M`` below a candidate counts against it (step 3).
BELOW_MARGIN_INLIERS = 2.5
#: A candidate floor may have at most this many points below it per inlier.
MAX_BELOW_PER_INLIER = 0.1
#: Distance of a point to the plane that makes it an inlier [m].
INLIER_M = 0.02
#: Candidate planes (point triplets) of the RANSAC, drawn with a fixed seed.
ITERATIONS = 2000
#: Largest angle between the floor's normal and the expected up (60 deg).
MAX_TILT_RAD = math.radians(60.0)
#: Least share of the points the floor must hold.
MIN_INLIER_FRACTION = 0.03


@dataclass(frozen=True)
class MountEstimate:
    """The camera mount found from the floor plane; n_points: the valid points within range."""

    height_m: float
    pitch_rad: float
    roll_rad: float
    inlier_fraction: float
    n_points: int

    @property
    def pitch_deg(self) -> float:
        """Pitch [deg], positive looks down."""
        return math.degrees(self.pitch_rad)

    @property
    def roll_deg(self) -> float:
        """Roll [deg], positive lowers the image's right side."""
        return math.degrees(self.roll_rad)


def mount_from_plane(normal_optical: np.ndarray, offset_m: float) -> tuple[float, float, float]:
    """(height [m], pitch, roll [rad]) of the camera above the plane ``n . p + d = 0`` (n up)."""
    n = np.asarray(normal_optical, dtype=np.float64)
    norm = float(np.linalg.norm(n))
    n = n / norm
    pitch = math.atan2(-n[2], math.hypot(n[0], n[1]))
    roll = math.atan2(-n[0], -n[1])
    return float(offset_m) / norm, pitch, roll


def _triplets(pixel_index: np.ndarray, shape: tuple[int, int], n: int,
              rng: np.random.Generator) -> np.ndarray:
    """(k, 3) int64 point indices: n // 2 triplets anywhere, the others in a pixel window."""
    m = pixel_index.size
    height, width = shape
    n_global = n // 2
    global_ = rng.integers(0, m, size=(n_global, 3))
    lookup = np.full(height * width, -1, dtype=np.int64)
    lookup[pixel_index] = np.arange(m)
    n_local = n - n_global
    anchor = rng.integers(0, m, size=n_local)
    rows, cols = np.divmod(pixel_index[anchor], width)
    half = max(2, max(height, width) // 16)
    offsets = rng.integers(-half, half + 1, size=(n_local, 2, 2))
    r = np.clip(rows[:, None] + offsets[:, :, 0], 0, height - 1)
    c = np.clip(cols[:, None] + offsets[:, :, 1], 0, width - 1)
    partners = lookup[r * width + c]
    local = np.column_stack([anchor, partners])
    local = local[(partners >= 0).all(axis=1)]
    return np.vstack([global_, local])


def _candidate_planes(points: np.ndarray, triplets: np.ndarray) -> np.ndarray:
    """(k, 4) float64 planes (unit n, d >= 0) through the triplets, collinear ones dropped."""
    p0 = points[triplets[:, 0]].astype(np.float64)
    normals = np.cross(points[triplets[:, 1]] - p0, points[triplets[:, 2]] - p0)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    normals = normals[ok] / norms[ok, None]
    offsets = -np.einsum('ij,ij->i', normals, p0[ok])
    flip = offsets < 0.0
    normals[flip] *= -1.0
    offsets[flip] *= -1.0
    return np.column_stack([normals, offsets])


def _fit_plane(points: np.ndarray) -> np.ndarray:
    """(4,) least-squares plane (unit n, d) of (k, 3) points, d >= 0."""
    centroid = points.mean(axis=0, dtype=np.float64)
    _, _, vt = np.linalg.svd(points.astype(np.float64) - centroid, full_matrices=False)
    normal = vt[2]
    offset = -float(normal @ centroid)
    if offset < 0.0:
        normal, offset = -normal, -offset
    return np.append(normal, offset)


def estimate_mount(depth_m: np.ndarray, intrinsics: Intrinsics, *, max_range_m: float = 4.0,
                   prior_pitch_rad: float | None = None) -> MountEstimate:
    """Find the floor in a depth frame (H, W) [m] and return the camera mount above it.

    prior_pitch_rad: the expected pitch whose up the floor normal is sought around (else
    optical -y). Raises ValueError for a bad argument or no plausible floor.
    """
    if not 0.0 < max_range_m < math.inf:
        raise ValueError(f'max_range_m={max_range_m!r} must be a finite number > 0')
    if prior_pitch_rad is not None and not abs(prior_pitch_rad) < math.pi / 2:
        raise ValueError(f'prior_pitch_rad={prior_pitch_rad!r} must be in (-pi/2, pi/2)')
    depth = np.where(depth_m <= max_range_m, depth_m, 0.0).astype(np.float32)   # NaN: 0
    points, pixel_index = back_project(depth, intrinsics)
    n_points = int(points.shape[0])
    if n_points < MIN_POINTS:
        raise ValueError(f'too few points to find the floor: {n_points} valid pixels within '
                         f'{max_range_m} m, need {MIN_POINTS}')
    rng = np.random.default_rng(0)
    up = mount_rotation(prior_pitch_rad or 0.0, 0.0)[2]   # the floor's up, optical frame
    plane = _best_candidate(points, pixel_index, depth.shape, up, rng)
    previous = None
    for _ in range(REFINE_ROUNDS):
        near = np.abs(points @ plane[:3].astype(np.float32) + np.float32(plane[3])) <= INLIER_M
        if np.count_nonzero(near) < 3 or (previous is not None and np.array_equal(near,
                                                                                  previous)):
            break
        plane, previous = _fit_plane(points[near]), near
    residual = points @ plane[:3].astype(np.float32) + np.float32(plane[3])
    fraction = float(np.count_nonzero(np.abs(residual) <= INLIER_M)) / n_points
    tilt = math.degrees(math.acos(min(1.0, float(plane[:3] @ up))))
    if tilt > math.degrees(MAX_TILT_RAD):
        raise ValueError(f'no plausible floor: the refined plane is tilted {tilt:.0f} deg from '
                         f'the expected up, more than {math.degrees(MAX_TILT_RAD):.0f} deg; '
                         'give prior_pitch_rad for a camera looking steeply down')
    if fraction < MIN_INLIER_FRACTION:
        raise ValueError(f'no plausible floor: the refined plane holds {fraction:.1%} of the '
                         f'points, less than {MIN_INLIER_FRACTION:.0%}')
    height, pitch, roll = mount_from_plane(plane[:3], plane[3])
    return MountEstimate(height_m=height, pitch_rad=pitch, roll_rad=roll,
                         inlier_fraction=fraction, n_points=n_points)


def _best_candidate(points: np.ndarray, pixel_index: np.ndarray, shape: tuple[int, int],
                    up: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(4,) the best supported RANSAC plane near ``up`` with next to nothing below it."""
    n_points = points.shape[0]
    score = points[rng.choice(n_points, size=min(SCORE_POINTS, n_points), replace=False)]
    score_h = np.column_stack([score, np.ones(len(score), dtype=np.float32)])
    planes = _candidate_planes(points, _triplets(pixel_index, shape, ITERATIONS, rng))
    planes = planes[planes[:, :3] @ up >= math.cos(MAX_TILT_RAD)]
    if planes.shape[0] == 0:
        raise ValueError('no plausible floor: no horizontal-ish plane below the camera (normal '
                         f'within {math.degrees(MAX_TILT_RAD):.0f} deg of up)')
    # signed distance of every scoring point to every candidate, > 0 towards the camera
    dist = planes.astype(np.float32) @ score_h.T
    below = np.count_nonzero(dist < -BELOW_MARGIN_INLIERS * INLIER_M, axis=1)
    inliers = np.count_nonzero(np.abs(dist, out=dist) <= INLIER_M, axis=1)
    min_count = max(MIN_INLIER_FRACTION * len(score), 3.0)
    # a plane with as many points below it as a floor needs is a table or box top
    plausible = (inliers >= min_count) & (below < min_count)
    plausible &= below <= MAX_BELOW_PER_INLIER * inliers
    if not plausible.any():
        best = int(np.argmax(inliers))
        raise ValueError(
            'no plausible floor: no horizontal-ish plane with at least '
            f'{MIN_INLIER_FRACTION:.0%} of the points and nothing below it (the best '
            f'horizontal-ish candidate holds {inliers[best] / len(score):.1%} of the points, '
            f'{below[best] / len(score):.1%} lie below it)')
    return planes[int(np.argmax(np.where(plausible, inliers, -1)))]
