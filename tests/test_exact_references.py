"""The references of the exact-engine studies (``tests/ebcm_reference.py``,
``tests/exact_references.py``) checked against codes independent of them: Lorenz-Mie for a
sphere, pytmatrixc (Mishchenko's EBCM Fortran) for a spheroid, holofit's own double-precision
EBCM at an order where both are well conditioned, and a wave known in closed form for the
extrapolation in the dipole size."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.optics import Optics
from holofit.particles import Sphere, Spherocylinder, Spheroid
from holofit.scattering.axisym import build_exact_tmatrix
from holofit.scattering.theory import Orientation
from holofit.scattering.tmatrix_wave import TMatrixWave
from tests.ebcm_reference import LongDoubleEBCM, capsule, spheroid
from tests.exact_references import (
    ExtrapolatedWave,
    FarFieldWave,
    ld_ebcm_amplitude,
    pytmatrix_amplitude,
)

OPTICS = Optics(0.660, 1.33)
K = OPTICS.k
ORIENTATION = Orientation(0.5, 1.1, 0.3)


def _dirs(n: int = 60) -> np.ndarray:
    d = np.random.default_rng(1).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _error(a, b, dirs) -> float:
    fa, fb = a.far_field_amplitude(dirs), b.far_field_amplitude(dirs)
    return float(np.abs(fa - fb).max() / np.abs(fb).max())


def test_long_double_ebcm_of_a_sphere_is_lorenz_mie() -> None:
    model = Sphere(0.45, 1.5)
    wave = FarFieldWave(model, OPTICS, ORIENTATION,
                        LongDoubleEBCM(spheroid(0.45, 0.45), 1.5 / 1.33, K, 16).amplitude)
    mie = TMatrixWave(model, OPTICS, ORIENTATION, build_exact_tmatrix(model, OPTICS))
    assert _error(wave, mie, _dirs()) < 1e-7  # Mie's own truncation at its default order


def _frame(t: float, p: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t, p = np.radians(t), np.radians(p)
    return (np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]),
            np.array([np.cos(t) * np.cos(p), np.cos(t) * np.sin(p), -np.sin(t)]),
            np.array([-np.sin(p), np.cos(p), 0.0]))


def test_long_double_ebcm_of_a_spheroid_is_mishchenkos_amplitude_matrix() -> None:
    """Complex amplitude matrices, both polarisations, every kind of geometry."""
    tmatrix = pytest.importorskip("pytmatrix.tmatrix")
    ref = tmatrix.Scatterer(radius=0.25 ** (1 / 3), wavelength=0.66 / 1.33,
                            m=complex(1.495 / 1.33), axis_ratio=0.5, shape=-1, ddelt=1e-8, ndgs=8)
    ebcm = LongDoubleEBCM(spheroid(0.5, 1.0), 1.495 / 1.33, K, 24)
    worst, largest = 0.0, 0.0
    for t0, p0, t, p in ((30, 0, 100, 40), (60, 10, 20, 200), (45, 0, 135, 180), (80, 0, 80, 0),
                         (150, 70, 10, 300), (180, 0, 30, 20)):
        ref.thet0, ref.phi0, ref.thet, ref.phi = t0, p0, t, p
        s = ref.get_S()
        k_in, ev, eh = _frame(t0, p0)
        k_out, tv, th = _frame(t, p)
        for j, e in enumerate((ev, eh)):
            a = ebcm.amplitude(k_in, e, k_out[None])[0] / K
            worst = max(worst, float(np.abs(np.array([a @ tv, a @ th]) - s[:, j]).max()))
            largest = max(largest, float(np.abs(s).max()))
    assert worst / largest < 1e-6


def test_long_double_ebcm_of_the_rod_matches_the_double_one_where_both_hold() -> None:
    """At order 18 (cond(Q) ~1e2) the double-precision EBCM of holofit keeps 12 digits: the two
    implementations agree to far below either's truncation error."""
    rod = Spherocylinder(0.501, 1.079, 1.495)
    ld = FarFieldWave(rod, OPTICS, ORIENTATION, LongDoubleEBCM(
        capsule(0.501, 1.079), 1.495 / 1.33, K, 18).amplitude)
    ours = TMatrixWave(rod, OPTICS, ORIENTATION, build_exact_tmatrix(rod, OPTICS, order=18))
    assert _error(ld, ours, _dirs()) < 1e-9


def test_pytmatrix_wave_is_the_exact_spheroid() -> None:
    pytest.importorskip("pytmatrix")
    model = Spheroid(0.4, 0.8, 1.45)
    ref = FarFieldWave(model, OPTICS, ORIENTATION, pytmatrix_amplitude(model, OPTICS))
    ours = TMatrixWave(model, OPTICS, ORIENTATION, build_exact_tmatrix(model, OPTICS))
    assert _error(ref, ours, _dirs()) < 3e-6  # pytmatrixc's own accuracy (ddelt 1e-8)


def test_ld_wave_and_cache_round_trip(tmp_path) -> None:
    model = Spheroid(0.3, 0.5, 1.45)
    first = ld_ebcm_amplitude(model, OPTICS, 12, cache=tmp_path)
    again = ld_ebcm_amplitude(model, OPTICS, 12, cache=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    d = _dirs(5)
    k_in, e = np.array([0.0, 0.6, -0.8]), np.array([1.0, 0.0, 0.0])
    np.testing.assert_array_equal(first(k_in, e, d), again(k_in, e, d))


class _Linear:
    """A far field ``F0 + c d + q d^2`` (a DDA's error at dipole size ``d``)."""

    def __init__(self, d: float, q: float = 0.0) -> None:
        self.d, self.q, self.optics = d, q, OPTICS
        self.radius_um = 1.0

    def far_field_amplitude(self, dirs: np.ndarray) -> np.ndarray:
        f0 = np.outer(dirs[:, 0], [1.0, 2.0, 3.0]) + 1j
        return f0 * (1 + 0.3 * self.d + self.q * self.d**2)


def test_extrapolation_to_zero_dipole_size() -> None:
    dirs = _dirs(4)
    f0 = _Linear(0.0).far_field_amplitude(dirs)
    linear = ExtrapolatedWave([_Linear(0.02), _Linear(0.03)], [0.02, 0.03])
    np.testing.assert_allclose(linear.far_field_amplitude(dirs), f0, atol=1e-13)
    quad = ExtrapolatedWave([_Linear(d, 5.0) for d in (0.01, 0.02, 0.03)], [0.01, 0.02, 0.03])
    np.testing.assert_allclose(quad.far_field_amplitude(dirs), f0, atol=1e-12)


def test_long_double_ebcm_obeys_the_optical_theorem() -> None:
    """Extinction from the forward amplitude equals the scattered power integrated over the
    sphere (a lossless spheroid: no absorption), ``4 pi Im(e* . A(k_in)) = int |A|^2 dOmega``,
    to the truncation error of the order (a truncated T-matrix conserves energy only to it)."""
    ebcm = LongDoubleEBCM(spheroid(0.5, 1.0), 1.495 / 1.33, K, 24)
    k_in = np.array([np.sin(0.7), 0.0, np.cos(0.7)])
    e = np.array([np.cos(0.7), 0.0, -np.sin(0.7)])
    x, w = np.polynomial.legendre.leggauss(48)
    ph = np.arange(96) * 2 * np.pi / 96
    ct, pp = np.meshgrid(x, ph, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = np.stack([st * np.cos(pp), st * np.sin(pp), ct], -1).reshape(-1, 3)
    a = ebcm.amplitude(k_in, e, dirs)
    scattered = float(((np.abs(a) ** 2).sum(axis=1).reshape(ct.shape) * w[:, None]).sum()
                      * 2 * np.pi / 96)
    forward = ebcm.amplitude(k_in, e, k_in[None])[0]
    extinction = 4 * np.pi * float(np.imag(np.conj(e) @ forward))
    assert extinction == pytest.approx(scattered, rel=1e-7)


def test_double_ebcm_of_the_rod_holds_past_the_raw_condition_number() -> None:
    """At order 34 the raw cond(Q) of the rod is ~1e20, yet the equilibrated solve of holofit's
    double-precision EBCM still agrees with the long-double one (19 digits) far below the
    order's truncation error (~9e-4): what limits double precision is the cancellation in the
    surface integrals, which only sets in near order 60 (``holofit.scattering.axisym.ebcm``)."""
    rod = Spherocylinder(0.501, 1.079, 1.495)
    ld = FarFieldWave(rod, OPTICS, ORIENTATION, LongDoubleEBCM(
        capsule(0.501, 1.079), 1.495 / 1.33, K, 34).amplitude)
    tm = build_exact_tmatrix(rod, OPTICS, order=34, estimate=False)
    assert tm.provenance["q_condition_max"] < 1e4  # the equilibrated Q's
    ours = TMatrixWave(rod, OPTICS, ORIENTATION, tm)
    assert _error(ld, ours, _dirs()) < 1e-6
