"""Built-in lines kernels (imported for registration)."""
