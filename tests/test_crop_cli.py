"""``holofit crop`` on the command line."""

from __future__ import annotations

import numpy as np
import pandas as pd
import tifffile
from click.testing import CliRunner

from holofit.cli import main
from holofit.io.tiffstack import write_tiff_stack
from tests.test_crop_synthetic import ring_pattern


def _movie(tmp_path):
    shape = (150, 170)
    rng = np.random.default_rng(0)
    frames = [
        rng.poisson(ring_pattern(shape, 80.3 + k, 70.6 - k) * 120).astype(np.uint8)
        for k in range(4)
    ]
    write_tiff_stack(tmp_path / "movie.tif", frames)
    tifffile.imwrite(tmp_path / "bg.tif", np.full(shape, 133, np.uint8))  # + dark 13
    return tmp_path / "movie.tif", tmp_path / "bg.tif"


def test_crop_command(tmp_path):
    movie, bg = _movie(tmp_path)
    out = tmp_path / "out"
    res = CliRunner().invoke(
        main,
        ["crop", str(movie), "--background", str(bg), "--dark-count", "13",
         "-i", "paper_60x_water", "-o", str(out), "--size", "90", "--no-plot"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "4 ok" in res.output
    table = pd.read_csv(out / "crops.csv")
    np.testing.assert_allclose(table["x_px"], 80.3 + np.arange(4), atol=0.1)
    np.testing.assert_allclose(table["y_px"], 70.6 - np.arange(4), atol=0.1)
    assert tifffile.imread(out / "crops.tif").shape == (4, 90, 90)
    assert not (out / "crops.png").exists()


def test_crop_command_follow_nearest(tmp_path):
    movie, bg = _movie(tmp_path)
    res = CliRunner().invoke(
        main,
        ["crop", str(movie), "-b", str(bg), "-i", "paper_60x_water", "-o", str(tmp_path / "o"),
         "--size", "90", "--follow", "nearest", "--start", "81,70", "--max-jump", "5"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (tmp_path / "o" / "crops.png").exists()


def test_crop_command_errors(tmp_path):
    movie, bg = _movie(tmp_path)
    base = ["crop", str(movie), "-b", str(bg), "-i", "paper_60x_water", "-o", str(tmp_path / "o")]
    runner = CliRunner()
    res = runner.invoke(main, [*base, "--start", "3,4"])
    assert res.exit_code == 2 and "--follow nearest" in res.output
    res = runner.invoke(main, [*base, "--follow", "nearest", "--start", "3"])
    assert res.exit_code == 2 and "X,Y" in res.output
    res = runner.invoke(main, [*base, "--dark", str(bg), "--dark-count", "3"])
    assert res.exit_code == 2 and "not both" in res.output
    res = runner.invoke(
        main, ["crop", str(tmp_path / "nope.tif"), "-b", str(bg), "-i", "paper_60x_water",
               "-o", str(tmp_path / "o")]
    )  # fmt: skip
    assert res.exit_code == 1 and "nope.tif: no such file" in res.output
    res = runner.invoke(main, [*base, "--size", "400"])
    assert res.exit_code == 1 and "does not fit" in res.output
    res = runner.invoke(main, [*base[:4], "-i", "no_such_scope", "-o", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert "holofit crop: error: no_such_scope: no such instrument" in res.output
