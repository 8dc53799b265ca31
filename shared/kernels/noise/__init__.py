"""Built-in noise-removal kernels (paper §3.2), imported for registration.

``dbscan`` (§3.2.1); ``erosion``, ``dilation`` and ``opening`` on a sparse occupancy grid (§3.2.2).
"""

from shared.kernels.noise import dbscan, elements, morphology
from shared.kernels.noise.dbscan import Dbscan, DbscanParams, dbscan_core_labels
from shared.kernels.noise.elements import ELEMENTS, element_footprint, element_offsets
from shared.kernels.noise.morphology import Dilation, Erosion, MorphologyParams, Opening

__all__ = [
    "ELEMENTS",
    "Dbscan",
    "DbscanParams",
    "Dilation",
    "Erosion",
    "MorphologyParams",
    "Opening",
    "dbscan",
    "dbscan_core_labels",
    "element_footprint",
    "element_offsets",
    "elements",
    "morphology",
]
