"""The pipeline layer: depth frame in, obstacle points, labels and costmap out (no ROS).

One module per stage family, :mod:`.params`, the orchestrator :mod:`.detector`; numba kernels
in :mod:`._compiled`, chosen by :mod:`.jit`.
"""

from .detector import DetectionResult, Detector
from .params import PRESETS, DetectorParams, Intrinsics

__all__ = ['DetectionResult', 'Detector', 'DetectorParams', 'Intrinsics', 'PRESETS']
