"""The seed's section 4.5 logistic-regression refinement of the obstacle pixels.

``P(obstacle) = sigma(a0 + a1 s + a2 c + sum_k b_k e_k)`` per pixel with a voxel: s the slope
of its voxel's normal, c the depth gradient, e_1..e_7 the previous frame's rule-based obstacle
states of seven neighbours. Choices the seed leaves open: docs/method.md.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import minimize
from scipy.special import expit

from ..labels import GT_NO_RETURN, GT_OBSTACLE, LABEL_GROUND, LABEL_OBSTACLE
from .depth import DepthFormatError
from .params import DetectorParams

#: Seed section 4.5 neighbours V_{t-1} as (dx, dy) = (column, row) offsets.
NEIGHBOUR_OFFSETS_XY: tuple[tuple[int, int], ...] = (
    (-1, -1), (-1, 0), (0, -1), (0, 0), (1, 0), (0, 1), (1, 1))

#: Feature names, in the column order of :func:`pixel_features`.
FEATURE_NAMES: tuple[str, ...] = ('slope', 'gradient') + tuple(
    f'e{k + 1}_prev({dx:+d},{dy:+d})' for k, (dx, dy) in enumerate(NEIGHBOUR_OFFSETS_XY))

#: Depth gradient magnitudes are clipped here [m/px].
GRADIENT_CLIP_M_PER_PX = 0.5

#: Version of the model file format written by :meth:`LogisticRefiner.save`.
MODEL_FORMAT_VERSION = 1
MODEL_KIND = 'obstacle_detection.pipeline.refine.LogisticRefiner'


def obstacle_mask(result: Any) -> np.ndarray:
    """(H, W) bool rule-based obstacle pixels of a ``DetectionResult`` (next frame's V_{t-1})."""
    return np.asarray(result.labels) == LABEL_OBSTACLE


def slope_image(result: Any) -> np.ndarray:
    """(H, W) float32 ``|n . up|`` of each pixel's voxel normal; NaN for pixels without a voxel."""
    pixel_voxel = np.asarray(result.pixel_voxel)
    normals = np.asarray(result.voxel_normals, dtype=np.float32).reshape(-1, 3)
    out = np.full(pixel_voxel.shape, np.nan, dtype=np.float32)
    has = pixel_voxel >= 0
    out[has] = np.abs(normals[pixel_voxel[has], 2])
    return out


def gradient_image(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) float32 depth gradient magnitude [m/px]: ``|Sobel 3x3| / 8``, clipped."""
    depth = np.asarray(depth_m, dtype=np.float32)
    gx = cv2.Sobel(depth, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(depth, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    magnitude = np.sqrt(gx * gx + gy * gy) / np.float32(8.0)
    return np.minimum(magnitude, np.float32(GRADIENT_CLIP_M_PER_PX))


def neighbour_states(previous_mask: np.ndarray) -> np.ndarray:
    """(H, W, 7) bool: ``previous_mask[y + dy, x + dx]`` per neighbour offset (outside: False)."""
    padded = np.pad(np.asarray(previous_mask, dtype=bool), 1)
    height, width = padded.shape[0] - 2, padded.shape[1] - 2
    out = np.empty((height, width, len(NEIGHBOUR_OFFSETS_XY)), dtype=bool)
    for k, (dx, dy) in enumerate(NEIGHBOUR_OFFSETS_XY):
        out[:, :, k] = padded[1 + dy:1 + dy + height, 1 + dx:1 + dx + width]
    return out


def pixel_features(result: Any, previous_mask: np.ndarray | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(features (M, 9) float64, pixel_index (M,)) of the pixels with a voxel.

    previous_mask: the previous frame's rule-based obstacle pixels, or None for this frame's.
    """
    pixel_voxel = np.asarray(result.pixel_voxel)
    if previous_mask is None:
        previous_mask = obstacle_mask(result)
    previous_mask = np.asarray(previous_mask, dtype=bool)
    if previous_mask.shape != pixel_voxel.shape:
        raise ValueError(f'previous obstacle mask shape {previous_mask.shape} differs from the '
                         f'frame shape {pixel_voxel.shape}')
    pixel_index = np.flatnonzero(pixel_voxel.reshape(-1) >= 0)
    features = np.empty((pixel_index.size, len(FEATURE_NAMES)), dtype=np.float64)
    features[:, 0] = slope_image(result).reshape(-1)[pixel_index]
    features[:, 1] = gradient_image(result.depth_m).reshape(-1)[pixel_index]
    states = neighbour_states(previous_mask).reshape(-1, len(NEIGHBOUR_OFFSETS_XY))
    features[:, 2:] = states[pixel_index]
    return features, pixel_index


def training_samples(result: Any, truth_labels: np.ndarray,
                     previous_mask: np.ndarray | None = None,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(features (M, 9), targets (M,) bool ``truth == GT_OBSTACLE``), GT_NO_RETURN dropped."""
    features, pixel_index = pixel_features(result, previous_mask)
    truth = np.asarray(truth_labels).reshape(-1)[pixel_index]
    keep = truth != GT_NO_RETURN
    return features[keep], truth[keep] == GT_OBSTACLE


def fit_logistic(features: np.ndarray, targets: np.ndarray, *, l2: float = 1e-3) -> np.ndarray:
    """Coefficients (D + 1,), intercept first, of an L2-penalised logistic fit (L-BFGS).

    features: (M, D); targets: (M,) bool. ValueError on empty or non-finite input.
    """
    x = np.asarray(features, dtype=np.float64)
    y = np.asarray(targets, dtype=np.float64).reshape(-1)
    if y.size == 0 or not np.isfinite(x).all() or not 0.0 <= l2 < math.inf:
        raise ValueError(f'a fit needs samples ({y.size} rows), finite features and a finite '
                         f'l2 >= 0 (l2={l2!r})')
    design = np.hstack([np.ones((y.size, 1)), x])
    penalty = np.full(design.shape[1], l2)
    penalty[0] = 0.0

    def loss_and_gradient(weights: np.ndarray) -> tuple[float, np.ndarray]:
        z = design @ weights
        # -log-likelihood = sum(log(1 + e^z) - y z), computed stably
        loss = np.sum(np.logaddexp(0.0, z) - y * z) + 0.5 * np.sum(penalty * weights ** 2)
        return float(loss), design.T @ (expit(z) - y) + penalty * weights

    fit = minimize(loss_and_gradient, np.zeros(design.shape[1]), jac=True, method='L-BFGS-B',
                   options={'maxiter': 1000, 'ftol': 1e-12, 'gtol': 1e-8})
    return fit.x


@dataclass(frozen=True)
class LogisticRefiner:
    """A fitted model: ``P(obstacle) = sigma(w0 + sum_j w_j (x_j - mean_j) / scale_j)``."""

    coefficients: tuple[float, ...]
    feature_mean: tuple[float, ...]
    feature_scale: tuple[float, ...]
    threshold: float = 0.5
    training_info: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        values = (*self.coefficients, *self.feature_mean, *self.feature_scale, self.threshold)
        if not all(math.isfinite(v) for v in values) or min(self.feature_scale) <= 0.0 \
                or not 0.0 < self.threshold < 1.0:
            raise ValueError('model values must be finite, scales > 0 and threshold in (0, 1)')

    @classmethod
    def fit(cls, features: np.ndarray, targets: np.ndarray, *, l2: float = 1e-3,
            threshold: float = 0.5, **info: Any) -> 'LogisticRefiner':
        """Standardise slope and gradient and fit; ``info`` is stored in the model file."""
        x = np.asarray(features, dtype=np.float64)
        mean = np.zeros(x.shape[1])
        scale = np.ones(x.shape[1])
        if x.shape[0]:
            mean[:2] = x[:, :2].mean(axis=0)
            spread = x[:, :2].std(axis=0)
            scale[:2] = np.where(spread > 1e-12, spread, 1.0)
        weights = fit_logistic((x - mean) / scale, targets, l2=l2)
        info.setdefault('samples', int(x.shape[0]))
        info.setdefault('positives', int(np.count_nonzero(targets)))
        return cls(tuple(float(w) for w in weights), tuple(float(m) for m in mean),
                   tuple(float(s) for s in scale), float(threshold),
                   tuple(sorted(info.items())))

    def _log_odds(self, features: np.ndarray) -> np.ndarray:
        """(M,) float64 linear predictor a0 + sum a_j x_j of raw features (M, 9)."""
        w = np.asarray(self.coefficients)
        scaled = (features - np.asarray(self.feature_mean)) / np.asarray(self.feature_scale)
        return w[0] + scaled @ w[1:]

    def predict(self, features: np.ndarray) -> np.ndarray:
        """(M,) bool obstacle decision for raw features (M, 9): z > logit(threshold)."""
        return self._log_odds(features) > math.log(self.threshold / (1.0 - self.threshold))

    def predict_labels(self, result: Any, previous_mask: np.ndarray | None = None,
                       ) -> np.ndarray:
        """(H, W) bool refined obstacle pixels of a result (previous_mask: as pixel_features)."""
        features, pixel_index = pixel_features(result, previous_mask)
        shape = np.asarray(result.pixel_voxel).shape
        out = np.zeros(shape[0] * shape[1], dtype=bool)
        out[pixel_index] = self.predict(features)
        return out.reshape(shape)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (format version, feature names, scaling, coefficients)."""
        return {
            'kind': MODEL_KIND,
            'version': MODEL_FORMAT_VERSION,
            'model': 'P(obstacle) = sigmoid(intercept + sum_j coef_j * (x_j - mean_j) / scale_j)',
            'features': list(FEATURE_NAMES),
            'neighbour_offsets_xy': [list(o) for o in NEIGHBOUR_OFFSETS_XY],
            'gradient_clip_m_per_px': GRADIENT_CLIP_M_PER_PX,
            'intercept': self.coefficients[0],
            'coefficients': dict(zip(FEATURE_NAMES, self.coefficients[1:])),
            'feature_mean': dict(zip(FEATURE_NAMES, self.feature_mean)),
            'feature_scale': dict(zip(FEATURE_NAMES, self.feature_scale)),
            'threshold': self.threshold,
            'training': dict(self.training_info),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> 'LogisticRefiner':
        """Inverse of :meth:`to_dict`; raises DepthFormatError on a mismatch."""
        for key, expected in (('kind', MODEL_KIND), ('version', MODEL_FORMAT_VERSION),
                              ('features', list(FEATURE_NAMES)),
                              ('gradient_clip_m_per_px', GRADIENT_CLIP_M_PER_PX)):
            if data.get(key) != expected:
                raise DepthFormatError(f'not a refiner model of this version: {key} '
                                       f'{data.get(key)!r}, expected {expected!r}')
        try:
            coefficients = (float(data['intercept']),
                            *(float(data['coefficients'][n]) for n in FEATURE_NAMES))
            mean = tuple(float(data['feature_mean'][n]) for n in FEATURE_NAMES)
            scale = tuple(float(data['feature_scale'][n]) for n in FEATURE_NAMES)
            threshold = float(data.get('threshold', 0.5))
        except (KeyError, TypeError, ValueError) as exc:
            raise DepthFormatError(f'model file lacks or garbles a field: {exc!r}') from exc
        info = data.get('training', {})
        return cls(coefficients, mean, scale, threshold,
                   tuple(sorted(info.items())) if isinstance(info, dict) else ())

    def save(self, path: str | Path) -> None:
        """Write the model as JSON (a few hundred bytes)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + '\n', encoding='utf-8')

    @classmethod
    def load(cls, path: str | Path) -> 'LogisticRefiner':
        """Read a model written by :meth:`save` (raises DepthFormatError, OSError)."""
        try:
            data = json.loads(Path(path).read_text(encoding='utf-8'))
        except json.JSONDecodeError as exc:
            raise DepthFormatError(f'{path}: not JSON ({exc})') from exc
        if not isinstance(data, dict):
            raise DepthFormatError(f'{path}: not a JSON object')
        return cls.from_dict(data)


@dataclass(frozen=True)
class RefinedResult:
    """A detection after the learned refinement (labels, voxels, points, costmap)."""

    labels: np.ndarray
    voxel_is_obstacle: np.ndarray
    obstacle_points: np.ndarray
    ground_points: np.ndarray
    costmap: Any


def voxel_votes(pixel_voxel: np.ndarray, mask: np.ndarray, n_voxels: int) -> np.ndarray:
    """(V,) bool: voxels more than half of whose pixels are True in ``mask``."""
    pixel_voxel = np.asarray(pixel_voxel).reshape(-1)
    mask = np.asarray(mask, dtype=bool).reshape(-1)
    has = pixel_voxel >= 0
    total = np.bincount(pixel_voxel[has], minlength=n_voxels)
    positive = np.bincount(pixel_voxel[has], weights=mask[has], minlength=n_voxels)
    return 2.0 * positive > total


def refine_result(result: Any, refined_mask: np.ndarray, params: DetectorParams,
                  ) -> RefinedResult:
    """Refined obstacle pixels -> labels, voxels (majority vote, N1 check) and a costmap."""
    # Imported here: the fit and the model file need neither the costmap nor the k-NN.
    from .costmap import build_costmap
    from .normals import validate_obstacles

    pixel_voxel = np.asarray(result.pixel_voxel)
    mask = np.asarray(refined_mask, dtype=bool) & (pixel_voxel >= 0)
    labels = np.array(result.labels, dtype=np.uint8, copy=True)
    has = pixel_voxel >= 0
    labels[has] = np.where(mask[has], LABEL_OBSTACLE, LABEL_GROUND)
    voxel_points = np.asarray(result.voxel_points, dtype=np.float32).reshape(-1, 3)
    is_obstacle = voxel_votes(pixel_voxel, mask, voxel_points.shape[0])
    # the pipeline's own k-NN query: max(N, N1 + 1) neighbours
    is_obstacle = validate_obstacles(is_obstacle, result.voxel_neighbours,
                                     params.validation_neighbours)
    obstacle_points = result.pose.ground_to_base(voxel_points[is_obstacle])
    ground_points = result.pose.ground_to_base(voxel_points[~is_obstacle])
    costmap = build_costmap(obstacle_points, ground_points, params)
    return RefinedResult(labels, is_obstacle, obstacle_points, ground_points, costmap)


class RefinedDetector:
    """A ``Detector`` followed by the refinement, for a stream (keeps the previous mask)."""

    def __init__(self, detector: Any, refiner: LogisticRefiner) -> None:
        self.detector = detector
        self.refiner = refiner
        self._previous: np.ndarray | None = None

    @property
    def params(self) -> DetectorParams:
        """The wrapped detector's parameters."""
        return self.detector.params

    def warm_up(self) -> float:
        """Prepare the wrapped detector's JIT kernels (see ``Detector.warm_up``)."""
        return self.detector.warm_up()

    def process(self, depth: np.ndarray, intrinsics: Any = None, *,
                depth_scale: float | None = None) -> Any:
        """Run the pipeline on one frame, refine it: its labels, points, costmap, timings."""
        result = self.detector.process(depth, intrinsics, depth_scale=depth_scale)
        start = time.perf_counter()
        previous = self._previous
        if previous is not None and previous.shape != result.labels.shape:
            previous = None
        mask = self.refiner.predict_labels(result, previous)
        refined = refine_result(result, mask, self.params)
        self._previous = obstacle_mask(result)
        timings = dict(result.timings_ms)
        total = timings.pop('total', 0.0)
        timings['refine'] = (time.perf_counter() - start) * 1e3
        timings['total'] = total + timings['refine']
        return dataclasses.replace(
            result, labels=refined.labels, obstacle_points=refined.obstacle_points,
            ground_points=refined.ground_points, costmap=refined.costmap,
            voxel_is_obstacle=refined.voxel_is_obstacle, timings_ms=timings)
