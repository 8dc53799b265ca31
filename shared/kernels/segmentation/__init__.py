"""Built-in segmentation kernels (imported for registration)."""
