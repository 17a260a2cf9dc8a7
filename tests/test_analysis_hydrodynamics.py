"""Hydrodynamic predictions against the paper's numbers and reference viscosities."""

import pytest

from holofit.analysis import hydrodynamics as hd

A, B, T = 0.501, 1.079, 21.0  # the paper's fitted rod (um) and temperature (C)


def test_paper_spherocylinder_predictions():
    # paper, rod results table: D_t' = 0.297 +- 0.016 um^2/s, D_r' = 0.311 +- 0.017 1/s
    sc = hd.spherocylinder_diffusion(A, B, T)
    assert sc["D_t"] == pytest.approx(0.297, abs=0.0005)
    assert sc["D_r"] == pytest.approx(0.311, abs=0.0005)
    p = hd.predict(lambda **k: hd.spherocylinder_diffusion(**k)["D_t"], T, 2.0,
                   {"a_um": A, "b_um": B})
    assert p.error == pytest.approx(0.016, abs=0.001) and p.error_sizes == 0
    p = hd.predict(lambda **k: hd.spherocylinder_diffusion(**k)["D_r"], T, 2.0,
                   {"a_um": A, "b_um": B})
    assert p.error == pytest.approx(0.017, abs=0.001)


def test_paper_cylinder_predictions():
    # paper: D_par' = 0.301, D_perp' = 0.265 (text) / 0.266, D_r' = 0.205, D_par'/D_perp' = 1.13
    cy = hd.cylinder_diffusion(A, B, T)
    assert cy["D_par"] == pytest.approx(0.301, abs=0.001)
    assert cy["D_perp"] == pytest.approx(0.2655, abs=0.001)
    assert cy["D_r"] == pytest.approx(0.205, abs=0.0005)
    assert cy["D_par/D_perp"] == pytest.approx(1.13, abs=0.005)
    assert cy["D_t"] == pytest.approx((cy["D_par"] + 2 * cy["D_perp"]) / 3)


def test_paper_janus_effective_radii():
    # paper, Janus table: D = 0.419 um^2/s -> a_eff = 524 nm; D_r = 1.15 1/s -> 523 nm (21 C)
    assert 1e3 * hd.radius_from_translational(0.419, T) == pytest.approx(524, abs=1.5)
    assert 1e3 * hd.radius_from_rotational(1.15, T) == pytest.approx(523, abs=1.5)


@pytest.mark.parametrize(
    ("t_c", "eta_mpa_s"),
    # IAPWS 2008 values at 0.1 MPa (as tabulated e.g. in the CRC Handbook)
    [(10.0, 1.3059), (20.0, 1.0016), (25.0, 0.8900), (40.0, 0.6527)],
)
def test_viscosity_against_iapws(t_c, eta_mpa_s):
    assert 1e3 * hd.water_viscosity(t_c) == pytest.approx(eta_mpa_s, rel=3e-3)


def test_sphere_relations_invert():
    d = hd.sphere_diffusion(0.45, 25.0)
    assert hd.radius_from_translational(d["D_t"], 25.0) == pytest.approx(0.45, rel=1e-12)
    assert hd.radius_from_rotational(d["D_r"], 25.0) == pytest.approx(0.45, rel=1e-12)
    # 1-um-diameter sphere in water at 20 C: D = kT / (6 pi eta a) = 0.4286 um^2/s (IAPWS eta)
    assert hd.sphere_diffusion(0.5, 20.0)["D_t"] == pytest.approx(0.4286, rel=3e-3)


def test_size_uncertainty_propagates_and_bad_sizes_are_refused():
    p = hd.predict(lambda **k: hd.sphere_diffusion(**k)["D_r"], 21.0, 0.0, {"a_um": 0.5},
                   {"a_um": 0.01})
    # D_r ~ a^-3: 2 % in a is 6 % in D_r
    assert p.error / p.value == pytest.approx(0.06, rel=0.01) and p.error_temperature == 0
    with pytest.raises(ValueError, match="b_um must be a positive length"):
        hd.cylinder_diffusion(0.5, -1.0, 21.0)
