"""Solving for the dipole moments of a lattice in a plane wave.

The DDA system in ADDA's form (Gaussian units): ``alpha_i^-1 P_i - sum_{j != i} G_ij P_j =
E_inc(r_i)``, solved in the symmetrically scaled unknowns ``x = alpha^(-1/2) P``:

    (I - alpha^(1/2) G alpha^(1/2)) x = alpha^(1/2) E_inc,

whose matrix is complex symmetric with unit diagonal (Jacobi-scaled), and whose relative
residual is the one ADDA reports. Everything here happens in the particle (lattice) frame; the
engine rotates the incident wave and the observation directions into it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.dda.interaction import Convolver, Interaction, get_interaction
from holofit.dda.lattice import Lattice
from holofit.dda.polarizability import ldr_s_term, polarizability
from holofit.dda.solver import ConvergenceError, SolveResult, bicgstab, qmr_cs

__all__ = ["DipoleSolution", "DipoleSystem", "incident_field"]


def incident_field(
    positions: NDArray[np.float64], k: float, propagation: ArrayLike, polarization: ArrayLike
) -> NDArray[np.complex128]:
    """Plane wave ``e exp(i k a.r)`` at ``positions`` (N, 3), zero phase at the origin."""
    a = np.asarray(propagation, dtype=float)
    e = np.asarray(polarization, dtype=complex)
    return np.exp(1j * k * (positions @ a))[:, None] * e[None, :]


@dataclass(eq=False)
class DipoleSolution:
    """Dipole moments ``P`` (N, 3) of a lattice for one incident plane wave (particle frame)."""

    lattice: Lattice
    k: float
    propagation: NDArray[np.float64]
    polarization: NDArray[np.float64]
    alpha: NDArray[np.complex128]
    x: NDArray[np.complex128]  # scaled unknowns, for warm starts
    P: NDArray[np.complex128]
    iterations: int
    residual: float


class DipoleSystem:
    """The DDA linear system of one lattice at one wavenumber, with its cached interaction.

    Parameters
    ----------
    lattice : Lattice
        Dipoles and their materials.
    k : float
        Wavenumber in the medium, rad/um.
    n_medium : float
        Refractive index of the medium (to form relative permittivities).
    pol : {"ldr", "cm"}
        Polarisability prescription.
    dtype : numpy complex dtype
        Precision of the FFT convolution (complex128 by default).
    """

    def __init__(self, lattice: Lattice, k: float, n_medium: float, pol: str = "ldr",
                 dtype: type = np.complex128) -> None:
        self.lattice = lattice
        self.k = float(k)
        self.pol = pol
        self.dtype = np.dtype(dtype)
        self.eps_rel = lattice.relative_permittivity(n_medium)
        self.interaction: Interaction = get_interaction(lattice.shape, lattice.d, self.k, dtype)
        self._conv = Convolver(self.interaction, lattice.shape)
        nx, ny, nz = lattice.shape
        # flat index of each dipole in the (z, y, x) box layout of the convolver
        self._flat = np.ravel_multi_index(
            (lattice.ijk[:, 2], lattice.ijk[:, 1], lattice.ijk[:, 0]), (nz, ny, nx))
        self.matvecs = 0

    def alpha(self, propagation: ArrayLike, polarization: ArrayLike) -> NDArray[np.complex128]:
        """Polarisability of each dipole for this incident wave (LDR depends on it)."""
        s = ldr_s_term(propagation, polarization)
        return polarizability(self.eps_rel, self.lattice.d, self.k, self.pol, s)

    def _matvec(self, x: NDArray, sqrt_alpha: NDArray) -> NDArray:
        n = self.lattice.n_dipoles
        y = x.reshape(n, 3) * sqrt_alpha[:, None]
        field = self._conv.field
        field.fill(0)
        flat = field.reshape(3, -1)
        flat[:, self._flat] = y.T
        z = self._conv.convolve()
        gz = z.reshape(3, -1)[:, self._flat].T
        self.matvecs += 1
        return (x.reshape(n, 3) - sqrt_alpha[:, None] * gz).ravel()

    def solve(
        self,
        propagation: ArrayLike,
        polarization: ArrayLike,
        tol: float = 1e-5,
        x0: NDArray[np.complex128] | None = None,
        maxiter: int = 2000,
        raise_on_failure: bool = True,
        method: str = "qmr",
    ) -> DipoleSolution:
        """Dipole moments for the plane wave ``polarization * exp(i k propagation . r)``.

        Parameters
        ----------
        propagation, polarization : array_like, shape (3,)
            Unit propagation direction and (real) polarisation, particle frame.
        tol : float
            Relative residual of the scaled system.
        x0 : ndarray, optional
            Warm start (the ``x`` of an earlier solution); otherwise the better of 0 and
            ``b`` (ADDA's ``-init_field auto``).
        maxiter : int
            Iteration limit.
        raise_on_failure : bool
            Raise :class:`ConvergenceError` (with the residual reached) if the tolerance is
            not met; otherwise return the last iterate with its residual.
        method : {"qmr", "bicgstab"}
            Krylov solver.
        """
        a = np.asarray(propagation, dtype=float)
        e = np.asarray(polarization, dtype=float)
        alpha = self.alpha(a, e)
        sqrt_alpha = np.sqrt(alpha)
        e_inc = incident_field(self.lattice.positions, self.k, a, e)
        b = (sqrt_alpha[:, None] * e_inc).ravel()

        def mv(v: NDArray) -> NDArray:
            return self._matvec(v, sqrt_alpha)

        if x0 is None:
            # ADDA's 'auto': start from b if that beats zero (residual |b - Ab| vs |b|)
            r_b = b - mv(b)
            start = b if np.linalg.norm(r_b) < np.linalg.norm(b) else None
        else:
            start = np.asarray(x0, dtype=complex).ravel()
        solver = {"qmr": qmr_cs, "bicgstab": bicgstab}[method]
        result: SolveResult = solver(mv, b, x0=start, tol=tol, maxiter=maxiter)
        if not result.converged and raise_on_failure:
            raise ConvergenceError(
                f"DDA solve did not converge: relative residual {result.residual:.3g} after "
                f"{result.iterations} iterations (tolerance {tol:g}, {self.lattice.n_dipoles} "
                "dipoles)"
            )
        P = result.x.reshape(-1, 3) * sqrt_alpha[:, None]
        return DipoleSolution(
            lattice=self.lattice, k=self.k, propagation=a, polarization=e, alpha=alpha,
            x=result.x, P=P, iterations=result.iterations, residual=result.residual,
        )
