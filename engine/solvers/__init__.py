"""Linear solvers of the implicit steps that are not in engine/linalg.py (the rod's tridiagonal solve)."""
