"""The one place where holofit's conventions live.

Every other module imports its geometry, units and hologram formula from here, so that a
sign or an axis is defined exactly once (the paper's frame and hologram, section 2).

Units
-----
Lengths are in micrometres (um), times in seconds (s), angles in radians (rad) everywhere
inside the code. Tables say their unit in the column name (``x_um``, ``theta_rad``) and in the
sidecar JSON.

Image axes
----------
A pixel is addressed ``[row i, column j]``. The sample-plane coordinates of its centre are
``x = j * pixel_size`` and ``y = i * pixel_size``: x runs along the columns, y along the rows
(as in trackpy and pylorenzmie). Positions are always full-frame; a crop carries the full-frame
index of its corner pixel. HoloPy's x is the row: compare with it through
:func:`holopy_to_holofit_xy`.

Axial coordinate
----------------
``z`` is the distance of the particle centre from the focal plane, positive toward the light
source (upstream). The illumination propagates along ``-z``. The frame is right-handed,
``z = x cross y``.

Orientation
-----------
The particle frame has its symmetry axis along particle ``+z`` (rod axis, Janus cap, dimer
axis). The lab orientation is the active rotation ``R = Rz(psi) Ry(theta) Rz(phi)``, which maps
particle-frame vectors to lab vectors; the axis is ``u = R z_hat = (sin theta cos psi,
sin theta sin psi, cos theta)``. ``theta = 0`` points the axis (or the Janus cap) toward the
light source.

Incident light and hologram
---------------------------
A plane wave of unit amplitude at the focal plane, ``E_inc(r) = e_pol exp(-i k z)``, with time
dependence ``exp(-i omega t)`` (absorbing materials have ``Im n > 0``) and linear polarisation
``e_pol = (cos beta, sin beta, 0)``. The recorded, background-normalised hologram is

    I = | e_pol + alpha * E_s,perp |^2

where ``E_s`` is the scattered field at the pixel relative to the incident field, including the
incident phase at the particle, ``exp(-i k z_p)``, and ``perp`` keeps the x and y components.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ANGLE_UNIT",
    "LENGTH_UNIT",
    "PROPAGATION_DIRECTION",
    "TIME_UNIT",
    "DetectorGrid",
    "angles_from_axis",
    "axis_from_angles",
    "euler_zyz",
    "euler_zyz_from_matrix",
    "hologram_intensity",
    "holopy_to_holofit_xy",
    "incident_phase_at",
    "medium_wavenumber",
    "pixel_centres",
    "polarization_vector",
    "r_squared",
    "rotation_from_vector",
    "rotation_y",
    "rotation_z",
]

LENGTH_UNIT = "um"
TIME_UNIT = "s"
ANGLE_UNIT = "rad"

#: Direction in which the illumination travels, in the lab frame.
PROPAGATION_DIRECTION = np.array([0.0, 0.0, -1.0])


def medium_wavenumber(wavelength_vacuum_um: float, n_medium: float) -> float:
    """Wavenumber in the medium.

    Parameters
    ----------
    wavelength_vacuum_um : float
        Vacuum wavelength, um.
    n_medium : float
        Refractive index of the medium (real).

    Returns
    -------
    float
        ``k = 2 pi n_medium / lambda_vac``, rad/um.
    """
    return 2.0 * np.pi * n_medium / wavelength_vacuum_um


def polarization_vector(angle_rad: float) -> NDArray[np.float64]:
    """Unit incident polarisation ``(cos beta, sin beta, 0)`` for an angle beta from lab x."""
    return np.array([np.cos(angle_rad), np.sin(angle_rad), 0.0])


def incident_phase_at(z_um: ArrayLike, k: float) -> NDArray[np.complex128]:
    """Phase factor of the incident wave at height z, ``exp(-i k z)`` (light travels along -z)."""
    return np.exp(-1j * k * np.asarray(z_um, dtype=float))


def rotation_z(angle: float) -> NDArray[np.float64]:
    """Active rotation by ``angle`` (rad) about z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_y(angle: float) -> NDArray[np.float64]:
    """Active rotation by ``angle`` (rad) about y."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def euler_zyz(psi: float, theta: float, phi: float = 0.0) -> NDArray[np.float64]:
    """Particle-to-lab rotation ``R = Rz(psi) Ry(theta) Rz(phi)``.

    Parameters
    ----------
    psi, theta, phi : float
        zyz Euler angles, rad. ``psi`` is the azimuth of the symmetry axis, ``theta`` its polar
        angle from lab +z (toward the source), ``phi`` the spin about the particle axis.

    Returns
    -------
    ndarray, shape (3, 3)
        Active rotation matrix: a particle-frame vector ``v_p`` is ``R @ v_p`` in the lab.
        ADDA's ``-orient alpha beta gamma`` has the same zyz form, but in ADDA's lab, where the
        light travels along +z: ADDA's angles are *not* holofit's. A shape in ADDA's particle
        frame at ADDA's orientation ``R_adda`` has ``R = Rz(beta_pol) Rx(pi) R_adda`` here
        (:func:`holofit.dda.adda.frames.orientation_from_adda`); reusing the angles directly
        mirrors any particle that is not symmetric under ``Rx(pi)``, e.g. a Janus sphere.
    """
    return rotation_z(psi) @ rotation_y(theta) @ rotation_z(phi)


def euler_zyz_from_matrix(r: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """``(psi, theta, phi)`` with ``R = Rz(psi) Ry(theta) Rz(phi)`` (holofit's convention).

    At ``theta = 0`` or ``pi`` only ``psi +- phi`` is defined; ``phi = 0`` is chosen then.
    """
    r = np.asarray(r, dtype=float)
    theta = np.arccos(np.clip(r[..., 2, 2], -1.0, 1.0))
    psi = np.arctan2(r[..., 1, 2], r[..., 0, 2])
    phi = np.arctan2(r[..., 2, 1], -r[..., 2, 0])
    pole = np.sin(theta) < 1e-12
    if np.any(pole):
        # R = Rz(psi + phi) (theta = 0) or Rz(psi - phi) Ry(pi) (theta = pi)
        psi = np.where(pole, np.arctan2(r[..., 1, 0], r[..., 0, 0]), psi)
        phi = np.where(pole, 0.0, phi)
        psi = np.where(pole & (r[..., 2, 2] < 0), np.arctan2(-r[..., 0, 1], r[..., 1, 1]), psi)
    return psi, theta, phi


def rotation_from_vector(w: ArrayLike) -> NDArray[np.float64]:
    """The rotation ``exp([w]_x)`` by angle ``|w|`` (rad) about ``w`` (Rodrigues' formula).

    Parameters
    ----------
    w : array_like, shape (..., 3)
        Rotation vector(s), rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices (the identity where ``w = 0``).
    """
    w = np.asarray(w, dtype=float)
    angle = np.linalg.norm(w, axis=-1)
    k = w / np.where(angle > 0, angle, 1.0)[..., None]
    kx = np.zeros((*w.shape[:-1], 3, 3))
    kx[..., 0, 1], kx[..., 0, 2] = -k[..., 2], k[..., 1]
    kx[..., 1, 0], kx[..., 1, 2] = k[..., 2], -k[..., 0]
    kx[..., 2, 0], kx[..., 2, 1] = -k[..., 1], k[..., 0]
    s = np.sin(angle)[..., None, None]
    c = (1.0 - np.cos(angle))[..., None, None]
    return np.eye(3) + s * kx + c * (kx @ kx)


def axis_from_angles(theta: ArrayLike, psi: ArrayLike) -> NDArray[np.float64]:
    """Unit symmetry axis ``u = (sin th cos psi, sin th sin psi, cos th)``, shape (..., 3)."""
    theta = np.asarray(theta, dtype=float)
    psi = np.asarray(psi, dtype=float)
    st = np.sin(theta)
    return np.stack([st * np.cos(psi), st * np.sin(psi), np.cos(theta)], axis=-1)


def angles_from_axis(u: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Polar angle theta in [0, pi] and azimuth psi in (-pi, pi] of unit vector(s) ``u``."""
    u = np.asarray(u, dtype=float)
    norm = np.linalg.norm(u, axis=-1)
    theta = np.arccos(np.clip(u[..., 2] / norm, -1.0, 1.0))
    psi = np.arctan2(u[..., 1], u[..., 0])
    return theta, psi


@dataclass(frozen=True)
class DetectorGrid:
    """A rectangular block of camera pixels in full-frame coordinates.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, columns)`` of the block.
    pixel_size_um : float
        Pixel pitch in the sample plane, um.
    corner : tuple of int
        Full-frame ``(row, column)`` index of the block's pixel ``[0, 0]``.
    """

    shape: tuple[int, int]
    pixel_size_um: float
    corner: tuple[int, int] = (0, 0)

    def coordinates(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Sample-plane ``(x, y)`` of every pixel centre, um, each of shape ``shape``."""
        return pixel_centres(self.shape, self.pixel_size_um, self.corner)

    @property
    def size(self) -> int:
        """Number of pixels."""
        return int(self.shape[0] * self.shape[1])


def pixel_centres(
    shape: tuple[int, int], pixel_size_um: float, corner: tuple[int, int] = (0, 0)
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Full-frame sample-plane coordinates of pixel centres.

    Returns
    -------
    x, y : ndarray
        ``x[i, j] = (corner_col + j) * pixel_size``, ``y[i, j] = (corner_row + i) * pixel_size``,
        um.
    """
    rows = (corner[0] + np.arange(shape[0])) * pixel_size_um
    cols = (corner[1] + np.arange(shape[1])) * pixel_size_um
    y, x = np.meshgrid(rows, cols, indexing="ij")
    return x, y


def holopy_to_holofit_xy(x_holopy: float, y_holopy: float) -> tuple[float, float]:
    """HoloPy's (x, y) is (row, column) times the pixel size; holofit's is (column, row)."""
    return y_holopy, x_holopy


def hologram_intensity(
    e_x: ArrayLike, e_y: ArrayLike, polarization_angle: float, alpha: float = 1.0
) -> NDArray[np.float64]:
    """Normalised in-line hologram ``|e_pol + alpha E_s,perp|^2``.

    Parameters
    ----------
    e_x, e_y : array_like of complex
        Lab x and y components of the scattered field at the pixels, relative to the incident
        field, *including* the incident phase at the particle.
    polarization_angle : float
        Angle of the incident polarisation from lab x, rad.
    alpha : float
        Scaling of the scattered field (dimensionless).

    Returns
    -------
    ndarray of float
        Intensity relative to the background (background = 1).
    """
    e_x, e_y = np.asarray(e_x), np.asarray(e_y)
    # |cos + alpha e_x|^2 + |sin + alpha e_y|^2 on real and imaginary parts (no complex
    # temporaries: the fits evaluate it at every step)
    a_r = np.cos(polarization_angle) + alpha * e_x.real
    a_i = alpha * e_x.imag
    b_r = np.sin(polarization_angle) + alpha * e_y.real
    b_i = alpha * e_y.imag
    return a_r * a_r + a_i * a_i + b_r * b_r + b_i * b_i


def r_squared(data: ArrayLike, model: ArrayLike, mask: ArrayLike | None = None) -> float:
    """Coefficient of determination of ``model`` as a description of ``data``.

    ``R^2 = 1 - sum (data - model)^2 / sum (data - mean(data))^2`` over unmasked pixels
    (the paper's definition, with the data's own mean).
    """
    d = np.asarray(data, dtype=float)
    m = np.asarray(model, dtype=float)
    if mask is not None:
        keep = np.asarray(mask, dtype=bool)
        d, m = d[keep], m[keep]
    ss_res = float(np.sum((d - m) ** 2))
    ss_tot = float(np.sum((d - d.mean()) ** 2))
    return 1.0 - ss_res / ss_tot
