"""linemap's shared library: types, kernels and the tools both robot and server use.

The robot agent (``robot_agent``) and the server (``server``) only move the parameters and results of
these kernels around; everything that computes lives here and is pure.
"""

__all__ = ["__version__"]

__version__ = "0.1.0"
