"""Fit parameters: names, the rotation-vector orientation, reporting and error propagation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from holofit.conventions import axis_from_angles, euler_zyz, rotation_from_vector
from holofit.holomodel.parameters import (
    ParameterSpace,
    State,
    index_column,
    particle_with,
    static_parameters,
    static_values,
)
from holofit.particles import Dimer, Ellipsoid, JanusSphere, Sphere, Spherocylinder, VoxelShape


def test_fit_table_names_of_static_parameters():
    assert [p.name for p in static_parameters(Spherocylinder(0.5, 1.0, 1.5))] == [
        "a_um", "b_um", "n"]
    assert [p.name for p in static_parameters(JanusSphere(0.4, 0.05, 1.58, 2.7))] == [
        "radius_um", "cap_thickness_um", "n_core", "n_cap"]
    assert [p.name for p in static_parameters(Dimer(0.4, 0.4, 0.0, 1.58, 1.58))] == [
        "radius1_um", "radius2_um", "gap_um", "n1", "n2"]
    assert index_column("indices", 1) == "n2"


def test_static_values_and_particle_with_round_trip_keep_absorption():
    rod = Spherocylinder(0.5, 1.0, complex(1.5, 0.01))
    values = dict(static_values(rod))
    assert values == {"a_um": 0.5, "b_um": 1.0, "n": 1.5}
    changed = particle_with(rod, {"b_um": 1.2, "n": 1.45})
    assert changed.b_um == 1.2 and complex(changed.index) == complex(1.45, 0.01)
    assert changed.a_um == 0.5


def test_voxel_indices_are_fit_parameters(tmp_path):
    path = tmp_path / "v.dat"
    path.write_text("Nmat=2\n0 0 0 1\n1 0 0 2\n")
    vox = VoxelShape(str(path), 0.05, (1.5, 2.5))
    assert dict(static_values(vox)) == {"n1": 1.5, "n2": 2.5}
    assert particle_with(vox, {"n2": 2.6}).indices == (1.5 + 0j, 2.6 + 0j)


def test_rodrigues_rotation_is_a_rotation_by_the_vector_length():
    w = np.array([0.3, -0.2, 0.5])
    r = rotation_from_vector(w)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(r @ w, w, atol=1e-14)  # the axis is fixed
    v = np.cross(w, [1.0, 0.0, 0.0])
    cos = np.dot(r @ v, v) / np.dot(v, v)
    assert math.isclose(math.acos(cos), np.linalg.norm(w), rel_tol=1e-12)


def _space(model, theta=0.7, psi=1.2, free=("x_um", "orientation", "alpha")):
    state = State((1.0, 2.0, 10.0), euler_zyz(psi, theta, 0.0), 0.9, static_values(model))
    return ParameterSpace(model, free, state)


def test_orientation_parameters_move_the_axis_smoothly_even_at_the_pole():
    rod = Spherocylinder(0.5, 1.0, 1.5)
    space = _space(rod, theta=0.0)
    assert space.names == ("x_um", "rot_a", "rot_b", "alpha")
    v0 = space.initial_vector()
    assert space.state(v0).rotation is not None
    # small rotations about the two perpendicular axes tilt the axis by their length
    for k in (1, 2):
        v = v0.copy()
        v[k] = 1e-3
        u = space.state(v).rotation[:, 2]
        assert math.isclose(math.acos(u[2]), 1e-3, rel_tol=1e-6)
    # an axisymmetric particle keeps phi = 0
    v = v0.copy()
    v[1:3] = [0.2, -0.1]
    assert abs(space.state(v).angles()[2]) < 1e-12


def test_spin_is_a_third_parameter_for_particles_that_are_not_axisymmetric():
    ell = Ellipsoid(0.3, 0.4, 0.6, 1.5)
    space = _space(ell)
    assert space.names == ("x_um", "rot_a", "rot_b", "rot_c", "alpha")
    v = space.initial_vector()
    v[3] = 0.3  # spin about the start axis: the axis stays, phi changes
    s = space.state(v)
    np.testing.assert_allclose(s.rotation[:, 2], space.start.rotation[:, 2], atol=1e-12)
    assert abs(s.angles()[2] - 0.3) < 1e-9


def test_report_gives_angles_axis_and_propagated_errors():
    rod = Spherocylinder(0.5, 1.0, 1.5)
    space = _space(rod, theta=0.7, psi=1.2)
    v = space.initial_vector()
    cov = np.diag([1e-6, 1e-4, 4e-4, 1e-6])  # rot_a, rot_b: 0.01 and 0.02 rad
    values, errors = space.report(v, cov)
    assert math.isclose(values["theta_rad"], 0.7, abs_tol=1e-12)
    assert math.isclose(values["psi_rad"], 1.2, abs_tol=1e-12)
    np.testing.assert_allclose([values["ux"], values["uy"], values["uz"]],
                               axis_from_angles(0.7, 1.2), atol=1e-12)
    # the two rotation axes are perpendicular to u: theta and psi errors combine them
    # as sigma_theta^2 + (sin(theta) sigma_psi)^2 = 0.01^2 + 0.02^2
    total = errors["theta_rad"] ** 2 + (math.sin(0.7) * errors["psi_rad"]) ** 2
    assert math.isclose(total, 0.01**2 + 0.02**2, rel_tol=1e-4)
    assert math.isclose(errors["x_um"], 1e-3) and math.isnan(errors["z_um"])


def test_unknown_parameter_names_are_refused():
    with pytest.raises(ValueError, match="unknown fit parameter"):
        _space(Spherocylinder(0.5, 1.0, 1.5), free=("x_um", "radius_um"))


def test_isotropic_particles_have_no_orientation_parameters():
    sphere = Sphere(0.5, 1.59)
    state = State((1.0, 2.0, 10.0), None, 0.9, static_values(sphere))
    space = ParameterSpace(sphere, ("x_um", "orientation", "radius_um"), state)
    assert space.names == ("x_um", "radius_um")
    values, _ = space.report(space.initial_vector())
    assert "theta_rad" not in values


def test_out_of_range_values_are_reported():
    rod = Spherocylinder(0.5, 1.0, 1.5)
    space = _space(rod, free=("x_um", "n"))
    v = space.initial_vector()
    v[1] = 7.0
    assert any("n = 7" in s for s in space.out_of_range(space.state(v)))
