"""Numba kernels (numpy/numba only)."""
