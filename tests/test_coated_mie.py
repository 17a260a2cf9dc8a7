"""Coated-sphere Lorenz-Mie (Yang's recursion) against independent evaluations and limits."""

import mpmath as mp
import numpy as np
import pytest

from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.scattering.coated_mie import (
    CoatedSphereWave,
    coated_amplitudes,
    coated_coefficients,
    coated_cross_sections,
)
from holofit.scattering.mie import MieWave
from holofit.scattering.mie_coefficients import mie_coefficients

OPTICS = Optics(0.66, 1.33, 0.0)


def _aden_kerker_mpmath(m1, m2, x, y, nmax, dps=30):
    """Bohren & Huffman eqs. 8.2 written out literally, in 30-digit arithmetic (where the
    cancellations that make them unusable in double precision do no harm)."""
    mp.mp.dps = dps
    m1, m2, x, y = mp.mpc(m1), mp.mpc(m2), mp.mpf(x), mp.mpf(y)

    def psi(n, z):
        return z * mp.sqrt(mp.pi / (2 * z)) * mp.besselj(n + 0.5, z)

    def chi(n, z):
        return -z * mp.sqrt(mp.pi / (2 * z)) * mp.bessely(n + 0.5, z)

    def xi(n, z):
        return psi(n, z) - 1j * chi(n, z)

    def der(f, n, z):
        return mp.diff(lambda t: f(n, t), z)

    out_a, out_b = [], []
    for n in range(1, nmax + 1):
        a_n = (m2 * psi(n, m2 * x) * der(psi, n, m1 * x) - m1 * der(psi, n, m2 * x)
               * psi(n, m1 * x)) / (m2 * chi(n, m2 * x) * der(psi, n, m1 * x)
                                    - m1 * der(chi, n, m2 * x) * psi(n, m1 * x))
        b_n = (m2 * psi(n, m1 * x) * der(psi, n, m2 * x) - m1 * psi(n, m2 * x)
               * der(psi, n, m1 * x)) / (m2 * der(chi, n, m2 * x) * psi(n, m1 * x)
                                         - m1 * der(psi, n, m1 * x) * chi(n, m2 * x))
        p = psi(n, m2 * y) - a_n * chi(n, m2 * y)
        dp = der(psi, n, m2 * y) - a_n * der(chi, n, m2 * y)
        out_a.append(complex((psi(n, y) * dp - m2 * der(psi, n, y) * p)
                             / (xi(n, y) * dp - m2 * der(xi, n, y) * p)))
        p = psi(n, m2 * y) - b_n * chi(n, m2 * y)
        dp = der(psi, n, m2 * y) - b_n * der(chi, n, m2 * y)
        out_b.append(complex((m2 * psi(n, y) * dp - der(psi, n, y) * p)
                             / (m2 * xi(n, y) * dp - der(xi, n, y) * p)))
    return np.array(out_a), np.array(out_b)


@pytest.mark.parametrize("m1,m2,x,y", [
    (1.195, 2.06, 2.5, 2.9),  # polystyrene core, TiO2 shell (Janus-like, in water)
    (1.19, 1.5 + 0.8j, 2.0, 2.6),  # absorbing shell
    (1.1, 0.12 + 2.9j, 2.5, 3.0),  # metal shell (gold-like)
])
def test_coefficients_match_aden_kerker_in_high_precision(m1, m2, x, y):
    a, b = coated_coefficients(m1, m2, x, y)
    ref_a, ref_b = _aden_kerker_mpmath(m1, m2, x, y, nmax=5)
    scale = max(np.abs(ref_a).max(), np.abs(ref_b).max())
    assert np.max(np.abs(a[:5] - ref_a)) < 1e-12 * scale
    assert np.max(np.abs(b[:5] - ref_b)) < 1e-12 * scale


def test_limits_reduce_to_the_homogeneous_sphere():
    m, y = 1.5 + 0.1j, 4.0
    a0, b0 = mie_coefficients(m, y)
    for m1, x in ((m, 2.0), (2.0, 0.0), (2.0, 1e-8)):  # same index; no core; vanishing core
        a, b = coated_coefficients(m1, m, x, y)
        np.testing.assert_allclose(a, a0, atol=1e-12)
        np.testing.assert_allclose(b, b0, atol=1e-12)
    a, b = coated_coefficients(m, 2.0, y, y)  # shell of zero thickness
    np.testing.assert_allclose(a, a0, atol=1e-13)
    np.testing.assert_allclose(b, b0, atol=1e-13)


def test_opaque_thick_shell_hides_the_core():
    """Im(m2) y ~ 120: the textbook formulas overflow/cancel; the light never sees the core."""
    a, b = coated_coefficients(1.5, 0.5 + 4.0j, 20.0, 30.0)
    a0, b0 = mie_coefficients(0.5 + 4.0j, 30.0)
    np.testing.assert_allclose(a, a0, atol=1e-12)
    np.testing.assert_allclose(b, b0, atol=1e-12)


def test_energy_balance_and_optical_theorem():
    k = OPTICS.k
    lossless = coated_cross_sections(1.59 / 1.33, 2.74 / 1.33, 0.443, 0.49, k)
    assert abs(lossless.absorption_um2) < 1e-12 * lossless.extinction_um2
    lossy = coated_cross_sections(1.59 / 1.33, (1.2 + 2.0j) / 1.33, 0.3, 0.35, k)
    assert lossy.absorption_um2 > 0.05 * lossy.extinction_um2
    assert lossy.scattering_um2 > 0
    # optical theorem through the angular functions: C_ext = (4 pi / k^2) Re S(0)
    s1, s2 = coated_amplitudes(1.59 / 1.33, (1.2 + 2.0j) / 1.33, k * 0.3, k * 0.35,
                               np.array([0.0]))
    assert s1[0] == pytest.approx(s2[0], rel=1e-13)
    assert 4 * np.pi / k**2 * s1[0].real == pytest.approx(lossy.extinction_um2, rel=1e-12)


def test_wave_field_equals_the_sphere_when_core_and_shell_agree():
    wave = CoatedSphereWave(0.2, 0.5, 1.6 + 0.01j, 1.6 + 0.01j, OPTICS)
    ref = MieWave(Sphere(0.5, 1.6 + 0.01j), OPTICS)
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(50, 3))
    pts *= (0.6 + 3 * rng.random(50))[:, None] / np.linalg.norm(pts, axis=1)[:, None]
    np.testing.assert_allclose(wave.field_at(pts), ref.field_at(pts), atol=1e-12)
    xs, ys = rng.random(30) * 5, rng.random(30) * 5
    for got, want in zip(wave.field_on_pixels((2.5, 2.5, 8.0), xs, ys),
                         ref.field_on_pixels((2.5, 2.5, 8.0), xs, ys), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-12)
    with pytest.raises(ValueError, match="outside the particle"):
        wave.field_at([[0.0, 0.0, 0.4]])
