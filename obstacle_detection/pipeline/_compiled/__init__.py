"""Numba kernels of the pipeline stages: leaves that import nothing of ours back.

A kernel module imports only :mod:`obstacle_detection.labels` and :mod:`._numba` (the numba
import and the compile decorators), takes arrays and plain values, and returns arrays. Each
stage module of :mod:`obstacle_detection.pipeline` (median, voxel, normals, ...) joins each
kernel here to its numpy twin ``_reference_<name>`` (same signature, same return type) with
the one dispatcher, :func:`obstacle_detection.pipeline.jit.choose`, and builds its own result
types. A kernel never returns a value meaning "fall back": an input it cannot take is refused
(ValueError, IndexError) and the stage sends such inputs to numpy before calling. One kernel
serves the ROS layer, not a stage: :mod:`.rvl`, the RVL depth decoder of
:mod:`obstacle_detection.ros.rvl` (chosen by the same switch).
"""
