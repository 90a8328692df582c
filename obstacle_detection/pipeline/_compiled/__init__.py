"""Numba kernels, leaves importing only :mod:`obstacle_detection.labels` and :mod:`._numba`.

Each stage module joins a kernel to its numpy twin ``_reference_<name>`` with
:func:`obstacle_detection.pipeline.jit.choose`; :mod:`.rvl` serves the ROS layer's RVL decoder.
"""
