"""Numba kernels of the solvers (arrays and scalars in, ``out`` last)."""
