"""The demo runs the whole pipeline (simulate -> crop -> prefit -> analyze) on known truth."""

from holofit.demo import run_demo


def test_demo_pipeline_recovers_the_truth(tmp_path):
    lines: list[str] = []
    out = run_demo(tmp_path, echo=lines.append, workers=0, n_frames=80)
    assert out["rms_x_nm"] < 5 and out["rms_y_nm"] < 5 and out["rms_z_nm"] < 20
    assert out["rms_a_nm"] < 5 and out["rms_n"] < 0.003
    # 80 frames give D to ~20 %: a loose check that the chain is consistent end to end
    assert abs(out["d_measured"] - out["d_true"]) < 0.35 * out["d_true"]
    for name in ("sim/movie.tif", "crop/crops.csv", "prefit/prefit.csv", "analysis/summary.csv"):
        assert (tmp_path / name).exists()
    assert any("Measured D" in line for line in lines)
