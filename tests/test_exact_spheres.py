"""Exact T-matrices of spheres and layered spheres against Lorenz-Mie and scattnlay.

The invariant imbedding integrates the Riccati equation of T(r) through the shells; for
concentric layers it must reproduce the coated-sphere coefficients to the integration's
accuracy (1e-9 here), and a Janus cap grown to a full shell must do the same (the polar-angle
split and the inverse rule then have nothing to cut).
"""

from __future__ import annotations

import numpy as np
import pytest

from holofit.optics import Optics
from holofit.particles import CoatedSphere, Sphere, Spherocylinder, Spheroid
from holofit.scattering.axisym import build_exact_tmatrix
from holofit.scattering.axisym.ebcm import ebcm_blocks
from holofit.scattering.axisym.iitm import integrate_profile, mie_start
from holofit.scattering.axisym.profiles import CapProfile, LayeredProfile, SpheroidProfile
from holofit.scattering.coated_mie import coated_coefficients
from holofit.scattering.mie_coefficients import mie_coefficients

OPTICS = Optics(0.660, 1.33)
K = OPTICS.k
#: the paper's Janus particle: PS core, TiO2 cap
CORE, CAP, N_CORE, N_CAP = 0.443, 0.047, 1.581, 2.74


def _diagonals(blocks: np.ndarray, order: int, m: int = 1) -> tuple[np.ndarray, np.ndarray]:
    idx = np.arange(order)
    return -blocks[m, idx, idx], -blocks[m, order + idx, order + idx]


def test_coated_sphere_by_imbedding_matches_coated_mie_to_1e9() -> None:
    L = 14
    prof = LayeredProfile((CORE, CORE + CAP), (N_CORE, N_CAP))
    res = integrate_profile(prof, L, K, 1.33, [192], richardson=True)
    a, b = coated_coefficients(N_CORE / 1.33, N_CAP / 1.33, K * CORE, K * (CORE + CAP), L)
    for m in (0, 1, 5):
        n0 = max(1, m)
        got_a, got_b = _diagonals(res.blocks, L, m)
        cnt = L - n0 + 1
        assert np.abs(got_a[:cnt] - a[n0 - 1:]).max() < 1e-9
        assert np.abs(got_b[:cnt] - b[n0 - 1:]).max() < 1e-9
    # concentric layers couple no orders
    off = res.blocks[2] - np.diag(np.diag(res.blocks[2]))
    assert np.abs(off).max() < 1e-13


def test_janus_cap_grown_to_a_full_shell_is_the_coated_sphere() -> None:
    L = 12
    a, b = coated_coefficients(N_CORE / 1.33, N_CAP / 1.33, K * CORE, K * (CORE + CAP), L)
    for rule in ("laurent", "inverse"):
        prof = CapProfile(CORE, CAP, N_CORE, N_CAP, x_edge=-1.0)
        res = integrate_profile(prof, L, K, 1.33, [192], richardson=True, polar_rule=rule)
        got_a, got_b = _diagonals(res.blocks, L)
        assert np.abs(got_a - a).max() < 1e-9, rule
        assert np.abs(got_b - b).max() < 1e-9, rule


def test_half_cap_differs_from_the_full_shell() -> None:
    """The cap's polar split is really applied (a test that could not fail otherwise)."""
    L = 10
    full = integrate_profile(CapProfile(CORE, CAP, N_CORE, N_CAP, x_edge=-1.0), L, K, 1.33,
                             [32]).blocks
    half = integrate_profile(CapProfile(CORE, CAP, N_CORE, N_CAP), L, K, 1.33, [32]).blocks
    assert np.abs(full - half).max() > 1e-2
    # a half cap on the +z side couples orders of both parities: N_1 to N_2 in m = 1
    assert abs(half[1, 0, 1]) > 1e-3


def test_coated_coefficients_agree_with_scattnlay() -> None:
    """scattnlay (Pena & Pal 2009; double-precision wheel): an independent layered-sphere
    code; its coefficients are Bohren & Huffman's a_n, b_n as holofit's."""
    scattnlay = pytest.importorskip("scattnlay")
    L = 14
    prof = LayeredProfile((CORE, CORE + CAP), (N_CORE, N_CAP))
    res = integrate_profile(prof, L, K, 1.33, [192], richardson=True)
    x = np.array([K * CORE, K * (CORE + CAP)])
    m = np.array([N_CORE / 1.33, N_CAP / 1.33], dtype=complex)
    _, an, bn = scattnlay.scattcoeffs(x, m, nmax=L)
    got_a, got_b = _diagonals(res.blocks, L)
    assert np.abs(got_a - an[:L]).max() < 1e-9
    assert np.abs(got_b - bn[:L]).max() < 1e-9


def test_three_layer_sphere_against_scattnlay() -> None:
    scattnlay = pytest.importorskip("scattnlay")
    L = 12
    radii = (0.25, 0.35, 0.45)
    idx = (1.45, 2.0 + 0.05j, 1.6)
    res = integrate_profile(LayeredProfile(radii, idx), L, K, 1.33, [128, 128], richardson=True)
    _, an, bn = scattnlay.scattcoeffs(np.array([K * r for r in radii]),
                                      np.array([v / 1.33 for v in idx], dtype=complex),
                                      nmax=L)
    got_a, got_b = _diagonals(res.blocks, L)
    assert np.abs(got_a - an[:L]).max() < 1e-9
    assert np.abs(got_b - bn[:L]).max() < 1e-9


def test_sphere_limits_of_the_ebcm_shapes_are_mie() -> None:
    """A spheroid of aspect 1 and a spherocylinder with b = a are spheres."""
    L = 14
    mie = mie_start(L, K, 0.5, 1.495 / 1.33)
    blocks, cond = ebcm_blocks(SpheroidProfile(0.5, 0.5, 1.495), L, K, 1.33, 40)
    assert np.abs(blocks - mie).max() < 1e-12
    assert cond.max() < 1e3
    for model in (Spheroid(0.5, 0.5, 1.495), Spherocylinder(0.5, 0.5, 1.495)):
        tm = build_exact_tmatrix(model, OPTICS, order=L, method="ebcm")
        a, b = mie_coefficients(1.495 / 1.33, K * 0.5, L)
        d = np.diag(tm.blocks[1])
        assert np.abs(d[:L] + a).max() < 1e-10
        assert np.abs(d[L:] + b).max() < 1e-10


def test_engine_builds_spheres_by_mie_and_coated_spheres_by_imbedding() -> None:
    tm = build_exact_tmatrix(Sphere(0.5, 1.59), OPTICS)
    assert tm.provenance["method"] == "mie"
    tc = build_exact_tmatrix(CoatedSphere(CORE, CAP, N_CORE, N_CAP), OPTICS)
    assert tc.provenance["method"] == "iitm"
    L = tc.order
    a, b = coated_coefficients(N_CORE / 1.33, N_CAP / 1.33, K * CORE, K * (CORE + CAP), L)
    d = np.diag(tc.blocks[0])  # m = 0
    assert np.abs(d[:L] + a).max() < 1e-7
    assert np.abs(d[L:] + b).max() < 1e-7


@pytest.mark.parametrize("parity", [False, True])
def test_runs_of_m_cover_every_order_once(parity: bool) -> None:
    from holofit.scattering.axisym.iitm import m_buckets

    for L in (1, 2, 5, 16, 28, 36):
        runs = m_buckets(L, parity)
        assert [m for r in runs for m in r] == list(range(L + 1))


def test_janus_blocks_do_not_depend_on_how_the_orders_m_are_grouped(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The runs of ``m`` integrated together are padded to their largest block: the padding
    must stay exactly zero (one run of all ``m``, the most padding, against a run per size,
    none)."""
    from holofit.scattering.axisym import iitm

    L = 12
    prof = CapProfile(CORE, CAP, N_CORE, N_CAP)
    got = {}
    for name, cost in (("one run", 1e30), ("one run per size", 0.0)):
        monkeypatch.setattr(iitm, "BUCKET_COST", cost)
        runs = iitm.m_buckets(L)
        assert len(runs) == 1 if name == "one run" else len(runs) >= L  # m = 0, 1: one size
        got[name] = integrate_profile(prof, L, K, 1.33, [16], polar_rule="inverse").blocks
    scale = np.abs(got["one run"]).max()
    assert np.abs(got["one run"] - got["one run per size"]).max() < 1e-13 * scale
