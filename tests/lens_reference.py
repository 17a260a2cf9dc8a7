"""Independent references for the lens tests: a brute-force 2-D pupil integral of any far field
(through an ideal or an aberrated pupil), and the evanescent part of a sphere's field (written
apart from holofit.scattering.lens and holofit.aberration)."""

from __future__ import annotations

import numpy as np
from scipy import special


def pupil_integral(far_field, k, position, xs, ys, theta_max, apodization="aplanatic",
                   n_v=300, n_phi=160, chunk=64, pupil_factor=None):
    """``-exp(-ikz)/(2 pi) Int sin th dth dph P T exp(ik(...))`` by a tensor-product rule.

    The polar variable is ``v`` with ``cos th = v^2`` (Gauss-Legendre in v, which makes
    ``sqrt(cos th)`` analytic at grazing incidence); the azimuth uses the trapezoid rule.
    ``far_field(directions (N, 3)) -> F (N, 3)`` with ``E_s = exp(ikr)/(-ikr) F``.
    ``pupil_factor(cos_theta, phi) -> P`` (arrays of the rule's (n_v, n_phi) grid; default 1)
    multiplies each plane wave: an aberrated objective's ``exp(i Phi)``, or a derivative's
    ``i dPhi/dc exp(i Phi)``.
    """
    xp, yp, zp = position
    v0 = np.sqrt(np.cos(theta_max))
    s, w = np.polynomial.legendre.leggauss(n_v)
    v = v0 + (1 - v0) * (s + 1) / 2
    wv = w * (1 - v0) / 2 * 2 * v  # sin th dth = d(cos th) = 2 v dv
    cos_t = v**2
    sin_t = np.sqrt(1 - cos_t**2)
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    ct, cp = np.meshgrid(cos_t, np.cos(phi), indexing="ij")
    st, sp = np.meshgrid(sin_t, np.sin(phi), indexing="ij")
    n = np.stack([st * cp, st * sp, -ct], axis=-1).reshape(-1, 3)
    f = np.asarray(far_field(n)).reshape(n_v, n_phi, 3)
    e_m = np.stack([ct * cp, ct * sp, st], axis=-1)
    e_p = np.stack([-sp, cp, np.zeros_like(cp)], axis=-1)
    f_m = np.sum(f * e_m, axis=-1)
    f_p = np.sum(f * e_p, axis=-1)
    if apodization == "aplanatic":
        q = np.sqrt(ct)
        tx = q * (f_m * cp - f_p * sp)
        ty = q * (f_m * sp + f_p * cp)
    else:
        tx, ty = f[..., 0], f[..., 1]
    weight = (wv[:, None] * (2 * np.pi / n_phi)) * np.exp(1j * k * zp * ct)
    if pupil_factor is not None:
        weight = weight * pupil_factor(ct, phi[None, :] + 0 * ct)
    kx = (k * st * cp).ravel()
    ky = (k * st * sp).ravel()
    tx = (tx * weight).ravel()
    ty = (ty * weight).ravel()
    xs = np.asarray(xs, float).ravel() - xp
    ys = np.asarray(ys, float).ravel() - yp
    ex = np.empty(xs.size, complex)
    ey = np.empty(xs.size, complex)
    for i in range(0, xs.size, chunk):
        ph = np.exp(1j * (np.outer(xs[i:i + chunk], kx) + np.outer(ys[i:i + chunk], ky)))
        ex[i:i + chunk] = ph @ tx
        ey[i:i + chunk] = ph @ ty
    pre = -np.exp(-1j * k * zp) / (2 * np.pi)
    return pre * ex, pre * ey


def mie_far_field(wave):
    """``F(n)`` of a MieWave from its own far-field kernel: ``F = E (-ikR) exp(-ikR)``."""
    k = wave.optics.k
    r = 1e4

    def far(n):
        e = wave.field_at(np.asarray(n) * r, far_field=True)
        return e * (-1j * k * r) * np.exp(-1j * k * r)

    return far


def _pi_tau(mu, nmax):
    mu = np.asarray(mu, dtype=complex)
    pi = np.zeros((nmax, mu.size), complex)
    tau = np.zeros_like(pi)
    p0, p1 = np.zeros_like(mu), np.ones_like(mu)
    for n in range(1, nmax + 1):
        pi[n - 1] = p1
        tau[n - 1] = n * mu * p1 - (n + 1) * p0
        p0, p1 = p1, ((2 * n + 1) * mu * p1 - (n + 1) * p0) / n
    return pi, tau


def mie_evanescent(wave, position, xs, ys, n_kappa=400):
    """The evanescent part (k_t > k) of a sphere's exact field on the plane, per pixel.

    ``E = (i/(2 pi k)) exp(-ikz) Int_0^inf dkappa exp(-kappa z) Int dph F_perp exp(i k_t.rho)``
    with ``k_z = i kappa``, ``cos th = i kappa / k`` in Bohren & Huffman's ``S1, S2`` (polynomials
    in ``cos th``, continued to complex angles). Polarisation along lab x only.
    """
    assert wave.optics.polarization_rad == 0.0
    k = wave.optics.k
    xp, yp, zp = position
    kap_max = 60.0 / zp
    s, w = np.polynomial.legendre.leggauss(n_kappa)
    kap = kap_max * (s + 1) / 2
    wk = w * kap_max / 2
    mu = 1j * kap / k
    kt = np.sqrt(k**2 + kap**2)
    a_n, b_n = wave.a, wave.b
    nn = np.arange(1, a_n.size + 1)
    c = (2 * nn + 1) / (nn * (nn + 1.0))
    pi, tau = _pi_tau(mu, a_n.size)
    s1 = (c * a_n) @ pi + (c * b_n) @ tau
    s2 = (c * a_n) @ tau + (c * b_n) @ pi
    a = 0.5 * (s1 + mu * s2)
    b = 0.5 * (mu * s2 - s1)
    dx = np.asarray(xs, float).ravel() - xp
    dy = np.asarray(ys, float).ravel() - yp
    rho = np.hypot(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        c2 = np.where(rho > 0, (dx**2 - dy**2) / rho**2, 1.0)
        s2p = np.where(rho > 0, 2 * dx * dy / rho**2, 0.0)
    arg = np.outer(rho, kt)
    j0 = special.j0(arg)
    j2 = special.jv(2, arg)
    weight = wk * np.exp(-kap * zp)
    i0 = j0 @ (weight * a)
    i2 = j2 @ (weight * b)
    pre = 1j / k * np.exp(-1j * k * zp)
    return pre * (i0 - i2 * c2), pre * (-i2 * s2p)


def spherical_pupil_phase(coefficients):
    """The pupil phase of spherical aberration written out by hand, ``cos th`` -> rad.

    HoloPy's form (Martin, Leahy & Manoharan 2022): in its conjugate time convention the phase
    ``x^2 sum_k c_k P_k(x)``, ``x = cos th - 1``, joins its defocus ``k z (1 - cos th)``; in
    holofit's ``exp(-i omega t)`` the same pupil is the conjugate, ``-x^2 sum_k c_k P_k(x)``.
    ``P_0..P_3`` are written out (no recurrence, no numpy.polynomial).
    """
    c = list(coefficients) + [0.0] * (4 - len(coefficients))

    def phase(cos_theta):
        x = np.asarray(cos_theta) - 1.0
        legendre = (c[0] + c[1] * x + c[2] * (3 * x**2 - 1) / 2
                    + c[3] * (5 * x**3 - 3 * x) / 2)
        return -(x**2) * legendre

    return phase


def aberrated_factor(coefficients, derivative=None):
    """``pupil_factor`` for :func:`pupil_integral`: ``exp(i Phi)``, or with ``derivative = j``
    its derivative with respect to coefficient ``j``, ``i dPhi/dc_j exp(i Phi)``."""
    phase = spherical_pupil_phase(coefficients)

    def factor(cos_theta, phi):
        f = np.exp(1j * phase(cos_theta))
        if derivative is None:
            return f
        unit = [0.0] * 4
        unit[derivative] = 1.0
        return 1j * spherical_pupil_phase(unit)(cos_theta) * f

    return factor
