"""Krylov solvers for the complex-symmetric DDA system ``A x = b``.

QMR for complex symmetric matrices (Freund 1992): a Lanczos process in the bilinear form
``u^T v`` (no conjugation), whose tridiagonal matrix is reduced by unitary Givens rotations
to minimise the quasi-residual; one matrix-vector product per iteration. The residual vector
is updated by recurrence (no extra product) and its true norm drives the stopping test
``||r|| / ||b|| < tol`` (the same relative residual ADDA reports). BiCGStab (scipy) is offered
as a fallback.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["ConvergenceError", "SolveResult", "bicgstab", "qmr_cs"]


class ConvergenceError(RuntimeError):
    """The iterative solver did not reach its tolerance (message gives the residual reached)."""


@dataclass
class SolveResult:
    """Outcome of an iterative solve."""

    x: NDArray[np.complexfloating]
    iterations: int
    residual: float
    converged: bool
    history: list[float] = field(default_factory=list)


def _bilinear(u: NDArray, v: NDArray) -> complex:
    return complex(np.dot(u, v))


# -- fused vector updates (one pass over memory each) ----------------------------------------


@numba.njit(cache=True, nogil=True)
def _lanczos_step(dst, av, v, v_prev, alpha, beta):  # pragma: no cover - compiled
    """``dst = av - alpha v - beta v_prev``; returns ``(dst . dst, ||dst||^2)``."""
    bil = 0j
    nrm = 0.0
    for i in range(av.shape[0]):
        t = av[i] - alpha * v[i] - beta * v_prev[i]
        dst[i] = t
        bil += t * t
        nrm += t.real * t.real + t.imag * t.imag
    return bil, nrm


@numba.njit(cache=True, nogil=True)
def _qmr_update(p_new, v, p_prev, p_prev2, x, v_next, r, coef):  # pragma: no cover - compiled
    """The rest of one QMR iteration in one pass; returns ``||r||^2``.

    ``p_new = (v - eta p_prev - theta p_prev2) / zeta`` (``p_new`` may be ``p_prev2``),
    ``x += tau p_new``, ``v_next *= 1/beta``, ``r = r_scale r + r_coef v_next``; ``coef`` is
    ``(eta, theta, 1/zeta, tau, 1/beta, r_scale, r_coef)``, the iteration's scalars together.
    """
    eta, theta, inv_zeta, tau, inv_beta, r_scale, r_coef = coef
    nrm = 0.0
    for i in range(v.shape[0]):
        p = (v[i] - eta * p_prev[i] - theta * p_prev2[i]) * inv_zeta
        p_new[i] = p
        x[i] += tau * p
        vn = v_next[i] * inv_beta
        v_next[i] = vn
        t = r_scale * r[i] + r_coef * vn
        r[i] = t
        nrm += t.real * t.real + t.imag * t.imag
    return nrm


def qmr_cs(
    matvec: Callable[[NDArray], NDArray],
    b: NDArray[np.complexfloating],
    x0: NDArray[np.complexfloating] | None = None,
    tol: float = 1e-5,
    maxiter: int = 1000,
    a_r0: NDArray[np.complexfloating] | None = None,
    a_x0: NDArray[np.complexfloating] | None = None,
) -> SolveResult:
    """Solve ``A x = b`` for complex symmetric ``A`` (``A^T = A``) by QMR.

    Parameters
    ----------
    matvec : callable
        ``v -> A v`` on 1-D complex vectors (it may return the same buffer every call: each
        result is used before the next call).
    b : ndarray
        Right-hand side.
    x0 : ndarray, optional
        Initial guess (warm start); zero if None.
    tol : float
        Target relative residual ``||b - A x|| / ||b||``.
    maxiter : int
        Maximum number of iterations (= matrix-vector products).
    a_r0 : ndarray, optional
        ``A r0`` for the initial residual ``r0`` (``A b`` when ``x0`` is None) if the caller
        already has it: the first iteration then needs no product (ADDA's trick when it picks
        ``x0 = 0`` after trying ``x0 = b``).
    a_x0 : ndarray, optional
        ``A x0`` if the caller already has it (the initial residual then needs no product).

    Returns
    -------
    SolveResult
        ``converged`` is False if ``maxiter`` was reached; the caller decides whether to raise.
    """
    b = np.ascontiguousarray(b, dtype=np.complex128)
    b_norm = float(np.linalg.norm(b))
    if b_norm == 0:
        return SolveResult(np.zeros_like(b), 0, 0.0, True, [0.0])
    if x0 is None:
        x = np.zeros_like(b)
        r = b.copy()
    else:
        x = np.array(x0, dtype=b.dtype, copy=True)
        r = b - (matvec(x) if a_x0 is None else a_x0)
        a_r0 = None
    res = float(np.linalg.norm(r)) / b_norm
    history = [res]
    if res < tol:
        return SolveResult(x, 0, res, True, history)
    if not np.isfinite(res):  # a start that is not a number: fail now, not after maxiter
        return SolveResult(x, 0, res, False, history)

    # Lanczos vectors in the bilinear form, weighted by omega_k = ||v_k|| (Freund's choice)
    beta = np.sqrt(_bilinear(r, r))
    v = r / beta
    v_prev = np.zeros_like(b)
    omega = float(np.linalg.norm(v))
    omega_prev = 0.0
    beta_curr = beta  # beta_k (couples v_k and v_{k-1}); beta_1 is the start value
    tau_bar = omega * beta  # quasi-residual, rotated
    c_prev = c_curr = 1.0
    s_prev = s_curr = 0.0 + 0.0j
    p_prev = np.zeros_like(b)
    p_prev2 = np.zeros_like(b)
    v_next = np.empty_like(b)
    for it in range(1, maxiter + 1):
        av = a_r0 / beta if (it == 1 and a_r0 is not None) else matvec(v)
        alpha = _bilinear(v, av)
        bil, nrm2 = _lanczos_step(v_next, av, v, v_prev, complex(alpha), complex(beta_curr))
        # entries of column k of the weighted tridiagonal after the previous two rotations
        theta = np.conj(s_prev) * omega_prev * beta_curr
        eta = c_prev * c_curr * omega_prev * beta_curr + np.conj(s_curr) * omega * alpha
        zeta_t = c_curr * omega * alpha - s_curr * c_prev * omega_prev * beta_curr
        beta_next = np.sqrt(complex(bil))
        norm_next = float(np.sqrt(nrm2))
        if abs(beta_next) < 1e-300 or norm_next == 0.0:
            # (near) breakdown or exact convergence of the Krylov space
            omega_next = 1.0
            beta_next = 0.0
        else:
            omega_next = norm_next / abs(beta_next)
        # new Givens rotation annihilating omega_{k+1} beta_{k+1}
        h = omega_next * beta_next
        zeta_abs = float(np.sqrt(abs(zeta_t) ** 2 + abs(h) ** 2))
        zeta = zeta_abs if abs(zeta_t) < 1e-300 else zeta_abs * zeta_t / abs(zeta_t)
        c_new = abs(zeta_t) / zeta_abs
        s_new = h / zeta
        tau = c_new * tau_bar
        tau_bar = -s_new * tau_bar
        # search direction, solution, normalised v_next and the residual recurrence
        # r_k = |s_k|^2 r_{k-1} + (c_k tau_bar_{k+1} / omega_{k+1}) v_{k+1}, in one pass
        inv_beta = 1.0 / beta_next if beta_next != 0.0 else 1.0
        coef = (complex(eta), complex(theta), complex(1.0 / zeta), complex(tau),
                complex(inv_beta), float(abs(s_new) ** 2), complex(c_new * tau_bar / omega_next))
        rr = _qmr_update(p_prev2, v, p_prev, p_prev2, x, v_next, r, coef)
        res = float(np.sqrt(rr)) / b_norm
        history.append(res)
        if res < tol or beta_next == 0.0:
            return SolveResult(x, it, res, res < tol or beta_next == 0.0, history)
        if not np.isfinite(res):
            return SolveResult(x, it, res, False, history)
        # shift (buffers rotate: p_prev2 now holds p_k; v_prev's buffer takes the next v_next)
        p_prev2, p_prev = p_prev, p_prev2
        v_prev, v, v_next = v, v_next, v_prev
        omega_prev, omega = omega, omega_next
        beta_curr = beta_next
        c_prev, c_curr = c_curr, c_new
        s_prev, s_curr = s_curr, s_new
    return SolveResult(x, maxiter, res, False, history)


def bicgstab(
    matvec: Callable[[NDArray], NDArray],
    b: NDArray[np.complexfloating],
    x0: NDArray[np.complexfloating] | None = None,
    tol: float = 1e-5,
    maxiter: int = 1000,
) -> SolveResult:
    """BiCGStab (scipy) with the same interface and relative-residual criterion."""
    from scipy.sparse.linalg import LinearOperator
    from scipy.sparse.linalg import bicgstab as _bicgstab

    n = b.size
    count = {"mv": 0}

    def mv(v: NDArray) -> NDArray:
        count["mv"] += 1
        return matvec(v)

    op = LinearOperator((n, n), matvec=mv, dtype=b.dtype)
    x, info = _bicgstab(op, b, x0=x0, rtol=tol, atol=0.0, maxiter=maxiter)
    res = float(np.linalg.norm(b - matvec(x)) / np.linalg.norm(b))
    return SolveResult(x, count["mv"], res, info == 0 and res < 10 * tol, [res])
