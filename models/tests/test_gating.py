"""The H-CNN gating feature and the seeded k-means."""

import numpy as np

from dribble_models.fixtures import synthetic_pairs
from dribble_models.gating import fit_centroids, gating_feature, histogram, nearest_cluster


def test_bin_edges_are_0_51_102_153_204_255():
    values = np.array([0, 50, 51, 101, 102, 152, 153, 203, 204, 255], np.uint8)
    np.testing.assert_array_equal(histogram(values), np.full(5, 0.2, np.float32))


def test_feature_is_top_histogram_then_bottom_histogram():
    top = np.zeros((120, 160), np.uint8)
    bottom = np.full((60, 80), 255, np.uint8)
    assert gating_feature(top, bottom).tolist() == [1, 0, 0, 0, 0, 0, 0, 0, 0, 1]


def test_kmeans_is_reproducible_with_a_seed(rng):
    tops, bottoms = synthetic_pairs(rng, 60)
    features = np.stack([gating_feature(t, b) for t, b in zip(tops, bottoms)])
    first = fit_centroids(features, 4, seed=3)
    again = fit_centroids(features, 4, seed=3)
    assert first.shape == (4, 10)
    np.testing.assert_array_equal(first, again)


def test_nearest_cluster_picks_the_closest_centroid():
    dark = (np.zeros((120, 160), np.uint8), np.zeros((60, 80), np.uint8))
    bright = (np.full((120, 160), 250, np.uint8), np.full((60, 80), 250, np.uint8))
    centroids = np.stack([gating_feature(*bright), gating_feature(*dark)])
    assert nearest_cluster(*dark, centroids) == 1
    assert nearest_cluster(*bright, centroids) == 0
