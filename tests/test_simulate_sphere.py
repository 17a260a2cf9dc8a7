"""`holofit simulate sphere`: files, ground truth, camera statistics."""

import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from holofit.camera import Camera
from holofit.cli import main
from holofit.config import load_instrument, resolve_config
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.io import open_movie
from holofit.particles import Sphere
from holofit.scattering.mie import LorenzMie


def test_cli_writes_movie_background_and_truth(tmp_path):
    out = tmp_path / "sim"
    res = CliRunner().invoke(
        main,
        [
            "simulate",
            "sphere",
            "-i",
            "paper_100x_oil",
            "--radius",
            "0.6",
            "--index",
            "1.45",
            "--position",
            "6,7,9",
            "--position",
            "6.5,7.2,12",
            "--shape",
            "96,128",
            "--alpha",
            "0.8",
            "--no-noise",
            "-o",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    truth = pd.read_csv(out / "truth.csv")
    assert truth[["x_um", "y_um", "z_um"]].to_numpy().tolist() == [[6, 7, 9], [6.5, 7.2, 12]]
    meta = json.loads((out / "truth.csv.json").read_text())
    assert meta["truth"]["particle"]["radius_um"] == 0.6 and meta["units"]["z_um"] == "um"
    inst = load_instrument(resolve_config("paper_100x_oil", "instruments"))
    with open_movie(out / "movie.tif") as movie, open_movie(out / "background.tif") as bg:
        assert len(movie) == 2 and movie.frame_shape == (96, 128) and movie.dtype == np.uint8
        level = meta["truth"]["camera"]["background_counts"]
        assert np.all(bg[0] == round(level))
        # noise-free: the frame is the exact hologram times the background level, quantised
        wave = LorenzMie().solve(Sphere(0.6, 1.45), inst.optics)
        model = calc_hologram(
            wave, (6.5, 7.2, 12), DetectorGrid((96, 128), inst.pixel_size_um), 0.8
        )
        assert np.max(np.abs(movie[1] - model * level)) <= 0.5 + 1e-9
        assert np.ptp(movie[1]) > 20  # a real hologram, not a blank frame


def test_cli_rejects_bad_input(tmp_path):
    r = CliRunner().invoke(
        main, ["simulate", "sphere", "--radius", "-1", "--position", "1,2,3", "-o", str(tmp_path)]
    )
    assert r.exit_code == 2 and "Invalid value for '--radius': -1.0 is not in the range x>0" in (
        r.output
    )
    r = CliRunner().invoke(main, ["simulate", "sphere", "--position", "1,2", "-o", str(tmp_path)])
    assert r.exit_code != 0 and "three comma-separated numbers" in r.output


def test_camera_noise_statistics():
    cam = Camera(
        bit_depth=12, background_counts=1000.0, electrons_per_count=4.0, read_noise_counts=2.0
    )
    raw = cam.expose(np.ones((400, 400)), np.random.default_rng(0)).astype(float)
    assert raw.mean() == pytest.approx(1000.0, abs=0.2)
    # variance = shot (counts / gain) + read^2 + quantisation 1/12
    assert raw.var() == pytest.approx(1000 / 4 + 4 + 1 / 12, rel=0.02)


def test_camera_saturates_and_quantises():
    cam = Camera(bit_depth=8, background_counts=200.0)
    raw = cam.expose(np.array([[0.5, 2.0]]), noise=False)
    assert raw.dtype == np.uint8 and raw.tolist() == [[100, 255]]
    with pytest.raises(ValueError, match="background_counts"):
        Camera(bit_depth=8, background_counts=300)
