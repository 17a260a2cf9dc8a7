"""Per-track analysis and pooling over tracks, against simulations with known truth."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from holofit.analysis import AnalysisConfig
from holofit.analysis.errors import AnalysisError
from holofit.analysis.track_tables import write_tracks
from holofit.analysis.tracks import (
    TrackPooling,
    analyze_tracks,
    pool_estimates,
    split_tracks,
)
from holofit.simulate.brownian import BrownianParameters, MeasurementNoise, simulate_trajectory

DT = 0.01
D_TRUE = 0.44  # um^2/s, a 1 um sphere in water


def _track(particle: int, d: float, n: int, seed: int, poor: float = 0.0) -> pd.DataFrame:
    sim = simulate_trajectory(
        BrownianParameters(n_frames=n, frame_interval_s=DT, d_par_um2_s=d, d_perp_um2_s=d,
                           d_r_s=1.0, start_position_um=(10.0 * particle, 10.0, 15.0)),
        MeasurementNoise(eps_xy_um=0.01), seed=seed, static={"a_um": 0.5})
    t = sim.table.copy()
    if poor:
        rng = np.random.default_rng(seed)
        t.loc[rng.random(len(t)) < poor, "status"] = "poor_fit"
    return t.assign(particle=particle)


def _write(tmp_path, parts: list[pd.DataFrame]):
    path = tmp_path / "fit.csv"
    pd.concat(parts, ignore_index=True).to_csv(path, index=False)
    return path


SPHERE = AnalysisConfig(model="sphere", temperature_c=21.0, a_um=0.5)


def test_pool_estimates_is_the_weighted_mean_and_its_chi2() -> None:
    x, s = np.array([1.0, 2.0, 4.0]), np.array([1.0, 1.0, 2.0])
    value, error, chi2, dof, _ = pool_estimates(x, s)
    w = 1 / s**2
    assert value == pytest.approx((1 + 2 + 1) / 2.25)
    assert error == pytest.approx(1 / np.sqrt(w.sum()))
    assert chi2 == pytest.approx(float(np.sum(w * (x - value) ** 2)))
    assert dof == 2


def test_consistency_p_value_is_uniform_for_alike_tracks() -> None:
    # tracks that measure one value with their stated errors: p < 0.05 about 5 % of the time
    rng = np.random.default_rng(3)
    ps = []
    for _ in range(2000):
        s = rng.uniform(0.5, 2.0, 5)
        ps.append(pool_estimates(3.0 + s * rng.standard_normal(5), s)[4])
    frac = np.mean(np.array(ps) < 0.05)
    assert abs(frac - 0.05) < 3 * np.sqrt(0.05 * 0.95 / 2000)


def test_tracks_recover_d_and_name_the_odd_ones(tmp_path) -> None:
    parts = [_track(p, D_TRUE, 600, seed=10 + p) for p in range(4)]
    parts.append(_track(4, 3 * D_TRUE, 600, seed=20))  # an impurity: a smaller particle
    parts.append(_track(5, D_TRUE, 600, seed=21, poor=0.7))  # dust: the model misses it
    parts.append(_track(6, D_TRUE, 12, seed=22))  # a track that left the field at once
    path = _write(tmp_path, parts)
    # the impurity diffuses 3x too fast for the fitted 500 nm: the consistency check flags it
    # (its hydrodynamic size a third of the optical one) and the pool leaves it out ...
    res = analyze_tracks(path, SPHERE, frame_interval_s=DT)
    status = {t.particle: t.status for t in res.tracks}
    assert status == {0: "analysed", 1: "analysed", 2: "analysed", 3: "analysed",
                      4: "flagged", 5: "poor_fit", 6: "short"}
    assert "size D_t" in res.tracks[4].message and "x the optical" in res.tracks[4].message
    assert sorted(res.estimate("D_t", "sphere").particles) == [0, 1, 2, 3]
    # ... and pooled as asked, it is the outlier the leave-one-out pulls name
    res = analyze_tracks(path, SPHERE, frame_interval_s=DT,
                         pooling=TrackPooling(include_flagged=True))
    est = res.estimate("D_t")
    assert est is not None and est.model == "sphere"
    assert est.outliers == [4]
    assert sorted(est.particles) == [0, 1, 2, 3]
    assert abs(est.value - D_TRUE) < 2 * est.error
    for t in res.tracks[:4]:
        m = t.result.measured["D_t"]
        assert abs(m.pull(D_TRUE)) < 3
    assert any("particle(s) 4" in n for n in res.notes)
    files = write_tracks(res, tmp_path / "out", inputs=[tmp_path / "fit.csv"])
    pooled = pd.read_csv(files["pooled"]).set_index("quantity")
    assert pooled.loc["D_t", "n_tracks"] == 4
    rows = pd.read_csv(files["tracks"])
    assert set(rows["particle"]) == set(range(7))


def test_duplicate_particle_frame_rows_are_a_clear_error(tmp_path) -> None:
    # a track table edited by hand: frame 5 of particle 0 twice
    a = _track(0, D_TRUE, 100, seed=1)
    path = _write(tmp_path, [a, a.iloc[[5]]])
    with pytest.raises(AnalysisError, match=r"fit.csv \(particle 0\): frame\(s\) 5 appear more"):
        analyze_tracks(path, SPHERE, frame_interval_s=DT)


def test_no_track_to_analyse_says_why(tmp_path) -> None:
    path = _write(tmp_path, [_track(0, D_TRUE, 10, seed=1), _track(1, D_TRUE, 8, seed=2)])
    with pytest.raises(AnalysisError, match=r"particle 0: .*fewer than 20"):
        analyze_tracks(path, SPHERE, frame_interval_s=DT)


def test_split_tracks_refuses_non_integer_ids() -> None:
    with pytest.raises(AnalysisError, match="row 1 holds 'x'"):
        split_tracks(pd.DataFrame({"particle": [0, "x"], "frame": [0, 1]}), "f.csv")


def test_cli_analyze_runs_every_track_and_pools(tmp_path) -> None:
    from click.testing import CliRunner

    from holofit.cli import main

    parts = [_track(p, D_TRUE, 300, seed=30 + p) for p in range(3)]
    path = _write(tmp_path, parts)
    out = tmp_path / "analysis"
    res = CliRunner().invoke(main, ["analyze", str(path), "--model", "sphere", "--a-um", "0.5",
                                    "--frame-interval-s", str(DT), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "pooled over tracks" in res.output
    for name in ("tracks.csv", "pooled.csv", "summary.csv", "tracks.png", "track_msds.png",
                 "particle_0_summary.csv", "particle_2_msd.png"):
        assert (out / name).is_file(), name
    summary = pd.read_csv(out / "summary.csv")
    assert set(summary["particle"]) == {0, 1, 2}
    pooled = pd.read_csv(out / "pooled.csv").set_index("quantity")
    assert abs(pooled.loc["D_t", "value"] - D_TRUE) < 3 * pooled.loc["D_t", "error"]
