"""Convergence studies of the exact T-matrices, and the DDA converged toward d -> 0 as a
reference (``make test-all``; minutes).

The DDA's own accuracy as a reference (measured, docs/validation/exact_tmatrix.md): the rod's
far field moves by ~1e-3 between 28 and 40 dipoles per wavelength (the smooth filling makes the
convergence non-monotone, so no extrapolation in d is trustworthy); the Janus particle's
falls almost linearly in d between 20 and 28 dipoles per wavelength (2.2e-2 at 10, 1.1e-2 at
20, 7.4e-3 at 28), and the linear extrapolation of those two is 1.7e-3 from the imbedding.
"""

from __future__ import annotations

import numpy as np
import pytest

from holofit.optics import Optics
from holofit.particles import JanusSphere, Spherocylinder, Spheroid
from holofit.scattering.axisym import build_exact_tmatrix
from holofit.scattering.axisym.blocks import tmatrix_from_blocks
from holofit.scattering.axisym.iitm import integrate_profile
from holofit.scattering.axisym.order import far_field_change
from holofit.scattering.axisym.profiles import SpherocylinderProfile, SpheroidProfile
from holofit.scattering.theory import Orientation
from holofit.scattering.tmatrix_wave import TMatrixWave

pytestmark = pytest.mark.slow

OPTICS = Optics(0.660, 1.33)
ROD = Spherocylinder(0.501, 1.079, 1.495)
SPHEROID = Spheroid(0.5, 1.0, 1.495)
JANUS = JanusSphere(0.443, 0.047, 1.581, 2.74)
ORIENTATION = Orientation(np.pi / 6, np.pi / 4, 0.0)


def _directions() -> np.ndarray:
    rng = np.random.default_rng(3)
    d = rng.normal(size=(300, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _dda(model, dpl: float) -> np.ndarray:
    from holofit.dda.engine import BuiltinDDA
    from holofit.dda.settings import DDASettings

    engine = BuiltinDDA(DDASettings(dipoles_per_wavelength=dpl, tolerance=1e-8))
    return engine.solve_direct(model, OPTICS, ORIENTATION).far_field_amplitude(_directions())


def _exact(model, tm) -> np.ndarray:
    return TMatrixWave(model, OPTICS, ORIENTATION, tm).far_field_amplitude(_directions())


def _imbedded(profile, order: int, steps: list[int]):
    res = integrate_profile(profile, order, OPTICS.k, 1.33, steps)
    return tmatrix_from_blocks(res.blocks, order, OPTICS.k, profile.r_outer)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_rod_dda_at_20_dipoles_per_wavelength_is_within_its_own_accuracy() -> None:
    exact = _exact(ROD, build_exact_tmatrix(ROD, OPTICS))
    coarse = _rel(_dda(ROD, 10), exact)
    fine = _rel(_dda(ROD, 20), exact)
    assert fine < 1.5e-3 < coarse


def test_janus_dda_extrapolated_in_d_agrees_with_imbedding() -> None:
    exact = _exact(JANUS, build_exact_tmatrix(JANUS, OPTICS, order=24))
    d1, d2 = 1.0 / 20, 1.0 / 28  # d is proportional to 1/dpl
    f1, f2 = _dda(JANUS, 20), _dda(JANUS, 28)
    extrapolated = f2 + (f2 - f1) * d2 / (d1 - d2)
    assert _rel(f2, exact) > 5e-3
    assert _rel(extrapolated, exact) < 4e-3


def test_rod_by_imbedding_converges_toward_the_ebcm() -> None:
    ebcm = build_exact_tmatrix(ROD, OPTICS)
    changes = []
    prev = None
    for L in (24, 32, 40):
        tm = _imbedded(SpherocylinderProfile(0.501, 1.079, 1.495), L, [16, 16])
        if prev is not None:
            changes.append(far_field_change(prev, tm))
        prev = tm
    assert changes[1] < changes[0]
    assert far_field_change(prev, ebcm) < 2e-3


def test_spheroid_imbedding_converges_toward_the_ebcm() -> None:
    ebcm = build_exact_tmatrix(SPHEROID, OPTICS, order=28, method="ebcm")
    prof = SpheroidProfile(0.5, 1.0, 1.495)
    errs = [far_field_change(_imbedded(prof, L, [16]), ebcm) for L in (20, 28)]
    assert errs[1] < errs[0] < 3e-3


def test_janus_order_convergence_is_algebraic_and_below_1e3_at_order_26() -> None:
    tms = {L: build_exact_tmatrix(JANUS, OPTICS, order=L) for L in (18, 22, 26, 30)}
    c1 = far_field_change(tms[18], tms[22])
    c2 = far_field_change(tms[22], tms[26])
    c3 = far_field_change(tms[26], tms[30])
    assert c3 < c2 < c1
    assert c3 < 1e-3
