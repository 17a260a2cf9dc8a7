"""Exact scattered field of a dipole set at arbitrary points, by direct summation (numba).

``E(r) = sum_j G(r - r_j) P_j`` with the point-dipole Green's tensor of
:mod:`holofit.dda.interaction`. It costs ``N_dipoles x N_points`` and is used where the
multipole expansion does not converge (points close to the particle) and as an independent
reference in tests.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["direct_field"]


@numba.njit(cache=True, nogil=True, fastmath={"contract", "reassoc", "nsz", "arcp"})
def _direct(points, positions, pr, pi, k, out):  # pragma: no cover - compiled
    npts = points.shape[0]
    ndip = positions.shape[0]
    for q in range(npts):
        ex_r = 0.0
        ex_i = 0.0
        ey_r = 0.0
        ey_i = 0.0
        ez_r = 0.0
        ez_i = 0.0
        x0 = points[q, 0]
        y0 = points[q, 1]
        z0 = points[q, 2]
        for j in range(ndip):
            rx = x0 - positions[j, 0]
            ry = y0 - positions[j, 1]
            rz = z0 - positions[j, 2]
            r2 = rx * rx + ry * ry + rz * rz
            r = np.sqrt(r2)
            inv = 1.0 / r
            kr = k * r
            c = np.cos(kr) * inv
            s = np.sin(kr) * inv
            # a = e (k^2 - (1 - ikr)/r^2), b = e (3 (1 - ikr)/r^2 - k^2), e = exp(ikr)/r
            t_r = k * k - inv * inv
            t_i = k * inv
            a_r = c * t_r - s * t_i
            a_i = s * t_r + c * t_i
            u_r = 3.0 * inv * inv - k * k
            u_i = -3.0 * k * inv
            b_r = c * u_r - s * u_i
            b_i = s * u_r + c * u_i
            nx = rx * inv
            ny = ry * inv
            nz = rz * inv
            # n . P
            dr = nx * pr[j, 0] + ny * pr[j, 1] + nz * pr[j, 2]
            di = nx * pi[j, 0] + ny * pi[j, 1] + nz * pi[j, 2]
            # G P = a P + b n (n . P)
            bdr = b_r * dr - b_i * di
            bdi = b_r * di + b_i * dr
            ex_r += a_r * pr[j, 0] - a_i * pi[j, 0] + bdr * nx
            ex_i += a_r * pi[j, 0] + a_i * pr[j, 0] + bdi * nx
            ey_r += a_r * pr[j, 1] - a_i * pi[j, 1] + bdr * ny
            ey_i += a_r * pi[j, 1] + a_i * pr[j, 1] + bdi * ny
            ez_r += a_r * pr[j, 2] - a_i * pi[j, 2] + bdr * nz
            ez_i += a_r * pi[j, 2] + a_i * pr[j, 2] + bdi * nz
        out[q, 0] = ex_r + 1j * ex_i
        out[q, 1] = ey_r + 1j * ey_i
        out[q, 2] = ez_r + 1j * ez_i


def direct_field(
    points: NDArray[np.float64], positions: NDArray[np.float64], P: NDArray[np.complex128],
    k: float,
) -> NDArray[np.complex128]:
    """Field (N, 3) at ``points`` radiated by dipoles ``P`` at ``positions`` (same frame, um).

    Points must not coincide with a dipole.
    """
    pts = np.ascontiguousarray(np.atleast_2d(points), dtype=float)
    pos = np.ascontiguousarray(positions, dtype=float)
    out = np.empty((pts.shape[0], 3), dtype=complex)
    _direct(pts, pos, np.ascontiguousarray(P.real), np.ascontiguousarray(P.imag), float(k), out)
    return out
