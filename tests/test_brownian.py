"""Rigid-body Brownian simulation: exact statistics, noise, injected artefacts, files."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from holofit.cli import main
from holofit.conventions import euler_zyz, euler_zyz_from_matrix, rotation_from_vector
from holofit.simulate.brownian import (
    BrownianParameters,
    MeasurementNoise,
    propagate_rigid_body,
    random_rotation,
    simulate_trajectory,
)
from holofit.tables.fit import read_fit_table


def test_euler_decomposition_round_trip():
    rng = np.random.default_rng(0)
    mats = [random_rotation(rng) for _ in range(50)]
    mats += [euler_zyz(0.3, 0.0, 0.2), euler_zyz(-1.0, math.pi, 0.4)]  # the poles
    for r in mats:
        psi, theta, phi = euler_zyz_from_matrix(r)
        np.testing.assert_allclose(euler_zyz(psi, theta, phi), r, atol=1e-12)


def test_rotation_vector_is_an_exact_rotation():
    w = np.array([0.3, -0.2, 0.5])
    r = rotation_from_vector(w)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(r @ w, w, atol=1e-14)  # axis fixed
    v = np.cross(w, [1, 0, 0])
    v /= np.linalg.norm(v)
    assert math.acos(np.dot(v, r @ v)) == pytest.approx(np.linalg.norm(w))


def test_translation_statistics_lab_and_body_frame():
    # strongly anisotropic so that the body-frame split is tested, not only the trace
    d_par, d_perp, d_r, dt = 1.0, 0.2, 0.05, 0.01
    p = BrownianParameters(200_000, dt, d_par, d_perp, d_r)
    pos, rot = propagate_rigid_body(p, np.random.default_rng(1))
    dr = pos[1:] - pos[:-1]
    u = rot[:-1, :, 2]
    par = np.einsum("ij,ij->i", dr, u) ** 2
    lab = np.einsum("ij,ij->i", dr, dr)
    se = math.sqrt(2 / dr.shape[0])  # relative error of a mean of chi-square(1) values
    assert par.mean() / (2 * d_par * dt) == pytest.approx(1, abs=4 * se)
    assert (lab.mean() - par.mean()) / (4 * d_perp * dt) == pytest.approx(1, abs=4 * se)
    assert lab.mean() / (2 * (d_par + 2 * d_perp) * dt) == pytest.approx(1, abs=4 * se)


def test_rotational_correlation_is_exponential():
    d_r, dt = 0.8, 0.01
    p = BrownianParameters(400_000, dt, 0.0, 0.0, d_r)
    _, rot = propagate_rigid_body(p, np.random.default_rng(2))
    u = rot[:, :, 2]
    for lag in (1, 10, 60):
        c = np.sum(u[lag:] * u[:-lag], axis=1)
        blocks = c[: c.size // 50 * 50].reshape(50, -1).mean(axis=1)
        err = blocks.std(ddof=1) / math.sqrt(50)
        assert abs(c.mean() - math.exp(-2 * d_r * lag * dt)) < 4 * err + 1e-5


def test_beard_schlick_first_order_error_and_default_substeps():
    # one Gaussian rotation-vector step of x = D h gives <u.u'> = 1/3 + 2/3 (1 - 2x) exp(-x)
    d_r, dt = 2.0, 0.1  # x = 0.2 per frame
    expected = 1 / 3 + 2 / 3 * (1 - 2 * 0.2) * math.exp(-0.2)
    p = BrownianParameters(300_000, dt, 0.0, 0.0, d_r, substeps=1)
    _, rot = propagate_rigid_body(p, np.random.default_rng(3))
    u = rot[:, :, 2]
    c = np.sum(u[1:] * u[:-1], axis=1)
    err = c.std() / math.sqrt(c.size)
    assert abs(c.mean() - expected) < 4 * err
    assert abs(c.mean() - math.exp(-0.4)) > 8 * err  # the exact value is resolved: O(x) error
    auto = BrownianParameters(50_000, dt, 0.0, 0.0, d_r)
    assert auto.steps_per_frame == 200
    _, rot = propagate_rigid_body(auto, np.random.default_rng(3))
    u = rot[:, :, 2]
    c = np.sum(u[1:] * u[:-1], axis=1)
    assert abs(c.mean() - math.exp(-0.4)) < 4 * c.std() / math.sqrt(c.size)


def test_measurement_noise_and_artefacts(tmp_path):
    p = BrownianParameters(20_000, 0.01, 0.3, 0.3, 0.3)
    noise = MeasurementNoise(0.03, 0.05, 0.026, flip_fraction=0.01, mirror_fraction=0.005,
                             fail_fraction=0.01, missing_fraction=0.02)
    sim = simulate_trajectory(p, noise, seed=4, static={"a_um": 0.5}, out_dir=tmp_path)
    table = sim.table.set_index("frame")
    truth = sim.truth.set_index("frame")
    assert len(sim.flipped_frames) == 200 and len(sim.mirrored_frames) == 100
    assert not set(sim.missing_frames) & set(table.index)
    assert (table.loc[sim.failed_frames, "status"] == "failed").all()
    assert table.loc[sim.failed_frames, "x_um"].isna().all()
    ok = table.index[table["status"] == "ok"]
    d = table.loc[ok, ["x_um", "y_um", "z_um"]] - truth.loc[ok, ["x_um", "y_um", "z_um"]]
    np.testing.assert_allclose(d.std().to_numpy(), [0.03, 0.03, 0.05], rtol=0.05)
    u_m = table[["ux", "uy", "uz"]]
    u_t = truth[["ux", "uy", "uz"]]
    clean = ok.difference(sim.flipped_frames).difference(sim.mirrored_frames)
    ang = np.arccos(np.clip(np.sum(u_m.loc[clean].to_numpy() * u_t.loc[clean].to_numpy(), 1),
                            -1, 1))
    assert math.sqrt(np.mean(ang**2)) == pytest.approx(0.026, rel=0.05)
    fl = sim.flipped_frames
    assert np.all(np.sum(u_m.loc[fl].to_numpy() * u_t.loc[fl].to_numpy(), 1) < -0.99)
    mi = sim.mirrored_frames
    mirrored_truth = u_t.loc[mi].to_numpy() * [1, 1, -1]
    assert np.all(np.sum(u_m.loc[mi].to_numpy() * mirrored_truth, 1) > 0.99)
    # files: the fit-table schema, truth in the sidecar
    fit = read_fit_table(tmp_path / "trajectory.csv")
    assert fit.frame_interval_s == pytest.approx(0.01)
    meta = json.loads((tmp_path / "trajectory.csv.json").read_text())
    assert meta["truth"]["mirrored_frames"] == sim.mirrored_frames.tolist()
    assert meta["truth"]["dynamics"]["d_r_s"] == 0.3
    assert read_fit_table(tmp_path / "truth.csv").ok.all()


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="d_r_s must be >= 0"):
        BrownianParameters(10, 0.01, 0.3, 0.3, -1.0)
    with pytest.raises(ValueError, match="add up to 1"):
        MeasurementNoise(flip_fraction=0.6, mirror_fraction=0.5)


def test_cli_simulate_trajectory(tmp_path):
    res = CliRunner().invoke(main, [
        "simulate", "trajectory", "--frames", "300", "--frame-rate", "50", "--d-t", "0.4",
        "--d-r", "1.0", "--eps-um", "0.02", "--flip-fraction", "0.01", "--a-um", "0.45",
        "--seed", "7", "-o", str(tmp_path / "sim"),
    ])
    assert res.exit_code == 0, res.output
    fit = read_fit_table(tmp_path / "sim" / "trajectory.csv")
    assert len(fit.table) == 300 and fit.frame_interval_s == pytest.approx(0.02)
    assert fit.table["a_um"].eq(0.45).all()
    res = CliRunner().invoke(main, ["simulate", "trajectory", "--d-r", "1", "-o",
                                    str(tmp_path / "x")])
    assert res.exit_code != 0 and "--d-par and --d-perp" in res.output
