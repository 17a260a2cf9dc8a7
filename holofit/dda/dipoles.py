"""Solving for the dipole moments of a lattice in a plane wave.

The DDA system in ADDA's form (Gaussian units): ``alpha_i^-1 P_i - sum_{j != i} G_ij P_j =
E_inc(r_i)``, solved in the symmetrically scaled unknowns ``x = alpha^(-1/2) P``:

    (I - alpha^(1/2) G alpha^(1/2)) x = alpha^(1/2) E_inc,

whose matrix is complex symmetric with unit diagonal (Jacobi-scaled), and whose relative
residual is the one ADDA reports. Everything here happens in the particle (lattice) frame; the
engine rotates the incident wave and the observation directions into it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.dda.convolution import Convolver
from holofit.dda.interaction import Interaction, get_interaction
from holofit.dda.lattice import Lattice
from holofit.dda.polarizability import INCIDENCE_INDEPENDENT, ldr_s_term, polarizability
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
    #: wall seconds of the solve's parts: "polarizability", "incident_field", "start" (the
    #: initial product and the choice of x0), "matvec" (products inside the Krylov loop),
    #: "krylov" (the solver's own vector updates and residual checks), "total"
    timings: dict[str, float] = field(default_factory=dict)


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
    pol : {"ldr", "ldr_avg", "cm", "fcd"}
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
        # (N,) isotropic voxels, or (N, 3) along the lattice axes for laminate boundary voxels
        self.eps_rel = (lattice.relative_permittivity(n_medium) if lattice.normals is None
                        else lattice.component_permittivity(n_medium))
        # filtered coupled dipoles: the FCD polarisability with the filtered interaction
        self.interaction: Interaction = get_interaction(
            lattice.shape, lattice.d, self.k, dtype, "fcd" if pol == "fcd" else "poi")
        self._conv = Convolver(self.interaction, lattice.shape, lattice.ijk)
        self.matvecs = 0

    def alpha(self, propagation: ArrayLike, polarization: ArrayLike) -> NDArray[np.complex128]:
        """Polarisability of each dipole for this incident wave (LDR depends on it)."""
        s = ldr_s_term(propagation, polarization)
        return polarizability(self.eps_rel, self.lattice.d, self.k, self.pol, s)

    @property
    def incidence_independent(self) -> bool:
        """True if the polarisabilities do not depend on the incident wave (the DDA is then
        one linear map of any incident field: the lattice has a T-matrix)."""
        return self.pol in INCIDENCE_INDEPENDENT

    def solve_field(
        self,
        e_inc: NDArray[np.complex128],
        tol: float = 1e-5,
        x0: NDArray[np.complex128] | None = None,
        maxiter: int = 2000,
        method: str = "qmr",
    ) -> tuple[NDArray[np.complex128], SolveResult]:
        """Dipole moments (N, 3) for an arbitrary incident field ``e_inc`` (N, 3) at the
        dipoles, with an incidence-independent polarisability (the same start rule and solvers
        as :meth:`solve`).

        Returns the moments and the solver's result (its ``x`` is the scaled unknown, for
        warm starts); raises :class:`ConvergenceError` if the tolerance is not met.
        """
        if not self.incidence_independent:
            raise ValueError(
                f"polarizability {self.pol!r} depends on the incident wave; a general incident "
                f"field needs one of {INCIDENCE_INDEPENDENT}"
            )
        if method not in ("qmr", "bicgstab"):
            raise ValueError(f"solver method must be 'qmr' or 'bicgstab', got {method!r}")
        alpha = self.alpha(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
        w = np.ascontiguousarray(np.sqrt(alpha if alpha.ndim == 2 else alpha[:, None]
                                         * np.ones(3)))
        b = (w * np.asarray(e_inc)).ravel()
        buf = np.empty_like(b)

        def mv(v: NDArray) -> NDArray:
            return self._matvec(v, w, buf)

        known: dict[str, NDArray] = {}
        if x0 is None:
            ab = mv(b).copy()
            start = b if np.linalg.norm(b - ab) < np.linalg.norm(b) else None
            known = {"a_x0": ab} if start is not None else {"a_r0": ab}
        else:
            start = np.asarray(x0, dtype=complex).ravel()
        if method == "qmr":
            result: SolveResult = qmr_cs(mv, b, x0=start, tol=tol, maxiter=maxiter, **known)
        else:
            result = bicgstab(lambda v: mv(v).copy(), b, x0=start, tol=tol, maxiter=maxiter)
        if not result.converged:
            raise ConvergenceError(
                f"DDA solve did not converge: relative residual {result.residual:.3g} after "
                f"{result.iterations} iterations (tolerance {tol:g}, {self.lattice.n_dipoles} "
                "dipoles)"
            )
        return result.x.reshape(-1, 3) * w, result

    def _matvec(self, x: NDArray, sqrt_alpha: NDArray, out: NDArray | None = None) -> NDArray:
        """``(I - alpha^(1/2) G alpha^(1/2)) x``."""
        self.matvecs += 1
        return self._conv.product(x, sqrt_alpha, 1.0, -1.0, out)

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
        if method not in ("qmr", "bicgstab"):
            raise ValueError(f"solver method must be 'qmr' or 'bicgstab', got {method!r}")
        clock = time.perf_counter
        t_start = clock()
        a = np.asarray(propagation, dtype=float)
        e = np.asarray(polarization, dtype=float)
        alpha = self.alpha(a, e)
        # (N,) isotropic or (N, 3) diagonal (lattice axes) polarisabilities
        w = np.sqrt(alpha if alpha.ndim == 2 else alpha[:, None] * np.ones(3))
        w = np.ascontiguousarray(w)
        t_alpha = clock()
        e_inc = incident_field(self.lattice.positions, self.k, a, e)
        b = (w * e_inc).ravel()
        buf = np.empty_like(b)
        t_inc = clock()
        mv_time = [0.0]

        def mv(v: NDArray) -> NDArray:
            t0 = clock()
            out = self._matvec(v, w, buf)
            mv_time[0] += clock() - t0
            return out

        start, known = _initial_guess(mv, b, x0)
        t_x0 = clock()
        mv_time[0] = 0.0
        if method == "qmr":
            result: SolveResult = qmr_cs(mv, b, x0=start, tol=tol, maxiter=maxiter, **known)
        else:
            result = bicgstab(lambda v: mv(v).copy(), b, x0=start, tol=tol, maxiter=maxiter)
        if not result.converged and raise_on_failure:
            raise ConvergenceError(
                f"DDA solve did not converge: relative residual {result.residual:.3g} after "
                f"{result.iterations} iterations (tolerance {tol:g}, {self.lattice.n_dipoles} "
                "dipoles)"
            )
        x = cast("NDArray[np.complex128]", result.x)  # the solvers keep b's dtype, complex128
        P = x.reshape(-1, 3) * w
        t_end = clock()
        timings = {"polarizability": t_alpha - t_start, "incident_field": t_inc - t_alpha,
                   "start": t_x0 - t_inc, "matvec": mv_time[0],
                   "krylov": t_end - t_x0 - mv_time[0], "total": t_end - t_start}
        return DipoleSolution(
            lattice=self.lattice, k=self.k, propagation=a, polarization=e, alpha=alpha,
            x=x, P=P, iterations=result.iterations, residual=result.residual,
            timings=timings,
        )


def _initial_guess(mv: Callable[[NDArray], NDArray], b: NDArray, x0: NDArray | None
                   ) -> tuple[NDArray | None, dict[str, NDArray]]:
    """The Krylov solver's start and the products it already knows.

    Without ``x0``, ADDA's ``-init_field auto``: start from ``b`` if that beats zero
    (residual ``|b - A b|`` against ``|b|``); the product ``A b`` is then the initial
    residual's (``x0 = b``) or the first Lanczos product's (``x0 = 0, r0 = b``), so it is not
    wasted.
    """
    if x0 is not None:
        return np.asarray(x0, dtype=complex).ravel(), {}
    ab = mv(b).copy()
    start = b if np.linalg.norm(b - ab) < np.linalg.norm(b) else None
    return start, ({"a_x0": ab} if start is not None else {"a_r0": ab})
