"""The fit-table schema: round trip, completion of the orientation, gaps, and clear errors."""

import json

import numpy as np
import pandas as pd
import pytest

from holofit.analysis.trajectory import Trajectory
from holofit.conventions import axis_from_angles
from holofit.tables.fit import (
    STATUSES,
    FitTableError,
    column_unit,
    read_fit_table,
    validate_fit_table,
    write_fit_table,
)


def _table(n=6, dt=0.01, with_u=True, with_angles=True):
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.2, 2.9, n)
    psi = rng.uniform(-3, 3, n)
    df = pd.DataFrame({"frame": np.arange(n) + 10, "time_s": (np.arange(n) + 10) * dt})
    df["x_um"], df["y_um"], df["z_um"] = rng.normal(size=(3, n))
    if with_u:
        u = axis_from_angles(theta, psi)
        df["ux"], df["uy"], df["uz"] = u.T
    if with_angles:
        df["theta_rad"], df["psi_rad"] = theta, psi
    df["a_um"] = 0.5 + 0.01 * np.arange(n)
    df["d_x_um"] = 0.003
    df["chi2"], df["r2"] = 1e-4, 0.98
    df["status"] = "ok"
    df["message"] = ""
    return df


def test_round_trip_with_sidecar(tmp_path):
    df = _table()
    df = df[list(reversed(df.columns))]  # any order in, canonical order out
    path = tmp_path / "fit.csv"
    written = write_fit_table(path, df, config={"engine": "test"})
    fit = read_fit_table(path)
    assert list(fit.table.columns[:5]) == ["frame", "time_s", "x_um", "y_um", "z_um"]
    assert list(fit.table.columns[-2:]) == ["status", "message"]
    assert fit.frame_interval_s == pytest.approx(0.01)
    np.testing.assert_allclose(fit.table["x_um"], written.table["x_um"], rtol=1e-9)
    meta = json.loads((tmp_path / "fit.csv.json").read_text())
    assert meta["units"]["x_um"] == "um" and meta["units"]["d_x_um"] == "um"
    assert meta["units"]["theta_rad"] == "rad"
    assert meta["frame_interval_s"] == pytest.approx(0.01, rel=1e-12)
    assert meta["schema"]["name"] == "holofit fit table"
    assert fit.static_summary()["a_um"]["median"] == pytest.approx(0.525)


def test_orientation_completed_from_either_form():
    full = _table()
    from_angles = validate_fit_table(_table(with_u=False)).table
    from_axis = validate_fit_table(_table(with_angles=False)).table
    np.testing.assert_allclose(from_angles[["ux", "uy", "uz"]], full[["ux", "uy", "uz"]],
                               atol=1e-12)
    np.testing.assert_allclose(from_axis["theta_rad"], full["theta_rad"], atol=1e-9)
    np.testing.assert_allclose(np.cos(from_axis["psi_rad"] - full["psi_rad"]), 1, atol=1e-9)


def test_gaps_from_missing_and_failed_frames():
    df = _table(n=8)
    df = df.drop(index=[3]).reset_index(drop=True)  # frame 13 missing
    df.loc[4, ["x_um", "y_um", "z_um", "ux", "uy", "uz", "theta_rad", "psi_rad"]] = np.nan
    df.loc[4, "status"] = "failed"  # frame 15
    df.loc[4, "time_s"] = np.nan
    traj = Trajectory.from_fit_table(validate_fit_table(df))
    assert traj.first_frame == 10 and traj.n_frames == 8
    np.testing.assert_array_equal(traj.valid, [1, 1, 1, 0, 1, 0, 1, 1])
    assert np.isnan(traj.position_um[3]).all() and np.isnan(traj.axis[5]).all()


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda d: d.drop(columns="status"), "missing required column(s) status"),
        (lambda d: d.assign(frame=[10, 11, 11, 13, 14, 15]), "frame(s) 11 appear more than once"),
        (lambda d: d.assign(status=["ok", "ok", "good", "ok", "ok", "ok"]),
         "frame 12 holds 'good'"),
        (lambda d: d.assign(x_um=[0, 1, np.nan, 0, 0, 0]), "'x_um' is NaN or missing at ok frame"),
        (lambda d: d.assign(ux=d.ux * 1.1), "not a unit vector"),
        (lambda d: d.assign(theta_rad=d.theta_rad + 0.01), "disagrees with (theta_rad, psi_rad)"),
        (lambda d: d.assign(time_s=[0.1, 0.11, 0.12, 0.135, 0.14, 0.15]),
         "time_s is not t0 + frame"),
        (lambda d: d.assign(frame=[0, 1, 2.5, 3, 4, 5]), "must hold integers"),
        (lambda d: d.assign(a_um=["0.5", "x", "0.5", "0.5", "0.5", "0.5"]),
         "column 'a_um' must be numeric; frame 11"),
    ],
)
def test_schema_errors_name_file_column_and_frame(change, expected):
    with pytest.raises(FitTableError) as err:
        validate_fit_table(change(_table()), source="run7/fit.csv")
    assert "run7/fit.csv" in str(err.value) and expected in str(err.value)


def test_failed_rows_may_be_empty(tmp_path):
    df = _table()
    df.loc[2, [c for c in df.columns if c not in ("frame", "status")]] = np.nan
    df.loc[2, "status"] = "not_converged"
    fit = write_fit_table(tmp_path / "f.csv", df)
    again = read_fit_table(tmp_path / "f.csv")
    assert list(again.ok) == [True, True, False, True, True, True]
    assert fit.frame_interval_s == pytest.approx(0.01)
    assert set(STATUSES) >= set(again.table["status"])


def test_unreadable_and_missing_files(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.csv"):
        read_fit_table(tmp_path / "nope.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("")
    with pytest.raises(FitTableError, match=r"bad\.csv"):
        read_fit_table(bad)


def test_column_units():
    assert column_unit("b_um") == "um" and column_unit("d_b_um") == "um"
    assert column_unit("d_psi_rad") == "rad" and column_unit("n") == "1"
    assert column_unit("time_s") == "s" and column_unit("status").startswith("text")


def test_an_empty_message_column_reads_back_as_text_and_takes_a_message(tmp_path):
    """A pass table whose every row is fine has no message at all: the CSV's column is empty
    and would read back as floats. read_table gives text, so that a quality rule can write a
    message into it (the per-track rules of a multi-track pass stopped with a TypeError)."""
    import pandas as pd

    from holofit.io.tables import read_table
    from holofit.quality import per_track

    path = tmp_path / "t.csv"
    pd.DataFrame({"particle": [0, 0, 1, 1], "frame": [0, 1, 0, 1], "status": "ok",
                  "message": [""] * 4, "chi2_red": [1.0, 9.0, 1.0, 1.0]}).to_csv(path,
                                                                            index=False)
    table = read_table(path)
    assert (table["message"] == "").all()

    def flag_big(part):
        big = part["chi2_red"] > 5
        part.loc[big, ["status", "message"]] = ["poor_fit", "chi2_red above 5"]
        return int(big.sum())

    assert per_track(flag_big)(table) == 1
    assert table.loc[1, "message"] == "chi2_red above 5" and table.loc[1, "status"] == "poor_fit"
