"""Exact Lorenz-Mie: far-field amplitudes, cross sections, near field.

Oracles: miepython (conjugate time convention), an independent Bohren & Huffman file shipped
with the ADDA reference data, mpmath arbitrary-precision coefficients, the optical theorem and
energy conservation, and an independent near-field series written here with scipy's spherical
Bessel and associated Legendre functions.
"""

import miepython
import mpmath as mp
import numpy as np
import pytest
from scipy import special

from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie, cross_sections, far_field_amplitudes
from holofit.scattering.mie_coefficients import mie_coefficients, n_stop
from tests.conftest import DATA

SIZES = [0.1, 0.5, 1.0, 3.0, 10.0, 25.0, 50.0]
INDICES = [1.05, 1.33, 1.6, 2.0, 2.7, 1.5 + 0.01j, 2.7 + 0.1j, 1.33 + 0.5j]


@pytest.mark.parametrize("x", SIZES)
@pytest.mark.parametrize("m", INDICES)
def test_amplitudes_match_miepython(m, x):
    theta = np.linspace(0, np.pi, 91)
    # miepython: exp(+i w t), absorbing index has Im < 0, amplitudes are our conjugates.
    a_mp, _ = miepython.coefficients(np.conj(m), x)
    r1, r2 = miepython.S1_S2(np.conj(m), x, np.cos(theta), norm="wiscombe")
    s1, s2 = far_field_amplitudes(m, x, theta, nmax=len(a_mp))  # same series length
    scale = max(np.abs(s1).max(), np.abs(s2).max())
    assert np.max(np.abs(s1 - np.conj(r1))) / scale < 1e-10
    assert np.max(np.abs(s2 - np.conj(r2))) / scale < 1e-10


@pytest.mark.parametrize("m,x", [(1.6, 50.0), (2.0, 25.0), (2.7 + 0.1j, 20.0), (1.05, 0.1)])
def test_coefficients_match_arbitrary_precision(m, x):
    """Our a_n, b_n against mpmath at 40 digits, all orders up to the truncation."""
    mp.mp.dps = 40
    a, b = mie_coefficients(m, x)
    mm, xx = mp.mpc(m.real, m.imag), mp.mpf(x)

    def psi(z, n):
        return z * mp.sqrt(mp.pi / (2 * z)) * mp.besselj(n + 0.5, z)

    def xi(z, n):
        return z * mp.sqrt(mp.pi / (2 * z)) * (mp.besselj(n + 0.5, z) + 1j * mp.bessely(n + 0.5, z))

    ref_a, ref_b = [], []
    for n in range(1, a.size + 1):
        d_psi_x = psi(xx, n - 1) - n * psi(xx, n) / xx
        d_psi_mx = psi(mm * xx, n - 1) - n * psi(mm * xx, n) / (mm * xx)
        d_xi_x = xi(xx, n - 1) - n * xi(xx, n) / xx
        p_mx, p_x, x_x = psi(mm * xx, n), psi(xx, n), xi(xx, n)
        ref_a.append(
            complex((mm * p_mx * d_psi_x - p_x * d_psi_mx) / (mm * p_mx * d_xi_x - x_x * d_psi_mx))
        )
        ref_b.append(
            complex((p_mx * d_psi_x - mm * p_x * d_psi_mx) / (p_mx * d_xi_x - mm * x_x * d_psi_mx))
        )
    assert np.max(np.abs(a - ref_a)) / np.max(np.abs(ref_a)) < 1e-12
    assert np.max(np.abs(b - ref_b)) / np.max(np.abs(ref_b)) < 1e-11


def test_truncation_error_of_default_series_is_negligible():
    # our series is longer than Wiscombe's: the neglected tail is below 1e-12 of the largest term
    for x in [*SIZES, 100.0, 300.0]:
        for m in INDICES:
            a, b = mie_coefficients(m, x, n_stop(x) + 20)
            n = n_stop(x)
            tail = max(np.abs(a[n:]).max(), np.abs(b[n:]).max())
            assert tail < 1e-12 * max(np.abs(a).max(), np.abs(b).max()), (m, x)


def test_against_independent_bohren_huffman_file():
    """ADDA's reference set ships exact Mie S1, S2 for its sphere case (independent code)."""
    rows = np.loadtxt(DATA / "adda" / "a_sphere_r0.45" / "mie_S1S2.txt", skiprows=3)
    m, x = 1.191729323, 5.6977066763
    s1, s2 = far_field_amplitudes(m, x, np.radians(rows[:, 0]))
    np.testing.assert_allclose(s1, rows[:, 1] + 1j * rows[:, 2], rtol=2e-10)
    np.testing.assert_allclose(s2, rows[:, 3] + 1j * rows[:, 4], rtol=2e-10)
    k = 2 * np.pi / 0.4962406015
    assert cross_sections(m, 0.45, k).extinction_um2 == pytest.approx(1.2958513145, rel=1e-9)


@pytest.mark.parametrize("m", [1.2, 1.6 + 0.05j, 2.7 + 0.3j])
@pytest.mark.parametrize("x", [0.3, 5.0, 40.0, 100.0])
def test_optical_theorem_and_energy_balance(m, x):
    k = 1.0
    cs = cross_sections(m, x / k, k)
    s1, s2 = far_field_amplitudes(m, x, np.array([0.0]))
    assert s1[0] == pytest.approx(s2[0], rel=1e-12)
    # optical theorem: C_ext = 4 pi / k^2 Re S(0)
    assert cs.extinction_um2 == pytest.approx(4 * np.pi / k**2 * s1[0].real, rel=1e-10)
    # C_sca = pi/k^2 int (|S1|^2 + |S2|^2) sin th dth, by Gauss-Legendre quadrature
    nodes, weights = np.polynomial.legendre.leggauss(4 * n_stop(x) + 20)
    t1, t2 = far_field_amplitudes(m, x, np.arccos(nodes))
    csca = np.pi / k**2 * np.sum(weights * (np.abs(t1) ** 2 + np.abs(t2) ** 2))
    assert csca == pytest.approx(cs.scattering_um2, rel=1e-9)
    assert cs.absorption_um2 >= -1e-12 * cs.extinction_um2
    if m.imag == 0:
        assert cs.absorption_um2 == pytest.approx(0.0, abs=1e-10 * cs.extinction_um2)


@pytest.mark.parametrize("x", [100.0, 150.0])
def test_large_spheres_are_stable(x):
    """Size parameters beyond 100: energy balance for lossless spheres and finite values."""
    for m in (1.05, 1.59, 2.7):
        cs = cross_sections(m, x, 1.0)
        assert np.isfinite(cs.extinction_um2)
        assert cs.scattering_um2 == pytest.approx(cs.extinction_um2, rel=1e-11)
        # extinction paradox: Q_ext -> 2 for large spheres
        assert 1.8 < cs.q_extinction < 2.4


# ---------------------------------------------------------------------------------------
# Near field: an independent evaluation of Bohren & Huffman eq. (4.45) with scipy functions


def _independent_field(sphere, optics, points):
    """Scattered field (lab frame, zero incident phase at the centre), written from scratch."""
    k = optics.k
    m = complex(sphere.index) / optics.n_medium
    a, b = mie_coefficients(m, k * sphere.radius_um)
    nmax = a.size
    beta = optics.polarization_rad
    # Bohren-Huffman frame: z' along the propagation (-z lab), x' along the polarisation
    ex = np.array([np.cos(beta), np.sin(beta), 0.0])
    ez = np.array([0.0, 0.0, -1.0])
    ey = np.cross(ez, ex)
    out = []
    for p in points:
        xp, yp, zp = p @ ex, p @ ey, p @ ez
        r = np.sqrt(xp**2 + yp**2 + zp**2)
        th = np.arccos(zp / r)
        ph = np.arctan2(yp, xp)
        rho = k * r
        n = np.arange(1, nmax + 1)
        mu = np.cos(th)
        p1 = -special.lpmv(1, n, mu)  # B&H P_n^1 has no Condon-Shortley phase
        pi_n = p1 / np.sin(th)
        tau_n = 0.5 * (n * (n + 1) * special.lpmv(0, n, mu) - special.lpmv(2, n, mu))
        h = special.spherical_jn(n, rho) + 1j * special.spherical_yn(n, rho)
        dh = special.spherical_jn(n, rho, True) + 1j * special.spherical_yn(n, rho, True)
        dxi = (h + rho * dh) / rho
        e_n = 1j**n * (2 * n + 1) / (n * (n + 1))
        # M_o1n and N_e1n (B&H 4.50) components
        e_r = np.sum(e_n * 1j * a * np.cos(ph) * n * (n + 1) * np.sin(th) * pi_n * h / rho)
        e_t = np.sum(e_n * (1j * a * np.cos(ph) * tau_n * dxi - b * np.cos(ph) * pi_n * h))
        e_p = np.sum(e_n * (-1j * a * np.sin(ph) * pi_n * dxi + b * np.sin(ph) * tau_n * h))
        r_hat = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
        t_hat = np.array([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), -np.sin(th)])
        p_hat = np.array([-np.sin(ph), np.cos(ph), 0.0])
        e_prime = e_r * r_hat + e_t * t_hat + e_p * p_hat
        out.append(e_prime[0] * ex + e_prime[1] * ey + e_prime[2] * ez)
    return np.array(out)


@pytest.mark.parametrize("pol_deg", [0.0, 30.0, 90.0])
def test_near_field_matches_independent_series(pol_deg):
    optics = Optics(0.66, 1.33, np.radians(pol_deg))
    sphere = Sphere(0.6, 1.59 + 0.002j)
    rng = np.random.default_rng(5)
    # kr from ~10 to ~30, all directions incl. backward and sideways
    dirs = rng.normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radii = rng.uniform(10, 30, 12) / optics.k
    pts = dirs * radii[:, None]
    got = LorenzMie().solve(sphere, optics).field_at(pts)
    ref = _independent_field(sphere, optics, pts)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11 * np.abs(ref).max())


def test_near_field_differs_from_far_field_at_small_kr_and_converges_as_1_over_kr():
    optics = Optics(0.66, 1.33, 0.0)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    direction = np.array([0.3, 0.2, -1.0])
    direction /= np.linalg.norm(direction)
    rel = []
    for kr in (15.0, 1e2, 1e3, 1e4, 1e5):
        p = (direction * kr / optics.k)[None, :]
        exact, far = wave.field_at(p), wave.field_at(p, far_field=True)
        rel.append(np.linalg.norm(exact - far) / np.linalg.norm(exact))
    assert rel[0] > 0.05  # near-field terms matter at kr ~ 15
    ratios = np.array(rel[1:-1]) / np.array(rel[2:])
    np.testing.assert_allclose(ratios, 10.0, rtol=0.05)  # difference falls as 1/(kr)
    assert rel[-1] < 1e-4


def test_far_field_form_is_transverse_and_uses_s1_s2():
    optics = Optics(0.66, 1.33, 0.0)
    wave = LorenzMie().solve(Sphere(0.5, 1.59), optics)
    # lab direction (sin t, 0, -cos t): in the B&H frame phi' = 0, so E = exp(ikr)/(-ikr) S2 e_th
    t = 0.4
    r = 50.0
    p = r * np.array([np.sin(t), 0.0, -np.cos(t)])
    e = wave.field_at(p[None, :], far_field=True)[0]
    _, s2 = wave.far_field_amplitudes(np.array([t]))
    k = optics.k
    expected_amp = np.exp(1j * k * r) / (-1j * k * r) * s2[0]
    # e_theta' in the lab frame at phi' = 0: (cos t, 0, -sin t) in B&H -> (cos t, 0, sin t) lab
    np.testing.assert_allclose(e, expected_amp * np.array([np.cos(t), 0.0, np.sin(t)]), atol=1e-15)
    assert abs(np.dot(e, p)) < 1e-12 * np.linalg.norm(e) * r


def test_points_inside_sphere_are_rejected():
    wave = LorenzMie().solve(Sphere(0.5, 1.59), Optics(0.66, 1.33))
    with pytest.raises(ValueError, match="outside the sphere"):
        wave.field_at([[0.1, 0.0, 0.2]])
