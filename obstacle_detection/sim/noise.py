"""The Kinect v2 like sensor model of the scene generator (steps in docs/scenes.md)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class NoiseModel:
    """Kinect v2 like sensor model; every draw seeded by ``(seed, frame_index)``.

    sigma(z) = depth_sigma_base_mm + depth_sigma_quad_mm_per_m2 * (z - depth_sigma_ref_m)^2 [mm].
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
    dark_blob_px: float = 0.0


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
#: The time-of-flight model with the dark dropouts in blobs of about 6 px (issue 22).
KINECT_V2_TOF_BLOBS = NoiseModel(dark_sigma_factor=2.0, far_dropout_rate=0.1,
                                 flying_pixel_rate=0.5, dark_blob_px=6.0)
#: Sensor models by the names scenario lists use.
NOISE_MODELS = {'kinect_v2': KINECT_V2_NOISE, 'kinect_v2_tof': KINECT_V2_TOF_NOISE,
                'kinect_v2_tof_blobs': KINECT_V2_TOF_BLOBS, 'exact': EXACT}


def blob_dropouts(hit_index: np.ndarray, dark: np.ndarray, rate: float, blob_px: float,
                  key: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the ``rate`` of each dark primitive's pixels dropped in smooth blobs."""
    rng = np.random.default_rng([*key, 0xB10B5])
    field = rng.standard_normal(hit_index.shape).astype(np.float32)
    field = cv2.GaussianBlur(field, (0, 0), blob_px, borderType=cv2.BORDER_REFLECT)
    out = np.zeros(hit_index.shape, bool)
    for index in np.flatnonzero(dark[:-1]):
        mine = hit_index == index
        if mine.any():
            cut = np.quantile(field[mine], 1.0 - rate)
            out |= mine & (field > cut)
    return out


def depth_edges(depth_m: np.ndarray, hit: np.ndarray, model: NoiseModel, window_px: int,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels with a depth edge in their ``window_px`` window: (edge, nearest, farthest)."""
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
    """Time-of-flight mixed pixels at depth edges: ``(depth (H, W) [m], flying (H, W) bool)``."""
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


def measure(depth_true: np.ndarray, hit_index: np.ndarray, dark: np.ndarray,
            model: NoiseModel, key: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apply the sensor model to the true depth: ``(depth_mm uint16, valid, flying)``.

    hit_index: (H, W) primitive hit, -1 none; dark: (P + 1,) bool; key: (seed, frame_index).
    """
    rng = np.random.default_rng([*key, 0x4015E])
    height, width = depth_true.shape
    hit = hit_index >= 0
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
        sigma_mm[on_dark] *= np.float32(model.dark_sigma_factor)
        sigma_mm *= gauss
        measured_mm += sigma_mm
    np.rint(measured_mm, out=measured_mm)
    lo, hi = round(model.min_range_m * 1e3), round(model.max_range_m * 1e3)
    valid = hit & (measured_mm >= lo) & (measured_mm <= hi)
    if dropout_draw is not None:
        blobs = model.dark_blob_px > 0.0
        dark_rate = model.dropout_rate if blobs else model.dark_dropout_rate
        rates = np.where(dark, dark_rate, model.dropout_rate).astype(np.float32)
        rate = rates[hit_index]
        span = model.max_range_m - model.far_dropout_start_m   # far dropouts rise over it
        ramp = np.clip((depth_true - model.far_dropout_start_m) / span, 0.0, 1.0)
        rate += (model.far_dropout_rate * ramp).astype(np.float32)
        valid &= dropout_draw >= rate
        if blobs and model.dark_dropout_rate > 0.0:
            valid &= ~blob_dropouts(hit_index, dark, model.dark_dropout_rate,
                                    model.dark_blob_px, key)
    b = model.border_px
    border = np.ones_like(valid)
    border[b:height - b, b:width - b] = False
    valid[border] = False
    depth_mm = np.where(valid, measured_mm, 0.0).astype(np.uint16)
    return depth_mm, valid, flying
