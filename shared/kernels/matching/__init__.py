"""Built-in matching kernels (imported for registration)."""

from shared.kernels.matching.icp import Icp, IcpParams

__all__ = ["Icp", "IcpParams"]
