"""Built-in clustering kernels (imported for registration)."""
