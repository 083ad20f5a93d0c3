"""The energy protocol: every elastic energy W(x) over a model's vertices.

Energy is the single source of truth: forces are ``-grad W`` and implicit integrators use the
Hessian of the same W. ``x``, ``dx``, ``f``, ``out`` are ``ti.ndarray`` of vec3 with one entry
per model vertex. Pins are handled by the model and the integrators, not by energies.
"""
import numpy as np

from engine.fields import float_dtype, vec3_ndarray, zero_vec3


class Energy:
    """Protocol for an elastic energy W(x) over the model's vertices.

    Energy is the single source of truth: forces are ``-grad W`` and implicit integrators
    use the Hessian of the same W.  Subclasses implement the first four methods with
    Taichi kernels; ``x``, ``dx``, ``f``, ``out`` are ``ti.ndarray`` of vec3 with one entry
    per model vertex.  Pins are handled by the model/integrators, not by energies.
    """

    name = "energy"
    n_vertices: int = 0

    def energy(self, x) -> float:
        """W(x)."""
        raise NotImplementedError

    def add_forces(self, x, f) -> None:
        """f += -dW/dx (deterministic: no parallel float atomics)."""
        raise NotImplementedError

    def add_hessian_product(self, x, dx, out, psd: bool = True) -> None:
        """out += H(x) dx, with H the exact Hessian or (psd=True) its PSD projection."""
        raise NotImplementedError

    def hessian_blocks(self, x, psd: bool = True):
        """Per-element Hessian blocks (energy-specific layout; documented by the subclass)."""
        raise NotImplementedError

    def add_hessian_diagonal(self, x, diag, psd: bool = True) -> None:
        """diag[i] += H_ii (3x3 vertex diagonal blocks, a mat3 ndarray) for block-Jacobi."""
        raise NotImplementedError(f"{type(self).__name__} has no Hessian diagonal")

    def gershgorin_row_sums(self, x) -> np.ndarray:
        """(n, 3) numpy array: sum_j |H_(i,a),j| of the exact Hessian at x (for the CFL bound)."""
        raise NotImplementedError(f"{type(self).__name__} has no Gershgorin bound")

    def dense_hessian(self, x, psd: bool = True) -> np.ndarray:
        """Dense (3n, 3n) Hessian in numpy, for tests on small models.

        Default: one Hessian-vector product per unit vector (3n products)."""
        n = self.n_vertices
        H = np.zeros((3 * n, 3 * n))
        dx = vec3_ndarray(n)
        out = vec3_ndarray(n)
        for col in range(3 * n):
            e = np.zeros((n, 3))
            e.reshape(-1)[col] = 1.0
            dx.from_numpy(e.astype(float_dtype()))
            zero_vec3(out)
            self.add_hessian_product(x, dx, out, psd)
            H[:, col] = out.to_numpy().reshape(-1)
        return H
