"""Built-in matching kernels (imported for registration)."""

from shared.kernels.matching.icp import Icp, IcpParams
from shared.kernels.matching.icp_line import IcpLine, IcpLineParams

__all__ = ["Icp", "IcpLine", "IcpLineParams", "IcpParams"]
