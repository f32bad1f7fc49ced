"""Numerical building blocks with no Stan in them: kernels, Hilbert-space
bases, emulators, output bases, quadrature and mode masses."""
