"""Built-in segmentation kernels (imported for registration)."""

from shared.kernels.segmentation.abd_iepf import AbdIepf, AbdIepfParams

__all__ = ["AbdIepf", "AbdIepfParams"]
