"""The shared Taichi engine: rod, meshes, energies, integrators, solvers, recorder."""
import os as _os

# Keep Taichi quiet on import (before any engine module imports taichi).
_os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
_os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
