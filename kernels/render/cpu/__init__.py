"""The CPU kernels (numba; imported lazily by the CPU device so its cache folder is chosen first)."""
