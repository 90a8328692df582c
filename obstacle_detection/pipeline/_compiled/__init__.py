"""Numba kernels of the pipeline stages: leaves that import nothing of ours back.

A kernel module imports only :mod:`obstacle_detection.labels` and :mod:`._numba` (the numba
import and the compile decorators), takes arrays and plain values, and returns arrays. Each
stage module of :mod:`obstacle_detection.pipeline` (median, voxel, normals, ...) chooses
between its kernels here and its numpy twin through the one switch,
:func:`obstacle_detection.pipeline.jit.enabled`, and builds its own result types. One kernel
serves the ROS layer, not a stage: :mod:`.rvl`, the RVL depth decoder of
:mod:`obstacle_detection.ros.rvl` (chosen by the same switch).
"""
