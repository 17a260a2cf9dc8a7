"""The frame algebra between holofit and ADDA: labs, particle frames, angles, amplitudes.

All of it is here: the built-in engine's ADDA-convention amplitude matrix
(:meth:`holofit.dda.engine.DDAWave.amplitude_matrix`) and the ADDA adapter use these
functions, and :func:`orientation_from_adda` maps an ADDA run's ``-orient`` to holofit.

holofit's lab has the light travelling along -z; ADDA's along +z. The rotation
``T = Rx(pi) = diag(1, -1, -1)`` maps one onto the other (x stays, y and z flip). ADDA always
solves two incident polarisations, along its lab x ("X") and y ("Y"), with the LDR
polarisability of each; holofit puts the instrument's polarisation on ADDA's x, so that ADDA's
X solution is exactly the instrument's: holofit lab -> ADDA lab is ``M = T Rz(-beta)``
(:func:`lab_map`, ``M = T`` for x polarisation), with beta the polarisation angle.

ADDA is given the dipoles in holofit's particle frame flipped by ``T`` (``y -> -y``,
``z -> -z``), so that its particle-to-lab rotation is ``R_adda = M R T``, with
``R = Rz(psi) Ry(theta) Rz(phi)`` holofit's; for x polarisation ``T R T = Rz(-psi) Ry(-theta)
Rz(-phi)``. ``-orient`` gets the zyz angles of ``R_adda`` (beta in [0, 180] deg). A Janus
particle at holofit's theta = 0 (cap toward the source) has its cap toward ADDA's -z.

ADDA refers the incident phase and ``F(n)`` to the centre of its dipole box. With ``s`` the
particle centre relative to that point (lab frame) and ``a`` the propagation direction,
``F_centre(n) = F_adda(n) exp(-i k (a - n).s)`` (both frames give the same dot product).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import (
    PROPAGATION_DIRECTION,
    euler_zyz,
    euler_zyz_from_matrix,
    rotation_z,
)
from holofit.optics import Optics
from holofit.scattering.theory import Orientation

__all__ = [
    "T_LAB",
    "adda_amplitude_matrix",
    "adda_orientation_deg",
    "amplitude_vectors",
    "far_field_from_ampl",
    "lab_map",
    "lab_to_adda_angles",
    "orientation_from_adda",
    "phase_origin_factor",
]

#: holofit lab -> ADDA lab (and holofit particle frame -> ADDA particle frame): Rx(pi)
T_LAB = np.diag([1.0, -1.0, -1.0])


def lab_map(polarization_rad: float = 0.0) -> NDArray[np.float64]:
    """Rotation from holofit's lab onto the ADDA lab used for an instrument polarisation.

    ``M = T Rz(-beta)``: the instrument's polarisation ``(cos beta, sin beta, 0)`` becomes ADDA's
    x (so ADDA's "X" solution is the instrument's, with the LDR polarisability of that very
    polarisation) and the light's -z becomes ADDA's +z. ``M = T`` for x polarisation.
    """
    return T_LAB @ rotation_z(-polarization_rad)


def adda_orientation_deg(
    orientation: Orientation | None, polarization_rad: float = 0.0
) -> tuple[float, float, float]:
    """``-orient`` angles (deg) for a holofit orientation.

    ADDA gets the dipoles in holofit's particle frame flipped by ``T``, so its particle-to-lab
    rotation is ``M R T`` (``M`` = :func:`lab_map`; ``T R T`` for x polarisation). Returned as
    zyz angles with beta in [0, 180] and alpha, gamma in (-180, 180].
    """
    rot = euler_zyz(*(orientation or Orientation()).as_tuple())
    r_adda = lab_map(polarization_rad) @ rot @ T_LAB
    return tuple(math.degrees(float(v)) for v in euler_zyz_from_matrix(r_adda))  # type: ignore[return-value]


def lab_to_adda_angles(
    directions: ArrayLike, lab: ArrayLike = T_LAB
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """ADDA's scattering angles ``(theta, phi)`` (deg) of holofit-lab unit directions (M, 3).

    ``n_adda = lab @ n`` (``lab`` = :func:`lab_map`); ``theta`` in [0, 180] from ADDA's +z (the
    propagation direction), ``phi`` in [0, 360) from ADDA's x.
    """
    n = np.atleast_2d(np.asarray(directions, dtype=float)) @ np.asarray(lab, dtype=float).T
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    theta = np.degrees(np.arccos(np.clip(n[:, 2], -1.0, 1.0)))
    phi = np.degrees(np.arctan2(n[:, 1], n[:, 0])) % 360.0
    return theta, phi


def amplitude_vectors(
    s: ArrayLike, theta_deg: ArrayLike, phi_deg: ArrayLike, polarization: ArrayLike
) -> NDArray[np.complex128]:
    """Far-field vectors ``F(n)`` (M, 3) in ADDA's lab from ADDA's amplitude matrix.

    ADDA's (Bohren & Huffman) basis at ``n(theta, phi)``: ``e_par_i = (cos phi, sin phi, 0)``,
    ``e_per_i = (sin phi, -cos phi, 0)``, ``e_par_s = e_theta``, ``e_per_s = -e_phi``, and
    ``[E_par_s, E_per_s] = [[S2, S3], [S4, S1]] [E_par_i, E_per_i]``. For an incident field
    ``e exp(ikz)`` (``e`` in ADDA's xy plane, any complex combination), ``E_par_i = e.e_par_i``,
    ``E_per_i = e.e_per_i`` and ``F = E_par_s e_theta - E_per_s e_phi`` with
    ``E_sca = exp(ikr)/(-ikr) F``.

    Parameters
    ----------
    s : array_like, shape (M, 4)
        ``[S1, S2, S3, S4]`` per direction.
    theta_deg, phi_deg : array_like, shape (M,)
        ADDA's scattering angles, deg (the exact requested ones, not the printed ones).
    polarization : array_like, shape (3,)
        Incident polarisation in ADDA's lab (z component ignored).
    """
    s = np.asarray(s, dtype=complex)
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    e = np.asarray(polarization, dtype=complex)
    c, sn = np.cos(ph), np.sin(ph)
    e_par_i = e[0] * c + e[1] * sn
    e_per_i = e[0] * sn - e[1] * c
    e_par_s = s[:, 1] * e_par_i + s[:, 2] * e_per_i
    e_per_s = s[:, 3] * e_par_i + s[:, 0] * e_per_i
    e_theta = np.stack([np.cos(th) * c, np.cos(th) * sn, -np.sin(th)], axis=-1)
    e_phi = np.stack([-sn, c, np.zeros_like(ph)], axis=-1)
    return e_par_s[:, None] * e_theta - e_per_s[:, None] * e_phi


def phase_origin_factor(
    directions: ArrayLike, centre_offset_um: ArrayLike, k: float,
    propagation: ArrayLike = PROPAGATION_DIRECTION,
) -> NDArray[np.complex128]:
    """Factor that refers ADDA's amplitudes to the particle centre.

    ``F_centre(n) = F_adda(n) * exp(-i k (a - n).s)``, with ``s`` the particle centre relative to
    ADDA's origin (the dipole-box centre) and ``a`` the propagation direction, all in one lab
    frame (holofit's by default).
    """
    n = np.atleast_2d(np.asarray(directions, dtype=float))
    a = np.asarray(propagation, dtype=float)
    s = np.asarray(centre_offset_um, dtype=float)
    return np.exp(-1j * k * ((a[None, :] - n) @ s))


def far_field_from_ampl(
    s: ArrayLike, theta_deg: ArrayLike, phi_deg: ArrayLike, directions: ArrayLike,
    optics: Optics, rotation: ArrayLike, centre_offset_um: ArrayLike,
    lab: ArrayLike | None = None,
) -> NDArray[np.complex128]:
    """holofit's ``F(n)`` from ADDA's amplitude matrix (pure function of one run's numbers).

    Parameters
    ----------
    s : array_like, shape (M, 4)
        ADDA's ``[S1, S2, S3, S4]``.
    theta_deg, phi_deg : array_like, shape (M,)
        The ADDA angles that were requested (exact).
    directions : array_like, shape (M, 3)
        The same directions as holofit-lab unit vectors.
    optics : Optics
        For k and the instrument's polarisation (holofit lab).
    rotation : array_like, shape (3, 3)
        holofit's particle-to-lab rotation.
    centre_offset_um : array_like, shape (3,)
        Particle centre relative to ADDA's box centre, holofit particle frame, um.
    lab : array_like, shape (3, 3), optional
        holofit lab -> ADDA lab rotation of the run (default :func:`lab_map` of the optics'
        polarisation, as the engine runs ADDA; any other map superposes ADDA's X and Y
        solutions).

    Returns
    -------
    ndarray, shape (M, 3)
        Far-field vector in holofit's lab, phase origin at the particle centre.
    """
    m = lab_map(optics.polarization_rad) if lab is None else np.asarray(lab, dtype=float)
    e_adda = m @ optics.polarization
    f_adda = amplitude_vectors(s, theta_deg, phi_deg, e_adda)
    f_lab = f_adda @ m  # rows: M^T F
    s_lab = np.asarray(rotation, dtype=float) @ np.asarray(centre_offset_um, dtype=float)
    return f_lab * phase_origin_factor(directions, s_lab, optics.k)[:, None]


def adda_amplitude_matrix(
    f_x: NDArray[np.complex128], f_y: NDArray[np.complex128], theta: ArrayLike, phi: ArrayLike
) -> NDArray[np.complex128]:
    """Amplitude matrix ``[S1, S2, S3, S4]`` (M, 4) in ADDA's (Bohren & Huffman) basis.

    Parameters
    ----------
    f_x, f_y : ndarray, shape (M, 3)
        Far-field vectors in the *lab* frame of ADDA (light along +z) for incident
        polarisation along lab x and lab y.
    theta, phi : array_like
        Scattering angles of the directions, rad.
    """
    th = np.asarray(theta, dtype=float)
    ph = np.asarray(phi, dtype=float)
    e_th = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), -np.sin(th)], axis=-1)
    e_per = -np.stack([-np.sin(ph), np.cos(ph), np.zeros_like(ph)], axis=-1)  # -e_phi
    fx_t, fy_t = np.sum(f_x * e_th, axis=1), np.sum(f_y * e_th, axis=1)
    fx_p, fy_p = np.sum(f_x * e_per, axis=1), np.sum(f_y * e_per, axis=1)
    c, s = np.cos(ph), np.sin(ph)
    s2 = c * fx_t + s * fy_t
    s3 = s * fx_t - c * fy_t
    s4 = c * fx_p + s * fy_p
    s1 = s * fx_p - c * fy_p
    return np.stack([s1, s2, s3, s4], axis=1)


def orientation_from_adda(orient_deg: Sequence[float] = (0.0, 0.0, 0.0),
                          polarization_rad: float = 0.0) -> Orientation:
    """holofit orientation of an ADDA shape file's particle for ADDA's ``-orient`` angles.

    Parameters
    ----------
    orient_deg : sequence of 3 floats
        ADDA's ``-orient alpha beta gamma``, degrees.
    polarization_rad : float
        The instrument's polarisation angle in holofit's lab; ADDA's "X" solution is the one
        that corresponds to it.

    Returns
    -------
    Orientation
        ``(psi, theta, phi)`` with ``Rz(psi) Ry(theta) Rz(phi) = Rz(beta_pol) Rx(pi) R_adda``.

    Notes
    -----
    A user with an ADDA shape file and ADDA's ``-orient alpha beta gamma`` (zyz, degrees) gets
    the same physical configuration in holofit by reading the file as a
    :class:`~holofit.particles.VoxelShape` (its frame is then holofit's particle frame, unchanged)
    and giving the orientation returned here.

    ADDA rotates the particle by ``R_adda = Rz(alpha) Ry(beta) Rz(gamma)`` into a lab where the
    light travels along +z, polarised along x ("X") or y ("Y"). holofit's lab has the light along
    -z, polarised at ``beta_pol`` from x; the rotation ``M = Rx(pi) Rz(-beta_pol)`` maps holofit's
    lab onto ADDA's with the instrument's polarisation on ADDA's x. A particle-frame point at
    ``r`` is at ``R_adda r`` in ADDA's lab and at ``R r`` in holofit's, so ``R_adda = M R`` and

        R = Rz(beta_pol) Rx(pi) Rz(alpha) Ry(beta) Rz(gamma).

    Taking holofit's ``(psi, theta, phi) = (alpha, beta, gamma)`` instead (the same zyz form,
    but the wrong lab) differs by the ``Rx(pi)`` in front: harmless only for particles symmetric
    under a rotation by pi about x (a sphere, a rod), but it puts a Janus cap on the wrong side.

    Phase origin: ADDA refers phases to the centre of the dipole box; a ``VoxelShape`` with
    ``centre_um = (0, 0, 0)`` does too.
    """
    if len(orient_deg) != 3:
        raise ValueError(f"ADDA -orient takes three angles (alpha beta gamma), got {orient_deg}")
    r_adda = euler_zyz(*np.radians(np.asarray(orient_deg, dtype=float)))
    rot = lab_map(polarization_rad).T @ r_adda  # ADDA's lab back to holofit's
    psi, theta, phi = (float(v) for v in euler_zyz_from_matrix(rot))
    return Orientation(psi, theta, phi)
