"""Crop -> prefit on measured holograms, with no manual guess, against published fits.

Each test runs the crop stage (``holofit.crop.run_crop``: normalisation, Hough-type centre
finder, crop) on the measured frame and the prefit stage on its output, with no guess of any
fit parameter: x, y come from the crop table, z, a, n from the automatic estimator. Where a
frame holds several particles, the user's choice of which one to follow is given as a start
point ~1 px from it (``--follow nearest``).

Published values (see tests/data/*/ *.json):
- HoloPy image0001 (test_nmpfit.py gold_sphere): n 1.582, r 0.6484 um, z 14.15 um, alpha free.
  HoloPy's x is the image row: the finder's centre below is (column, row).
- pylorenzmie PS_silica, silica sphere (2021 TestFrame notebook): a 0.4976 um, n 1.4255,
  z 179.284 px x 0.048 um. pylorenzmie's model has no alpha: fitted here with alpha = 1.
- pylorenzmie image0400 (2021 TestFrame notebook): left a 1.1816 um, n 1.3923; right
  a 1.2226 um, n 1.3936; alpha = 1 likewise. Saturated pixels (255) are masked.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import tifffile

from holofit.batch import BatchSettings
from holofit.config import load_instrument
from holofit.crop import CropConfig, run_crop
from holofit.prefit.sphere import SphereFitSettings
from holofit.prefit.stage import run_prefit
from tests.conftest import CONFIGS, DATA

SERIAL = BatchSettings(workers=0, progress=False)


def _crop_folder(tmp_path, raw, background_level, size, instrument, follow_start=None):
    """``holofit crop`` on one raw frame with a flat background of ``background_level``."""
    movie = tmp_path / "movie.tif"
    background = tmp_path / "background.tif"
    tifffile.imwrite(movie, raw)
    tifffile.imwrite(background, np.full(raw.shape, background_level, dtype=raw.dtype))
    follow = "strongest" if follow_start is None else "nearest"
    result = run_crop(movie, background, instrument, tmp_path / "crops",
                      CropConfig(size=size, follow=follow, start=follow_start, plot=False))
    row = pd.read_csv(result.table).iloc[0]
    assert row["status"] in ("ok", "edge"), row["message"]
    return tmp_path / "crops"


def _prefit(tmp_path, crops, fit=None, status="ok"):
    result = run_prefit(crops, tmp_path / "prefit", fit=fit, batch=SERIAL, plot=False)
    row = pd.read_csv(result.table).iloc[0]
    assert row["status"] == status, row["message"]
    return row


def test_holopy_image0001(tmp_path):
    inst = load_instrument(CONFIGS / "instruments" / "holopy_image0001.toml")
    raw = tifffile.imread(DATA / "holopy" / "image0001.tif")
    # already background-divided: a flat background makes the crop stage's normalisation
    # I / mean(I), HoloPy's normalize()
    row = _prefit(tmp_path, _crop_folder(tmp_path, raw, 128, 100, inst))
    assert row["n"] == pytest.approx(1.582, abs=0.005)
    assert row["radius_um"] == pytest.approx(0.6484, abs=0.005)
    assert row["z_um"] == pytest.approx(14.15, abs=0.1)
    # the position in HoloPy's frame: x (row) 5.534, y (column) 5.792 um
    assert row["y_um"] == pytest.approx(5.534, abs=0.02)
    assert row["x_um"] == pytest.approx(5.792, abs=0.02)
    assert row["alpha"] == pytest.approx(0.6497, abs=0.01)
    assert row["r2"] > 0.96


def _pylorenzmie(name):
    # normalised so that the background is 100 counts; 255 is saturated (the crop stage masks
    # pixels at the camera's full scale)
    return tifffile.imread(DATA / "pylorenzmie" / f"{name}.tif")


def test_pylorenzmie_ps_silica_silica_sphere(tmp_path):
    inst = load_instrument(CONFIGS / "instruments" / "pylorenzmie.toml")
    raw = _pylorenzmie("PS_silica")
    crops = _crop_folder(tmp_path, raw, 100, 200, inst, follow_start=(908.5, 484.0))
    row = _prefit(tmp_path, crops, SphereFitSettings(fix_alpha=1.0))
    assert row["radius_um"] == pytest.approx(0.498, abs=0.01)
    assert row["n"] == pytest.approx(1.4255, abs=0.005)
    assert row["z_um"] == pytest.approx(179.284 * 0.048, abs=0.1)
    px = inst.pixel_size_um
    assert row["x_um"] / px == pytest.approx(907.701, abs=0.3)
    assert row["y_um"] / px == pytest.approx(484.8, abs=0.3)


@pytest.mark.parametrize(
    "label, centre, a_pub, n_pub",
    [("left", (582.514, 686.094), 1.1816, 1.3923), ("right", (883.809, 747.796), 1.2226, 1.3936)],
)
def test_pylorenzmie_image0400_both_spheres(tmp_path, label, centre, a_pub, n_pub):
    inst = load_instrument(CONFIGS / "instruments" / "pylorenzmie.toml")
    raw = _pylorenzmie("image0400")
    start = (round(centre[0]) + 0.6, round(centre[1]) - 0.8)
    crops = _crop_folder(tmp_path, raw, 100, 200, inst, follow_start=start)
    # the two spheres' fringes overlap: each crop holds its neighbour's rings, which no single
    # sphere explains (R^2 0.63-0.72, residual 15-20 times the pixel noise): the values agree
    # with the published fits, and the fit is flagged all the same
    row = _prefit(tmp_path, crops, SphereFitSettings(fix_alpha=1.0), status="poor_fit")
    assert "far above the pixel noise" in row["message"]
    assert row["n_masked"] > 0  # the saturated core is left out
    assert row["radius_um"] == pytest.approx(a_pub, abs=0.05)
    assert row["n"] == pytest.approx(n_pub, abs=0.01)
    px = inst.pixel_size_um
    assert np.hypot(row["x_um"] / px - centre[0], row["y_um"] / px - centre[1]) < 1.0


def test_a_fit_far_from_the_data_is_not_plain_ok(tmp_path):
    # pylorenzmie's `sample`, upper-right particle: no good sphere fit exists (its README: "many
    # minima; lm chi2_red >= 8: use it as a failure-flagging test")
    inst = load_instrument(CONFIGS / "instruments" / "pylorenzmie.toml")
    raw = tifffile.imread(DATA / "pylorenzmie" / "sample.tif")
    bg = tifffile.imread(DATA / "pylorenzmie" / "background.tif")
    movie, background = tmp_path / "m.tif", tmp_path / "b.tif"
    tifffile.imwrite(movie, raw)
    tifffile.imwrite(background, bg)
    crops = run_crop(movie, background, inst, tmp_path / "crops",
                     CropConfig(size=301, follow="nearest", start=(921, 303), dark=13.0,
                                plot=False))
    assert pd.read_csv(crops.table).iloc[0]["status"] in ("ok", "edge")
    result = run_prefit(tmp_path / "crops", tmp_path / "prefit",
                        fit=SphereFitSettings(fix_alpha=1.0), batch=SERIAL, plot=False)
    row = pd.read_csv(result.table).iloc[0]
    assert row["status"] == "poor_fit"
    assert "far above the pixel noise" in row["message"] or "outside" in row["message"]


def test_pylorenzmie_image0400_two_tracks_without_a_start_point(tmp_path):
    """Issue 22: the crop stage's default (tracks) finds both spheres of image0400 with no
    start point, one track each, and the prefit of each (keyed by particle, frame) gives what
    the single-particle crops above give (the published sizes and indices)."""
    inst = load_instrument(CONFIGS / "instruments" / "pylorenzmie.toml")
    raw = _pylorenzmie("image0400")
    movie, background = tmp_path / "movie.tif", tmp_path / "background.tif"
    tifffile.imwrite(movie, raw)
    tifffile.imwrite(background, np.full(raw.shape, 100, dtype=raw.dtype))
    crop = run_crop(movie, background, inst, tmp_path / "crops", CropConfig(size=200, plot=False))
    frames = crop.frames.sort_values("x_px")
    assert frames["particle"].tolist() == sorted(frames["particle"])  # ids by x, from 0
    assert len(frames) == 2 and set(frames["status"]) <= {"ok", "edge"}
    published = [((582.514, 686.094), 1.1816, 1.3923), ((883.809, 747.796), 1.2226, 1.3936)]
    result = run_prefit(tmp_path / "crops", tmp_path / "prefit", batch=SERIAL, plot=False,
                        fit=SphereFitSettings(fix_alpha=1.0))
    table = pd.read_csv(result.table).set_index("particle")
    px = inst.pixel_size_um
    for p, (centre, a_pub, n_pub) in zip(frames["particle"], published, strict=True):
        row = table.loc[p]
        assert np.hypot(row["x_um"] / px - centre[0], row["y_um"] / px - centre[1]) < 1.0
        assert row["radius_um"] == pytest.approx(a_pub, abs=0.05)
        assert row["n"] == pytest.approx(n_pub, abs=0.01)
        assert row["status"] == "poor_fit"  # the neighbour's rings, as in the crops above
