"""The floor plane from the data: a per-frame refinement of the configured camera mount.

A bounded RANSAC plane fit on upward-facing samples; the method: docs/method.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import jit
from ._compiled import traversal as jit_traversal
from .geometry import GroundRays, mount_angles, mount_rotation
from .params import DetectorParams

#: About this many pixels (an even grid) are sampled for the floor fit.
SAMPLE_PIXELS = 3000


#: RANSAC plane hypotheses per frame (fixed seed: the same frame gives the same fit).
HYPOTHESES = 64
#: Where in each third of the samples the triplet points are taken (fixed: the same frame
#: gives the same fit).
_PICKS = np.random.default_rng(0).random((3, HYPOTHESES))
#: Most samples that score the hypotheses (an even subsample of the floor samples).
SCORE_POINTS = 2000
#: The best hypotheses that are refined by least squares; the best refined one is kept.
REFINED_HYPOTHESES = 2
#: Inlier band of the RANSAC [m].
INLIER_BAND_M = 0.03
#: Inlier bands of the least-squares refits that follow, in order [m].
REFIT_BANDS_M = (0.03, 0.015)
#: A floor sample's local normal (from its grid neighbours) is within acos(sqrt(.)) of
#: vertical: 30 deg (the mount may be 5 deg off, the normals of neighbouring samples are noisy).
FACING_UP_COS2 = math.cos(math.radians(30.0)) ** 2
#: Floor samples are taken up to this far beyond the forward range [m] (a high camera sees the
#: floor only far away).
FIT_RANGE_MARGIN_M = 1.0
#: How FloorFit.reason starts when the plane found lies beyond the fit's bounds.
BEYOND_BOUNDS = 'fitted floor'
#: Samples this far below a fitted plane are lower ground: the floor, when the plane ran
#: through a raised surface (see floor_beneath) [m].
BENEATH_M = 0.05


def sample_step(shape: tuple[int, int]) -> int:
    """Row and column step of the sampled pixel grid for an (H, W) image."""
    return max(1, round(math.sqrt(shape[0] * shape[1] / SAMPLE_PIXELS)))


@dataclass(frozen=True)
class FloorFit:
    """The mount a frame was processed with; d_*: used minus configured; samples: inliers.

    reason: why the configured mount was kept ('' when refined, 'off' when refine_floor is off).
    """

    refined: bool
    height_m: float
    pitch_rad: float
    roll_rad: float
    d_height_m: float = 0.0
    d_pitch_deg: float = 0.0
    d_roll_deg: float = 0.0
    samples: int = 0
    reason: str = ''

    @property
    def beyond_bounds(self) -> bool:
        """Whether the floor was found but farther from the mount than the fit may correct."""
        return not self.refined and self.reason.startswith(BEYOND_BOUNDS)

    def summary(self) -> str:
        """One line for a log: the correction, or why there is none."""
        if not self.refined:
            return f'floor: configured mount kept ({self.reason})'
        return (f'floor: height {self.height_m:.3f} m ({self.d_height_m:+.3f}), pitch '
                f'{math.degrees(self.pitch_rad):.2f} deg ({self.d_pitch_deg:+.2f}), roll '
                f'{math.degrees(self.roll_rad):.2f} deg ({self.d_roll_deg:+.2f}), '
                f'{self.samples} samples')


def configured(params: DetectorParams, reason: str) -> FloorFit:
    """Return the configured mount, not refined, with the reason."""
    return FloorFit(False, params.camera_height_m, params.camera_pitch_rad,
                    params.camera_roll_rad, reason=reason)


def sample_rays(rays: GroundRays, shape: tuple[int, int]) -> np.ndarray:
    """Return (3, M) float32: the rays of the sampled pixel grid."""
    return np.ascontiguousarray(rays.subsampled(sample_step(shape)).table())


def floor_samples(depth_m: np.ndarray, sub_rays: np.ndarray,
                  params: DetectorParams) -> np.ndarray:
    """Subsampled points (3, M) float64 near the configured floor, in the configured frame."""
    return _floor_samples(depth_m, sample_step(depth_m.shape), sub_rays, params.camera_height_m,
                          math.tan(params.floor_max_tilt_rad), params.floor_max_offset_m + 0.02,
                          params.min_range_m, params.max_range_m + FIT_RANGE_MARGIN_M,
                          params.lateral_limit_m, FACING_UP_COS2)


def _reference_floor_samples(depth_m: np.ndarray, step: int, sub_rays: np.ndarray,
                             height_m: float, tan_tilt: float, band0_m: float, min_x_m: float,
                             max_x_m: float, max_y_m: float, facing_cos2: float) -> np.ndarray:
    """(3, M) float64: the samples of every ``step``-th pixel that face up near the floor.

    Near: |z| <= band0_m + tan_tilt * hypot(x, y), min_x_m <= x <= max_x_m, |y| <= max_y_m.
    """
    grid = depth_m[::step, ::step]
    gh, gw = grid.shape
    with np.errstate(invalid='ignore'):
        d = np.where(grid > 0.0, grid, np.nan).astype(np.float64)   # no return: NaN
    r = sub_rays.reshape(3, gh, gw)
    pts = np.stack((d * r[0], d * r[1], d * r[2] + height_m))
    # a local normal from the right and the lower neighbour on the grid: floor samples face
    # up (walls, box sides and flying pixels do not); NaN (no return) drops out
    du = pts[:, :-1, 1:] - pts[:, :-1, :-1]
    dv = pts[:, 1:, :-1] - pts[:, :-1, :-1]
    nx = du[1] * dv[2] - du[2] * dv[1]
    ny = du[2] * dv[0] - du[0] * dv[2]
    nz = du[0] * dv[1] - du[1] * dv[0]
    x, y, z = pts[0, :-1, :-1], pts[1, :-1, :-1], pts[2, :-1, :-1]
    with np.errstate(invalid='ignore'):
        facing_up = nz * nz >= (nx * nx + ny * ny + nz * nz) * facing_cos2
        band = np.hypot(x, y) * tan_tilt
        band += band0_m
        near = facing_up & (np.abs(z) <= band)
        near &= (x >= min_x_m) & (x <= max_x_m)
        near &= np.abs(y) <= max_y_m
    return np.stack((x[near], y[near], z[near]))


_floor_samples = jit.choose(_reference_floor_samples, jit_traversal.floor_samples)


def lstsq_plane(pts: np.ndarray) -> np.ndarray:
    """Return (a, b, c) of the least-squares plane z = a x + b y + c of pts (3, M) (centred)."""
    mean = np.add.reduce(pts, axis=1) / pts.shape[1]   # pts.mean(axis=1), its overhead spared
    c = pts - mean[:, None]
    sxx, sxy, syy = np.dot(c[0], c[0]), np.dot(c[0], c[1]), np.dot(c[1], c[1])
    sxz, syz = np.dot(c[0], c[2]), np.dot(c[1], c[2])
    det = sxx * syy - sxy * sxy
    if not abs(det) > 1e-12:
        return np.array([0.0, 0.0, mean[2]])
    a = (sxz * syy - syz * sxy) / det
    b = (syz * sxx - sxz * sxy) / det
    return np.array([a, b, mean[2] - a * mean[0] - b * mean[1]])


def _in_band(pts: np.ndarray, a: float, b: float, c: float, band_m: float) -> np.ndarray:
    """(3, m) float64: the samples pts (3, M) within band_m of z = a x + b y + c."""
    resid = pts[2] - (a * pts[0] + b * pts[1] + c)
    return pts[:, np.abs(resid) <= band_m]


def _count_in_band(pts: np.ndarray, a: float, b: float, c: float, band_m: float) -> int:
    """How many samples pts (3, M) lie within band_m of z = a x + b y + c."""
    resid = pts[2] - (a * pts[0] + b * pts[1] + c)
    return int(np.count_nonzero(np.abs(resid) <= band_m))


def ransac_plane(pts: np.ndarray, params: DetectorParams) -> np.ndarray:
    """Return (k, 3): (a, b, c) of the bounded hypotheses with most samples in the band."""
    return _ransac(pts, _PICKS, math.tan(params.floor_max_tilt_rad) ** 2,
                   params.floor_max_offset_m, INLIER_BAND_M, SCORE_POINTS, REFINED_HYPOTHESES)


def _reference_ransac_plane(pts: np.ndarray, picks: np.ndarray, tan_tilt2: float,
                            offset_m: float, band_m: float, score_points: int,
                            k: int) -> np.ndarray:
    """(k, 3) float64: the best k of the hypotheses from ``picks`` ((3, h) in [0, 1))."""
    # one point from each third of the samples (image row order: far, middle, near for a
    # camera above the floor): well-conditioned triplets
    third = pts.shape[1] // 3
    picks = (picks * third).astype(np.int64) + np.arange(3)[:, None] * third
    p0, p1, p2 = pts[:, picks[0]], pts[:, picks[1]], pts[:, picks[2]]   # (3, h) each
    u, v = p1 - p0, p2 - p0
    nx = u[1] * v[2] - u[2] * v[1]
    ny = u[2] * v[0] - u[0] * v[2]
    nz = u[0] * v[1] - u[1] * v[0]
    good = np.abs(nz) > 1e-9
    nz = np.where(good, nz, 1.0)
    a, b = -nx / nz, -ny / nz
    c = p0[2] - a * p0[0] - b * p0[1]
    bounded = good & (a * a + b * b <= tan_tilt2)
    bounded &= np.abs(c) <= offset_m
    # the configured floor itself is always a candidate, and so is the level plane through
    # the most common sample height in 1 cm bins (the floor under a mount wrong in height)
    near = np.abs(pts[2]) <= offset_m
    counts = np.bincount(np.floor((pts[2][near] + offset_m) * 100.0).astype(np.int64))
    mode = (int(np.argmax(counts)) + 0.5) * 0.01 - offset_m if counts.size else 0.0
    a = np.append(a[bounded], (0.0, 0.0))
    b = np.append(b[bounded], (0.0, 0.0))
    c = np.append(c[bounded], (0.0, mode))
    sp = pts[:, ::max(1, pts.shape[1] // score_points)].astype(np.float32)
    a32, b32, c32 = a.astype(np.float32), b.astype(np.float32), c.astype(np.float32)
    resid = a32[:, None] * sp[0] + b32[:, None] * sp[1] + c32[:, None] - sp[2]
    score = np.count_nonzero(np.abs(resid) <= band_m, axis=1)
    best = np.argsort(-score, kind='stable')[:k]
    return np.stack((a[best], b[best], c[best]), axis=1)


_ransac = jit.choose(_reference_ransac_plane, jit_traversal.ransac_plane)


def fit_floor(depth_m: np.ndarray, sub_rays: np.ndarray, params: DetectorParams) -> FloorFit:
    """Fit the floor plane of depth_m (H, W) [m]; return the mount to process the frame with."""
    if not params.refine_floor:
        return configured(params, 'off')
    pts = floor_samples(depth_m, sub_rays, params)
    if pts.shape[1] < params.floor_min_points:
        return configured(params, f'{pts.shape[1]} floor samples < floor_min_points='
                                  f'{params.floor_min_points}')
    coef, used = best_plane(pts, params)
    if used < params.floor_min_points:
        return configured(params, f'{used} floor inliers < floor_min_points='
                                  f'{params.floor_min_points}')
    reason = _out_of_bounds(coef, params)
    if reason:
        return configured(params, reason)
    coef, used = floor_beneath(pts, coef, used, params)
    return corrected_mount(params, *(float(v) for v in coef), used)


def best_plane(pts: np.ndarray, params: DetectorParams) -> tuple[np.ndarray, int]:
    """Return ((a, b, c), inliers of its last refit): the refined plane most samples support."""
    best = None   # (inliers in the last band, coefficients, samples of the last refit)
    refits: list[list[np.ndarray]] = []   # the inliers of each refit of the earlier hypotheses
    for coef in ransac_plane(pts, params):   # each refined on narrowing bands
        used = 0
        stages: list[np.ndarray] = []
        repeated = False
        for stage, band in enumerate(REFIT_BANDS_M):
            inliers = _in_band(pts, *coef, band)
            used = inliers.shape[1]
            if used < 3:
                break
            # the same inliers as an earlier hypothesis at this stage: the same refits follow,
            # the same plane and support, which did not beat the best (skipped, same result)
            repeated = any(len(done) > stage and done[stage].shape == inliers.shape
                           and done[stage].tobytes() == inliers.tobytes() for done in refits)
            if repeated:
                break
            stages.append(inliers)
            coef = lstsq_plane(inliers)
        refits.append(stages)
        if repeated:
            continue
        support = _count_in_band(pts, *coef, REFIT_BANDS_M[-1])
        if best is None or support > best[0]:
            best = (support, coef, used)
    return best[1], best[2]


def _out_of_bounds(coef: np.ndarray, params: DetectorParams) -> str:
    """Why the plane (a, b, c) is too far from the configured floor to be it, or ''."""
    a, b, c = (float(v) for v in coef)
    tilt = math.atan(math.hypot(a, b))
    if tilt > params.floor_max_tilt_rad:
        return f'{BEYOND_BOUNDS} tilted {math.degrees(tilt):.1f} deg > floor_max_tilt_deg'
    if abs(c) > params.floor_max_offset_m:
        return f'{BEYOND_BOUNDS} offset {c:+.3f} m beyond floor_max_offset_m'
    return ''


def floor_beneath(pts: np.ndarray, coef: np.ndarray, used: int,
                   params: DetectorParams) -> tuple[np.ndarray, int]:
    """Return the floor under a raised surface the fit took for it: ((a, b, c), inliers)."""
    resid = pts[2] - (coef[0] * pts[0] + coef[1] * pts[1] + coef[2])
    # within the offset bound of the configured floor (not a lower floor beyond a drop)
    low = (resid < -BENEATH_M) & (pts[2] >= -params.floor_max_offset_m)
    beneath = np.ascontiguousarray(pts[:, low])   # the kernels' layout
    if beneath.shape[1] < params.floor_min_points:
        return coef, used
    lower, _ = best_plane(beneath, params)
    for band in REFIT_BANDS_M:   # refined on all samples (the floor on the plane's other side)
        lower_in = _in_band(pts, *lower, band)
        if lower_in.shape[1] < params.floor_min_points:
            return coef, used
        lower = lstsq_plane(lower_in)
    if _out_of_bounds(lower, params):
        return coef, used
    band = REFIT_BANDS_M[-1]
    if _count_in_band(pts, *lower, band) <= _count_in_band(pts, *coef, band):
        return coef, used
    return lower, lower_in.shape[1]


def corrected_mount(params: DetectorParams, a: float, b: float, c: float,
                     samples: int) -> FloorFit:
    """Return the mount whose ground frame has the plane z = a x + b y + c as z = 0."""
    norm = math.sqrt(a * a + b * b + 1.0)
    n = np.array([-a, -b, 1.0]) / norm             # floor "up" in the configured frame
    height = (params.camera_height_m - c) / norm    # camera (0, 0, h) above the plane
    # the configured frame's rotation followed by the smallest rotation taking n to +z;
    # axis = n x (0, 0, 1) with np.cross's operations (its Python overhead spared)
    n0, n1, n2 = float(n[0]), float(n[1]), float(n[2])
    axis = np.array([n1 * 1.0 - n2 * 0.0, n2 * 0.0 - n0 * 1.0, n0 * 0.0 - n1 * 0.0])
    s, cos_angle = math.sqrt(float(axis.dot(axis))), n2   # np.linalg.norm's operations
    rot_c = np.eye(3)
    if s > 0.0:
        k = axis / s
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        rot_c = rot_c + s * kx + (1.0 - cos_angle) * (kx @ kx)
    total = rot_c @ mount_rotation(params.camera_pitch_rad, params.camera_roll_rad)
    roll, pitch, _ = mount_angles(total)
    return FloorFit(True, height, pitch, roll, d_height_m=height - params.camera_height_m,
                    d_pitch_deg=math.degrees(pitch - params.camera_pitch_rad),
                    d_roll_deg=math.degrees(roll - params.camera_roll_rad), samples=samples)
