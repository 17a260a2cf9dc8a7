"""Exact T-matrices of homogeneous bodies of revolution (rod, spheroid, cylinder) and of the
Janus particle: convergence, physical identities and independent references.

References and their own accuracy (measured, docs/validation/exact_tmatrix.md):

* miepy 1.1 (its own C++ null-field code with discrete sources; double precision): a spheroid's
  T-matrix eigenvalues to ~1e-5, a flat cylinder's to ~2e-3 (they move by that much with its
  quadrature ``Nint``). Compared through the eigenvalues of each ``m`` block, which no change of
  basis normalisation or phase convention alters.
* pytmatrixc 0.3.4 (Mishchenko's EBCM Fortran, on the package index here as a prebuilt
  wheel): extinction and differential scattering of the spheroid to ~1e-7 (its ``ddelt``
  1e-8), of the cylinder to ~3e-5 (``ddelt`` 1e-6, where it stops at nmax 29, 3.4e-5 short of
  the long-double EBCM at order 48; tighter settings stop its Fortran).
* DESIGN.md section 7: an independent long-double EBCM of the paper's rod, C_ext 4.1681 /
  2.9820 / 2.6329 um^2 at axis tilts 0 / 45 / 80 deg (x polarisation, psi 30 deg), good to
  1-3e-4.
* holofit's own DDA at its default rule (10 dipoles per wavelength): 1e-3 to 5e-3 from exact
  for these shapes, so it catches any error of order one (signs, the negative-m blocks).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from holofit.optics import Optics
from holofit.particles import Cylinder, Spherocylinder, Spheroid
from holofit.scattering.axisym import build_exact_tmatrix
from holofit.scattering.axisym.blocks import tmatrix_from_blocks, unpad_block
from holofit.scattering.axisym.ebcm import ebcm_blocks
from holofit.scattering.axisym.iitm import integrate_profile
from holofit.scattering.axisym.order import far_field_change
from holofit.scattering.axisym.profiles import CapProfile, CylinderProfile, SpheroidProfile
from holofit.scattering.theory import Orientation
from holofit.scattering.tmatrix import TMatrix
from holofit.scattering.vsw import term_indices

OPTICS = Optics(0.660, 1.33)
K = OPTICS.k
ROD = Spherocylinder(0.501, 1.079, 1.495)
SPHEROID = Spheroid(0.5, 1.0, 1.495)
CYLINDER = Cylinder(0.5, 1.0, 1.495)


def _imbedded(profile, order: int, steps: list[int]) -> TMatrix:
    res = integrate_profile(profile, order, K, 1.33, steps)
    return tmatrix_from_blocks(res.blocks, order, K, profile.r_outer)


def _normalised(tm: TMatrix) -> np.ndarray:
    """T in the flux-normalised basis: holofit's waves have angular norm n (n + 1)."""
    _, n, _ = term_indices(tm.order)
    nu = np.sqrt(n * (n + 1.0))
    return tm.dense() * nu[:, None] / nu[None, :]


def _extinction(tm: TMatrix, euler: tuple[float, float, float]) -> float:
    """C_ext (um^2) for the instrument's x-polarised wave (optical theorem)."""
    e = np.array([1.0, 0.0, 0.0])
    c = tm.lab_coefficients(euler, e)
    forward = tm.expansion(c.vector).far_amplitude(np.array([[0.0, 0.0, -1.0]]))[0]
    return float(4 * np.pi / tm.k**2 * np.imag(e @ forward))


def test_spheroid_converges_spectrally_in_the_order() -> None:
    tms = {L: build_exact_tmatrix(SPHEROID, OPTICS, order=L, method="ebcm")
           for L in (16, 20, 24, 28)}
    d16 = far_field_change(tms[16], tms[28])
    d20 = far_field_change(tms[20], tms[28])
    d24 = far_field_change(tms[24], tms[28])
    assert d20 < 2e-5
    assert d24 < 1e-7
    assert d24 < d20 / 50 < d16 / 2500


def test_spheroid_ebcm_and_imbedding_agree() -> None:
    """Two independent methods (surface integrals vs the radial Riccati march)."""
    e = build_exact_tmatrix(SPHEROID, OPTICS, order=24, method="ebcm")
    prof = SpheroidProfile(0.5, 1.0, 1.495)
    i = tmatrix_from_blocks(integrate_profile(prof, 24, K, 1.33, [12]).blocks, 24, K, 1.0)
    assert far_field_change(i, e) < 2e-3


def test_lossless_t_matrices_are_unitary_and_reciprocal() -> None:
    """S = I + 2T is unitary (energy) and T_ij = (-1)^(m+m') T_(j-)(i-) (reciprocity) in the
    flux-normalised basis; the unnormalised basis is not unitary (so the check can fail)."""
    cases = (
        (build_exact_tmatrix(SPHEROID, OPTICS, order=20, method="ebcm"), 1e-4),
        (_imbedded(SpheroidProfile(0.5, 1.0, 1.495), 16, [64]), 1e-6),
        (_imbedded(CapProfile(0.443, 0.047, 1.581, 2.74), 14, [64]), 1e-6),
    )
    for tm, tol in cases:
        t = _normalised(tm)
        s = np.eye(t.shape[0]) + 2 * t
        assert np.abs(s @ s.conj().T - np.eye(t.shape[0])).max() < tol
        kind, n, m = term_indices(tm.order)
        where = {key: i for i, key in enumerate(zip(kind, n, m, strict=True))}
        flip = np.array([where[(a, b, -c)] for a, b, c in zip(kind, n, m, strict=True)])
        sign = (-1.0) ** (m[:, None] + m[None, :])
        recip = sign * t[np.ix_(flip, flip)].T
        assert np.abs(t - recip).max() < tol * np.abs(t).max()
    raw = cases[1][0].dense()
    s = np.eye(raw.shape[0]) + 2 * raw
    assert np.abs(s @ s.conj().T - np.eye(raw.shape[0])).max() > 0.1


def _miepy_blocks(t: np.ndarray, lmax: int) -> dict[int, np.ndarray]:
    import miepy

    idx = np.array(list(miepy.mode_indices(lmax)))
    out = {}
    for m in range(lmax + 1):
        sel = np.nonzero(idx[:, 2] == m)[0]
        out[m] = t[:, sel][:, :, :, sel].reshape(2 * sel.size, 2 * sel.size)
    return out


@pytest.mark.filterwarnings("ignore:EBCM T-matrix:RuntimeWarning")
@pytest.mark.parametrize(("profile", "miepy_call", "tol"), [
    (SpheroidProfile(0.5, 1.0, 1.495), "spheroid", 5e-5),
    (CylinderProfile(0.5, 1.0, 1.495), "cylinder", 5e-3),
])
def test_block_eigenvalues_agree_with_miepy(profile, miepy_call: str, tol: float) -> None:
    miepy = pytest.importorskip("miepy")
    L = 20
    if miepy_call == "spheroid":
        ref = miepy.tmatrix.tmatrix_spheroid(0.5, 1.0, 0.66, 1.495**2, 1.33**2, L)
    else:
        ref = miepy.tmatrix.tmatrix_cylinder(0.5, 2.0, 0.66, 1.495**2, 1.33**2, L)
    theirs = _miepy_blocks(ref, L)
    ours, _ = ebcm_blocks(profile, L, K, 1.33, 2 * L + 10)
    for m in (0, 1, 2, 5):
        a = np.sort_complex(np.linalg.eigvals(-unpad_block(ours[m], m, L)))  # miepy: +a_n
        b = np.sort_complex(np.linalg.eigvals(theirs[m]))
        assert np.abs(a - b).max() < tol, m


def test_rod_extinction_matches_the_long_double_ebcm_reference() -> None:
    """DESIGN.md's long-double EBCM (L = 42, five digits); the default build, solved at the
    order where its change stops falling, is within 1e-5 to 6e-5 of it (3e-4 at L = 26)."""
    tm = build_exact_tmatrix(ROD, OPTICS, max_seconds=math.inf)
    assert tm.provenance["method"] == "ebcm"
    assert tm.provenance["order_search_stop"] == "precision floor"
    reference = {0: 4.1681, 45: 2.9820, 80: 2.6329}
    for tilt, value in reference.items():
        got = _extinction(tm, (np.pi / 6, np.radians(tilt), 0.0))
        assert abs(got - value) / value < 1e-4, (tilt, got)


@pytest.mark.parametrize(("model", "low", "high"), [
    (ROD, 3e-4, 8e-3), (SPHEROID, 3e-4, 4e-3), (CYLINDER, 3e-4, 1.5e-2)])
def test_dda_at_its_default_rule_is_close_to_exact(model, low: float, high: float) -> None:
    """The DDA (10 dipoles per wavelength) at a tilted orientation, which involves every m
    block including the negative ones: its known model error, not more, not less (the lower
    bounds are below the errors of the plane-cut filling, 0.9-1.2e-3, and above the exact
    engine's own, ~6e-4 for the rod)."""
    from holofit.dda.engine import BuiltinDDA
    from holofit.dda.settings import DDASettings
    from holofit.scattering.axisym import AxisymmetricTMatrix

    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = Orientation(np.pi / 6, np.pi / 4, 0.4)
    fd = BuiltinDDA(DDASettings()).solve_direct(model, OPTICS, o).far_field_amplitude(dirs)
    fe = AxisymmetricTMatrix().solve(model, OPTICS, o).far_field_amplitude(dirs)
    err = np.abs(fd - fe).max() / np.abs(fe).max()
    assert low < err < high


def _pytmatrix(shape: int, radius: float, ratio: float):
    """pytmatrixc (Mishchenko's EBCM Fortran, Mishchenko & Travis 1998; its own accuracy set by
    ``ddelt``, 1e-8 here, and measured against ours: C_ext to ~1e-7 for the spheroid)."""
    tmatrix = pytest.importorskip("pytmatrix.tmatrix")
    return tmatrix.Scatterer(radius=radius, wavelength=0.66 / 1.33, m=complex(1.495 / 1.33),
                             axis_ratio=ratio, shape=shape, ddelt=1e-8 if shape == -1 else 1e-6,
                             ndgs=8 if shape == -1 else 4)


@pytest.mark.parametrize(("model", "shape", "radius", "tol"), [
    (SPHEROID, -1, 0.25 ** (1 / 3), 1e-6),
    # pytmatrixc stops the cylinder at nmax 29 (its ddelt test on the cross sections): its far
    # field is 3.4e-5 from the long-double EBCM at order 48 and 6e-6 from ours solved at 30;
    # ours, solved at 38, is 1.2e-5 from the long-double one (bench/results/exact/)
    (CYLINDER, -2, (0.5**2 * 1.0 * 1.5) ** (1 / 3), 3e-5),
])
def test_extinction_matches_pytmatrix_for_both_polarisations(model, shape: int, radius: float,
                                                            tol: float) -> None:
    """Incidence at ``th0`` to the axis; pytmatrix's vertical polarisation lies in the plane
    of axis and incidence (ours: psi = 0), horizontal across it (psi = 90 deg)."""
    s = _pytmatrix(shape, radius, 0.5)
    from pytmatrix import scatter

    tm = build_exact_tmatrix(model, OPTICS)
    for th in (30.0, 60.0):
        s.thet0, s.thet, s.phi0, s.phi = th, 180.0 - th, 0.0, 180.0
        for horizontal, psi in ((False, 0.0), (True, np.pi / 2)):
            ref = scatter.ext_xsect(s, h_pol=horizontal)
            got = _extinction(tm, (psi, np.radians(th), 0.0))
            assert abs(got - ref) / ref < tol, (th, horizontal)


def test_differential_scattering_matches_pytmatrix() -> None:
    """|f|^2 (um^2) in the particle frame for incident and scattered directions of every kind,
    v and h polarisations: the plane-wave coefficients and the far field of the T-matrix."""
    from holofit.scattering.vsw import plane_wave_coefficients

    s = _pytmatrix(-1, 0.25 ** (1 / 3), 0.5)
    from pytmatrix import scatter

    tm = build_exact_tmatrix(SPHEROID, OPTICS)

    def frame(t: float, p: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t, p = np.radians(t), np.radians(p)
        return (np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]),
                np.array([np.cos(t) * np.cos(p), np.cos(t) * np.sin(p), -np.sin(t)]),
                np.array([-np.sin(p), np.cos(p), 0.0]))

    for t0, p0, t, p in ((30, 0, 100, 40), (60, 10, 20, 200), (45, 0, 135, 180), (80, 0, 80, 0)):
        s.thet0, s.phi0, s.thet, s.phi = t0, p0, t, p
        k_in, e_v, e_h = frame(t0, p0)
        k_out = frame(t, p)[0]
        for horizontal, e in ((False, e_v), (True, e_h)):
            ref = scatter.sca_intensity(s, h_pol=horizontal)
            out = tm.scatter(plane_wave_coefficients(k_in, e, tm.order))
            a = tm.expansion(out).far_amplitude(k_out[None])[0]
            got = float(np.sum(np.abs(a) ** 2)) / K**2
            assert abs(got - ref) / ref < 5e-5
