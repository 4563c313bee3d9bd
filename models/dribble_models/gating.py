"""H-CNN gating: a 5-bin histogram of each thumbnail, and seeded k-means over it.

Bins are equal over 0..255 (`numpy.histogram(x, bins=5, range=(0, 255))`: edges 0, 51, 102,
153, 204, 255), divided by the pixel count; top then bottom. The robot computes the same
feature with `dribble_controller::histogram::gating_feature`.
"""

from __future__ import annotations

import numpy as np
from sklearn.cluster import KMeans

from . import contract


def histogram(thumbnail: np.ndarray) -> np.ndarray:
    counts, _ = np.histogram(thumbnail, bins=contract.HISTOGRAM_BINS, range=(0, 255))
    return (counts / thumbnail.size).astype(np.float32)


def gating_feature(top_u8: np.ndarray, bottom_u8: np.ndarray) -> np.ndarray:
    """The 10-value feature: top histogram, then bottom histogram."""
    return np.concatenate([histogram(top_u8), histogram(bottom_u8)])


def fit_centroids(features: np.ndarray, clusters: int = contract.DEFAULT_CLUSTERS, seed: int = 0) -> np.ndarray:
    """k-means centroids [clusters, 10] of gating features [N, 10]; the same seed gives the
    same centroids."""
    features = np.asarray(features, dtype=np.float64)
    if len(features) < clusters:
        raise ValueError(f"k-means with {clusters} clusters needs at least {clusters} samples, got {len(features)}")
    kmeans = KMeans(n_clusters=clusters, random_state=seed, n_init=10).fit(features)
    return kmeans.cluster_centers_.astype(np.float32)


def nearest_cluster(top_u8: np.ndarray, bottom_u8: np.ndarray, centroids: np.ndarray) -> int:
    """Index of the centroid nearest (Euclidean) to the pair's feature; the first on a tie."""
    feature = gating_feature(top_u8, bottom_u8)
    distances = np.linalg.norm(np.asarray(centroids, dtype=np.float32) - feature, axis=1)
    return int(np.argmin(distances))
