"""The pipeline layer: depth frame in, obstacle points, labels and costmap out (numpy only).

One module per stage family, the frozen parameter dataclass (:mod:`.params`) and the
orchestrator (:mod:`.detector`). Numba kernels live in :mod:`._compiled` (leaves that import
nothing of ours); :mod:`.jit` holds the one switch between them and the numpy path. Nothing
here imports rclpy, the ROS layer, evaluation, the scene generator or pictures.
"""

from .detector import DetectionResult, Detector
from .params import PRESETS, DetectorParams, Intrinsics

__all__ = ['DetectionResult', 'Detector', 'DetectorParams', 'Intrinsics', 'PRESETS']
