"""The demo runs the whole pipeline (simulate -> crop -> prefit -> analyze) on known truth."""

import pytest

from holofit.demo.rod import run_demo


def test_demo_pipeline_recovers_the_truth(tmp_path):
    lines: list[str] = []
    out = run_demo(tmp_path, particle="sphere", echo=lines.append, workers=0, n_frames=80)
    assert out["rms_x_nm"] < 5 and out["rms_y_nm"] < 5 and out["rms_z_nm"] < 20
    assert out["rms_a_nm"] < 5 and out["rms_n"] < 0.003
    # 80 frames give D to ~20 %: a loose check that the chain is consistent end to end
    assert abs(out["d_measured"] - out["d_true"]) < 0.35 * out["d_true"]
    for name in ("sim/movie.tif", "crop/crops.csv", "prefit/prefit.csv", "analysis/summary.csv"):
        assert (tmp_path / name).exists()
    assert any("Measured D" in line for line in lines)


@pytest.mark.slow
def test_rod_demo_runs_all_five_stages(tmp_path):
    lines: list[str] = []
    out = run_demo(tmp_path, particle="rod", echo=lines.append, workers=2, n_frames=40)
    assert out["ok_fraction"] > 0.9
    assert abs(out["a_um"] - 0.501) < 0.01 and abs(out["b_um"] - 1.079) < 0.02
    assert out["rms_x_um_nm"] < 10 and out["rms_z_um_nm"] < 30 and out["axis_rms_deg"] < 1
    for name in ("crop/crops.csv", "prefit/prefit.csv", "library/library.csv", "fit/fit.csv",
                 "fit/static.json", "analysis/summary.csv"):
        assert (tmp_path / name).exists()
    assert any(line.startswith("6. analyze") for line in lines)
