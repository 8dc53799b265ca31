"""Built-in clustering kernels (imported for registration): k-means and fuzzy c-means (paper §3.3)."""

from shared.kernels.clustering.fcm import FuzzyCMeans, FuzzyCMeansParams
from shared.kernels.clustering.kmeans import KMeans, KMeansParams

__all__ = ["FuzzyCMeans", "FuzzyCMeansParams", "KMeans", "KMeansParams"]
