"""How the physics kernels are compiled: numba's kernel cache (cache.py) and the warm-up
that compiles them once per install (warmup.py)."""
