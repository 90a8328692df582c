"""The robot-level ground truth of a rendered frame (``SceneFrame.labels``; docs/scenes.md)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from obstacle_detection.labels import GT_ABOVE_ROBOT, GT_OBSTACLE, GT_TRAVERSABLE

from .primitives import Patch, Primitive

#: Two drivable patches whose rectangles are closer than this touch (connectivity) [m].
TOUCH_M = 1e-3
#: A hit lies on a patch when it is within this of the patch plane (plus its tolerance) [m].
ON_PATCH_M = 1e-4
#: Width of the band of reachable ground before a drop whose cells the truth marks [m].
DROP_EDGE_BAND_M = 0.03


@dataclass(frozen=True)
class TruthRules:
    """The robot-level truth's parameters (``DetectorParams`` fields of one name)."""

    max_slope_rad: float = math.pi / 6
    max_step_height_m: float = 0.05
    max_step_down_m: float = 0.05
    robot_height_m: float = 1.0

    @classmethod
    def from_params(cls, params: Any) -> 'TruthRules':
        """Rules from detector parameters (or other rules): their fields of these names."""
        return cls(**{f.name: float(getattr(params, f.name)) for f in dataclasses.fields(cls)})


def _rise(a: Patch, b: Patch) -> np.ndarray | None:
    """Height of ``b`` over ``a`` at the x ends of where they touch; None if they do not."""
    x0, x1 = max(a.x0_m, b.x0_m), min(a.x1_m, b.x1_m)
    y0, y1 = max(a.y0_m, b.y0_m), min(a.y1_m, b.y1_m)
    if x0 > x1 + TOUCH_M or y0 > y1 + TOUCH_M:
        return None
    xs = np.array([v for v in (x0, x1) if math.isfinite(v)] or [0.0])
    return b.z_at(xs) - a.z_at(xs)   # planar patches: the extremes are at the x ends


def _connects(a: Patch, b: Patch, rules: TruthRules) -> bool:
    """Return True when the robot on patch ``a`` can drive onto ``b`` (touching, within a step)."""
    dz = _rise(a, b)
    return dz is not None and bool(dz.min() <= rules.max_step_height_m
                                   and dz.max() >= -rules.max_step_down_m)


def scene_patches(primitives: tuple[Primitive, ...], rules: TruthRules,
                  ) -> tuple[list[Patch], list[bool]]:
    """Every drivable patch of the scene and whether the robot (at the origin) reaches it."""
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
    """Robot-level truth of hit points: ``(labels (N,) uint8 GT_*, drop_edge (N,) bool)``."""
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
        on_reached |= _on_patch(patch, x, y, z, owner)
    labels = np.where(z - ground > rules.robot_height_m, GT_ABOVE_ROBOT,
                      GT_OBSTACLE).astype(np.uint8)
    labels[on_reached] = GT_TRAVERSABLE
    labels[_climbable_risers(x, y, z, patches, reached, rules)] = GT_TRAVERSABLE
    labels[_ledges(x, y, z, owner, patches, reached, rules)] = GT_OBSTACLE
    for i, primitive in enumerate(primitives):
        own = [ok for patch, ok in zip(patches, reached) if patch.owner == i]
        if own and all(own) and _vertical_extent_m(primitive) <= rules.max_step_height_m:
            labels[owner == i] = GT_TRAVERSABLE
    drop_edge = np.zeros(x.shape, dtype=bool)
    for a, a_ok in zip(patches, reached):
        if not a_ok:
            continue
        for b, b_ok in zip(patches, reached):
            dz = None if b_ok else _rise(a, b)
            if dz is None or dz.max() >= -rules.max_step_down_m:   # b is no drop beside a
                continue
            near = Patch(max(a.x0_m, b.x0_m) - DROP_EDGE_BAND_M,
                         min(a.x1_m, b.x1_m) + DROP_EDGE_BAND_M,
                         max(a.y0_m, b.y0_m) - DROP_EDGE_BAND_M,
                         min(a.y1_m, b.y1_m) + DROP_EDGE_BAND_M, 0.0)
            drop_edge |= near.covers(x, y) & _on_patch(a, x, y, z, owner)
    return labels, drop_edge


def _on_patch(patch: Patch, x: np.ndarray, y: np.ndarray, z: np.ndarray,
              owner: np.ndarray) -> np.ndarray:
    """(N,) bool: hits of the patch's own primitive that lie on the patch."""
    return (patch.covers(x, y) & (owner == patch.owner)
            & (np.abs(z - patch.z_at(x)) <= patch.tolerance_m + ON_PATCH_M))


def _climbable_risers(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                      patches: list[Patch], reached: list[bool], rules: TruthRules,
                      ) -> np.ndarray:
    """(N,) bool: hits on a riser no higher than a step up to a reached surface above."""
    top = np.full(x.shape, -np.inf)
    low = np.full(x.shape, np.inf)
    for patch, ok in zip(patches, reached):
        if ok:
            covered = patch.covers(x, y)
            plane = patch.z_at(x)
            np.maximum(top, np.where(covered, plane, -np.inf), out=top)
            np.minimum(low, np.where(covered, plane, np.inf), out=low)
    with np.errstate(invalid='ignore'):
        rise = top - low
        return ((rise > 1e-3) & (rise <= rules.max_step_height_m)
                & (z <= top + ON_PATCH_M) & (z >= low - ON_PATCH_M))


def _ledges(x: np.ndarray, y: np.ndarray, z: np.ndarray, owner: np.ndarray,
            patches: list[Patch], reached: list[bool], rules: TruthRules) -> np.ndarray:
    """(N,) bool: reached ground within ``DROP_EDGE_BAND_M`` of a ledge (issue 22)."""
    out = np.zeros(x.shape, dtype=bool)
    eps = 1e-3
    for i, (a, a_ok) in enumerate(zip(patches, reached)):
        if not a_ok:
            continue
        on_a = _on_patch(a, x, y, z, owner)
        if not on_a.any():
            continue
        for axis, edge, outward in (('x', a.x0_m, -1.0), ('x', a.x1_m, 1.0),
                                    ('y', a.y0_m, -1.0), ('y', a.y1_m, 1.0)):
            if not math.isfinite(edge):
                continue
            coord = x if axis == 'x' else y
            band = on_a & (np.abs(coord - edge) <= DROP_EDGE_BAND_M)
            if not band.any():
                continue
            qx = np.where(band, edge + outward * eps, x) if axis == 'x' else x
            qy = np.where(band, edge + outward * eps, y) if axis == 'y' else y
            z_here = a.z_at(x)
            beyond = np.full(x.shape, -np.inf)
            for j, (b, b_ok) in enumerate(zip(patches, reached)):
                if not b_ok or j == i:
                    continue
                plane = b.z_at(qx)
                fits = b.covers(qx, qy) & (plane <= z_here + rules.max_step_height_m)
                np.maximum(beyond, np.where(fits, plane, -np.inf), out=beyond)
            out |= band & np.isfinite(beyond) & (z_here - beyond > rules.max_step_down_m)
    return out
