"""Built-in noise kernels (imported for registration)."""
