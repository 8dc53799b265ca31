"""Built-in straight-line kernels (paper §3.4, §4), imported here so that they register.

``centroid-join`` (CJ), ``svd`` (eq. 27-32), ``hough`` (Algorithm 1) and ``hough-cluster`` (Algorithm 2,
eq. 35). Shared grouping, Hough voting and span code lives in :mod:`shared.kernels.lines._common`.
"""

from shared.kernels.lines.centroid_join import CentroidJoin, CentroidJoinParams
from shared.kernels.lines.hough import Hough, HoughParams
from shared.kernels.lines.hough_cluster import HoughCluster, HoughClusterParams
from shared.kernels.lines.svd import Svd, SvdParams

__all__ = [
    "CentroidJoin",
    "CentroidJoinParams",
    "Hough",
    "HoughCluster",
    "HoughClusterParams",
    "HoughParams",
    "Svd",
    "SvdParams",
]
