"""The objective's pupil: what an ideal lens of numerical aperture NA does to each scattered
plane wave (pure functions on arrays).

Angular spectrum
----------------
Below the particle (light travels along -z), the scattered field is a superposition of plane
waves travelling in the directions ``n = (sin th cos ph, sin th sin ph, -cos th)``, ``th`` the
angle from the optical axis. Its propagating part is fixed exactly by the far-field amplitude
``F(n)`` (``E_s = exp(ikr)/(-ikr) F(n)``, phase origin at the particle centre): on the plane
a height ``z_p`` below the particle,

    E(dx, dy) = -1/(2 pi) Int_0^{pi/2} sin th dth Int_0^{2 pi} dph F(n)
                exp(i k [dx sin th cos ph + dy sin th sin ph + z_p cos th]),

the plane-wave (Weyl) representation of ``exp(ikr)/(-ikr)`` written per direction. The
evanescent part (``k_t > k``) is what a lens never collects.

The lens
--------
The objective collects the directions with ``sin th <= NA / n_medium`` (all propagating waves
if ``NA >= n_medium``) and images them onto the camera. In sample-plane coordinates (unit
magnification) the image is the integral above over the pupil, with ``F`` replaced by its
imaged transverse vector ``T``. ``apodization`` says how:

``"aplanatic"`` (default)
    An objective obeying Abbe's sine condition with a paraxial tube lens (the usual infinity
    system, magnification >> 1). Energy conservation ray by ray gives the amplitude factor
    ``sqrt(cos th)`` (the power a plane wave carries through the sample plane, ``|F|^2 cos th``
    per area, arrives in a near-normal wave at the camera), and the meridional component
    ``F_m = F . e_m`` (``e_m`` in the plane of ``n`` and the axis) turns with the ray onto the
    radial direction: ``T = sqrt(cos th) (F_m rho_hat + F_ph ph_hat)``. This is HoloPy's
    ``MieLens`` model (Leahy et al., Opt. Express 28, 1061 (2020)).
``"none"``
    The transverse part of each plane wave as it is in the sample: ``T = (F_x, F_y)`` =
    ``cos th F_m rho_hat + F_ph ph_hat``. With ``NA >= n_medium`` this is the propagating part
    of the exact field at the focal plane, i.e. holofit's ideal model minus its evanescent
    waves; useful to relate the two models, not a lens.

Both are written ``T = q_m(th) F_m rho_hat + q_ph(th) F_ph ph_hat`` with
``(q_m, q_ph) = (sqrt cos, sqrt cos)`` or ``(cos, 1)``.
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

if TYPE_CHECKING:
    from holofit.scattering.multipole import MultipoleExpansion

__all__ = [
    "APODIZATIONS",
    "aperture_angle",
    "apodization_factors",
    "check_apodization",
    "expansion_far_modes",
    "expansion_pupil_modes",
    "pupil_nodes",
    "sphere_pupil",
]

APODIZATIONS = ("aplanatic", "none")


def check_apodization(apodization: str) -> str:
    """``apodization`` if it is known, else a ValueError naming the choices."""
    if apodization not in APODIZATIONS:
        raise ValueError(
            f"unknown lens apodization {apodization!r}; choose one of {', '.join(APODIZATIONS)}"
        )
    return apodization


def aperture_angle(numerical_aperture: float, n_medium: float) -> float:
    """Largest collected angle from the axis, ``arcsin(min(NA / n_medium, 1))``, rad.

    Raises
    ------
    ValueError
        If the numerical aperture is not positive.
    """
    na = float(numerical_aperture)
    if not na > 0:
        raise ValueError(f"numerical_aperture must be positive, got {numerical_aperture}")
    return float(np.arcsin(min(na / float(n_medium), 1.0)))


def apodization_factors(
    cos_theta: ArrayLike, apodization: str = "aplanatic"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(q_m, q_ph)``: the factors on the meridional and azimuthal far-field components."""
    c = np.asarray(cos_theta, dtype=float)
    if check_apodization(apodization) == "aplanatic":
        s = np.sqrt(np.maximum(c, 0.0))
        return s, s
    return c, np.ones_like(c)


def pupil_nodes(
    theta_max: float, n: int, sqrt_endpoint: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Legendre nodes and weights for ``Int_0^theta_max f(th) dth``.

    With ``sqrt_endpoint`` the variable is ``th = theta_max s (2 - s)``, which makes a
    ``sqrt(cos th)`` factor analytic at ``theta_max = pi/2`` (an aplanatic lens collecting all
    propagating waves) and tames it just below.

    Returns
    -------
    theta, weights : ndarray, shape (n,)
        Angles (rad) and weights (Jacobian included).
    """
    s, w = _unit_gauss_legendre(int(n))
    if sqrt_endpoint:
        return theta_max * s * (2.0 - s), w * theta_max * 2.0 * (1.0 - s)
    return theta_max * s, w * theta_max


@functools.lru_cache(maxsize=32)
def _unit_gauss_legendre(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Legendre nodes and weights on [0, 1] (cached; scipy's tridiagonal eigensolver:
    numpy's ``leggauss`` solves a dense companion matrix, seconds for a thousand nodes)."""
    s, w = special.roots_legendre(n)
    s, w = 0.5 * (s + 1.0), 0.5 * w
    s.flags.writeable = False
    w.flags.writeable = False
    return s, w


def sphere_pupil(
    s1: ArrayLike, s2: ArrayLike, cos_theta: ArrayLike, apodization: str = "aplanatic"
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Imaged pupil field of a sphere: ``T_x' = a + b cos 2ph'``, ``T_y' = b sin 2ph'``.

    In the frame whose x' axis is the incident polarisation (azimuth ``ph'`` from it), the far
    field of a sphere is ``F = S2 cos ph' e_m - S1 sin ph' ph_hat`` (Bohren & Huffman's
    amplitudes ``S1, S2`` at the scattering angle ``th``), so ``a = (q_ph S1 + q_m S2)/2`` and
    ``b = (q_m S2 - q_ph S1)/2``.
    """
    q_m, q_ph = apodization_factors(cos_theta, apodization)
    s1 = np.asarray(s1)
    s2 = np.asarray(s2)
    return 0.5 * (q_ph * s1 + q_m * s2), 0.5 * (q_m * s2 - q_ph * s1)


def expansion_pupil_modes(
    expansion: MultipoleExpansion, theta: ArrayLike, apodization: str = "aplanatic"
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Azimuthal Fourier modes of the imaged pupil field of a multipole expansion.

    Parameters
    ----------
    expansion : MultipoleExpansion
        Lab-frame outgoing expansion (:class:`holofit.scattering.multipole.MultipoleExpansion`) of
        order L.
    theta : array_like, shape (N,)
        Angles from the optical axis (downstream directions), rad.
    apodization : str
        See the module docstring.

    Returns
    -------
    t_plus, t_minus : ndarray of complex, shape (N, 2L + 3)
        Modes ``m = -(L+1) .. L+1`` (column ``m + L + 1``) of ``T_+ = T_x + i T_y`` and
        ``T_- = T_x - i T_y``: ``T_+(th, ph) = sum_m t_plus[:, m + L + 1] exp(i m ph)``.

    Notes
    -----
    The expansion gives ``F_th^m, F_ph^m`` (spherical components about +z, per azimuthal order
    ``m``, :func:`expansion_far_modes`); downstream ``th_s = pi - th`` and ``e_th = -e_m``.
    With ``R = -q_m F_th`` and ``Ph = q_ph F_ph``, ``T_+ = (R + i Ph) exp(i ph)`` and
    ``T_- = (R - i Ph) exp(-i ph)``: the modes shift by one order each way.
    """
    theta = np.asarray(theta, dtype=float)
    L = expansion.order
    f_t, f_p = expansion_far_modes(expansion, np.pi - theta)
    q_m, q_ph = apodization_factors(np.cos(theta), apodization)
    r = -q_m[:, None] * f_t
    ph = q_ph[:, None] * f_p
    t_plus = np.zeros((theta.size, 2 * L + 3), dtype=complex)
    t_minus = np.zeros_like(t_plus)
    # source order m (column m + L of r) lands at m + 1 in T_+ (column m + L + 2) and at m - 1
    # in T_- (column m + L)
    t_plus[:, 2:] = r + 1j * ph
    t_minus[:, :-2] = r - 1j * ph
    return t_plus, t_minus


def expansion_far_modes(
    expansion: MultipoleExpansion, theta_s: ArrayLike
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Far-field amplitude ``F = E (-ikr) exp(-ikr)`` of an expansion, per azimuthal order.

    Parameters
    ----------
    expansion : MultipoleExpansion
        Coefficients ``p_nm, q_nm`` of ``N_nm, M_nm`` (:mod:`holofit.scattering.multipole`).
    theta_s : array_like, shape (N,)
        Polar angles from +z, rad.

    Returns
    -------
    f_th, f_ph : ndarray of complex, shape (N, 2L + 1)
        ``F_th(th, ph) = sum_m f_th[:, m + L] exp(i m ph)``, likewise ``F_ph``.

    Notes
    -----
    In the far field ``h_n -> (-i)^(n+1) exp(ikr)/(kr)`` and ``xi_n'/(kr) -> (-i)^n exp(ikr)/(kr)``,
    so ``A = i F`` has ``A_th^m = sum_n (-i)^n (p_nm dY_nm + q_nm mY_nm)`` and
    ``A_ph^m = i sum_n (-i)^n (p_nm mY_nm + q_nm dY_nm)``, with ``dY = dPbar_n^m/dth`` and
    ``mY = m Pbar_n^m / sin th`` (``Pbar`` orthonormal, Condon-Shortley phase;
    ``Pbar_n^-m = (-1)^m Pbar_n^m``).
    """
    theta_s = np.asarray(theta_s, dtype=float)
    L = expansion.order
    dpt, mpt = _far_tables(theta_s, L)  # [m >= 0, pt, n]
    c = ((-1j) ** np.arange(L + 1))[:, None]
    p = expansion.p * c
    q = expansion.q * c
    # coefficients per |m| (rows n): p, q at +m and at -m (times (-1)^m, which the tables
    # carry for negative orders), as real columns for real matrix products
    sign = ((-1.0) ** np.arange(L + 1))[None, :]
    m = np.arange(L + 1)
    coef = np.stack([p[:, L + m], q[:, L + m], p[:, L - m] * sign, q[:, L - m] * sign])
    coef = np.ascontiguousarray(np.moveaxis(coef, 2, 0))  # [m, (p+, q+, p-, q-), n]
    real = np.ascontiguousarray(np.swapaxes(coef, 1, 2)).view(np.float64)  # [m, n, 8]
    d = np.matmul(dpt, real).view(complex)
    e = np.matmul(mpt, real).view(complex)
    # d, e: [m, pt, (p+, q+, p-, q-)] contracted with dY and mY; for -m, mY changes sign
    a_t = np.empty((theta_s.size, 2 * L + 1), dtype=complex)
    a_p = np.empty_like(a_t)
    a_t[:, L:] = (d[:, :, 0] + e[:, :, 1]).T
    a_p[:, L:] = 1j * (e[:, :, 0] + d[:, :, 1]).T
    a_t[:, L - 1 :: -1] = (d[1:, :, 2] - e[1:, :, 3]).T
    a_p[:, L - 1 :: -1] = 1j * (-e[1:, :, 2] + d[1:, :, 3]).T
    return -1j * a_t, -1j * a_p


#: bytes of Legendre tables kept (:func:`_far_tables`): a pupil rule's are shared by every
#: wave imaged through it (a fit's orientations and their derivative waves)
FAR_TABLES_BYTES = 64 * 2**20
_FAR_TABLES: OrderedDict[tuple, tuple[NDArray[np.float64], NDArray[np.float64]]] = OrderedDict()
_FAR_TABLES_LOCK = threading.Lock()


def _far_tables(theta_s: NDArray[np.float64], order: int) -> tuple[NDArray, NDArray]:
    """``dPbar_n^m/dth`` and ``m Pbar_n^m / sin th`` at ``theta_s`` for ``n, m <= order``, in
    the layout ``[m, point, n]`` of :func:`expansion_far_modes`'s products (read-only).

    They depend on the pupil's nodes and the order only, not on the wave: cached (the most recent
    node sets and orders, up to :data:`FAR_TABLES_BYTES`), so that a new orientation of a particle,
    or a derivative wave, imaged through the same pupil rule costs no Legendre recurrence.
    """
    from holofit.scattering.legendre import legendre_tables

    key = (int(order), theta_s.shape, theta_s.tobytes())
    with _FAR_TABLES_LOCK:
        tables = _FAR_TABLES.get(key)
        if tables is not None:
            _FAR_TABLES.move_to_end(key)
            return tables
    _, dp, mp = legendre_tables(np.ascontiguousarray(np.cos(theta_s)), order)  # [pt, n, m]
    tables = (np.ascontiguousarray(dp.transpose(2, 0, 1)),
              np.ascontiguousarray(mp.transpose(2, 0, 1)))
    for t in tables:
        t.flags.writeable = False
    with _FAR_TABLES_LOCK:
        _FAR_TABLES[key] = tables
        while len(_FAR_TABLES) > 1 and sum(
                a.nbytes + b.nbytes for a, b in _FAR_TABLES.values()) > FAR_TABLES_BYTES:
            _FAR_TABLES.popitem(last=False)
    return tables
