"""Numba kernels, each joined to its numpy twin by :func:`..jit.choose` (importing no stage)."""
