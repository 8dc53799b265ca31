"""Built-in matching kernels (imported for registration)."""
