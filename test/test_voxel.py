"""Voxel grid: centroids of hand-made points."""

import numpy as np

from obstacle_detection.pipeline.voxel import voxel_downsample


def test_centroids_of_hand_made_points():
    pts = np.array([
        [0.01, 0.01, 0.01], [0.02, 0.00, 0.02],   # voxel (0, 0, 0)
        [0.11, 0.01, 0.01],                        # voxel (1, 0, 0)
        [-0.01, 0.05, 0.01], [-0.09, 0.09, 0.03],  # voxel (-1, 0, 0)
    ], np.float32)
    grid = voxel_downsample(pts, (0.1, 0.1, 0.1))
    # voxels in key order: (-1, 0, 0), (0, 0, 0), (1, 0, 0)
    np.testing.assert_allclose(grid.centroids, [[-0.05, 0.07, 0.02], [0.015, 0.005, 0.015],
                                                [0.11, 0.01, 0.01]], rtol=1e-6)
    assert grid.counts.tolist() == [2, 2, 1]
    # every point maps to the voxel whose centroid it contributed to
    assert grid.point_voxel.tolist() == [1, 1, 2, 0, 0]


def test_anisotropic_voxels():
    pts = np.array([[0.0, 0.0, 0.0], [0.04, 0.0, 0.0], [0.0, 0.04, 0.0]], np.float32)
    grid = voxel_downsample(pts, (0.05, 0.03, 0.05))
    assert grid.centroids.shape[0] == 2


def test_matches_unique_reference_on_random_cloud():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1.0, 1.0, (5000, 3)).astype(np.float32)
    size = (0.2, 0.25, 0.3)
    grid = voxel_downsample(pts, size)
    keys, inverse = np.unique(np.floor(pts / np.float32(size)).astype(int), axis=0,
                              return_inverse=True)
    assert grid.centroids.shape[0] == keys.shape[0]
    inverse = inverse.reshape(-1)
    expected = np.stack([np.bincount(inverse, pts[:, a]) / np.bincount(inverse)
                         for a in range(3)], axis=1)
    np.testing.assert_allclose(grid.centroids, expected, rtol=1e-5, atol=1e-6)


def test_empty_input():
    grid = voxel_downsample(np.zeros((0, 3), np.float32), (0.025,) * 3)
    assert grid.centroids.shape == (0, 3) and grid.point_voxel.size == 0
