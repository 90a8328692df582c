"""Numba kernels of the pipeline stages: leaves that import nothing of ours but each other.

Each stage module of :mod:`obstacle_detection.pipeline` chooses between its kernel here and
its numpy twin through the one switch in :mod:`obstacle_detection.pipeline.jit`.
"""
