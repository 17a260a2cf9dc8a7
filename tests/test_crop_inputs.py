"""What the crop stage accepts: several backgrounds, already-normalised movies, option limits.

The truths: HoloPy's and pylorenzmie's published hologram centres (tests/data, see the
README there), and the normalisation formula evaluated directly with numpy on the same pixels.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from click.testing import CliRunner

from holofit.cli import main
from holofit.crop import CropConfig, CropError, run_crop
from holofit.crop.reference import read_reference_frame
from tests.conftest import DATA

HOLOPY = DATA / "holopy"
PYLM = DATA / "pylorenzmie"
BACKGROUNDS = [HOLOPY / f"bg0{k}.tif" for k in (1, 2, 3)]
TOLERANCE_PX = 1.5


def _invoke(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_several_backgrounds_are_one_median():
    direct = np.median(np.stack([tifffile.imread(p) for p in BACKGROUNDS]).astype(float), axis=0)
    np.testing.assert_array_equal(read_reference_frame(BACKGROUNDS), direct)
    assert np.abs(direct - tifffile.imread(BACKGROUNDS[2])).max() > 0  # not just the last one


def test_stacks_and_single_frames_pool_their_frames(tmp_path):
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 4000, (5, 16, 12), dtype=np.uint16)
    tifffile.imwrite(tmp_path / "a.tif", frames[:3], photometric="minisblack")
    tifffile.imwrite(tmp_path / "b.tif", frames[3])
    tifffile.imwrite(tmp_path / "c.tif", frames[4])
    pooled = read_reference_frame([tmp_path / n for n in ("a.tif", "b.tif", "c.tif")])
    np.testing.assert_array_equal(pooled, np.median(frames.astype(float), axis=0))
    tifffile.imwrite(tmp_path / "d.tif", frames[0, :8])
    with pytest.raises(CropError, match=r"d\.tif has frames of shape \(8, 12\), .*a\.tif of "
                                        r"shape \(16, 12\)"):
        read_reference_frame([tmp_path / "a.tif", tmp_path / "d.tif"])


def test_crop_with_three_backgrounds_and_a_dark_frame(tmp_path):
    """HoloPy's tutorial hologram: the centre of its fit, every background in the sidecar."""
    out = tmp_path / "out"
    args = ["crop", HOLOPY / "image01.tif", "--dark", HOLOPY / "df01.tif", "-i",
            "holopy_image01", "-o", out, "--size", "200", "--no-plot"]  # fmt: skip
    for bg in BACKGROUNDS:
        args += ["-b", bg]
    res = _invoke(args)
    assert res.exit_code == 0, res.output
    side = json.loads((out / "crops.csv.json").read_text())
    norm = side["settings"]["normalization"]
    assert norm["background"] == [str(p) for p in BACKGROUNDS]
    assert norm["dark"] == [str(HOLOPY / "df01.tif")]
    assert [i["path"] for i in side["inputs"]] == [
        str(p) for p in (HOLOPY / "image01.tif", *BACKGROUNDS, HOLOPY / "df01.tif")
    ]
    table = np.genfromtxt(out / "crops.csv", delimiter=",", names=True, dtype=None,
                          encoding="utf-8")
    x, y = float(table["x_px"]), float(table["y_px"])
    # HoloPy tutorial fit (24.16, 21.84) um with x = row: column 21.84, row 24.16
    assert np.hypot(x - 21.84 / 0.0851, y - 24.16 / 0.0851) <= TOLERANCE_PX
    # the crop is the paper's normalisation with the median background, evaluated directly
    raw = tifffile.imread(HOLOPY / "image01.tif").astype(float)
    dark = tifffile.imread(HOLOPY / "df01.tif").astype(float)
    bg = np.median(np.stack([tifffile.imread(p) for p in BACKGROUNDS]).astype(float), axis=0)
    direct = (raw - dark) / (bg - dark) * np.mean(bg - dark) / np.mean(raw - dark)
    r, c = int(table["corner_row"]), int(table["corner_col"])
    crop = tifffile.imread(out / "crops.tif")
    np.testing.assert_allclose(crop, direct[r : r + 200, c : c + 200], rtol=2e-6)


@pytest.mark.parametrize(
    "movie,instrument,size,truth",
    [
        # stored normalised with the background at 100 counts; 255 is saturated
        (PYLM / "PS_silica.tif", "pylorenzmie", 201, (376.437, 481.864)),
        # background-divided and scaled so that the maximum is 255; HoloPy's fit (x = row)
        (HOLOPY / "image0001.tif", "holopy_image0001", 80, (5.792 / 0.1151, 5.534 / 0.1151)),
    ],
)
def test_normalised_public_data_crop_without_a_background(tmp_path, movie, instrument, size,
                                                         truth):
    out = tmp_path / "out"
    # the strongest hologram (PS_silica.tif holds two particles; tracks mode crops both)
    res = _invoke(["crop", movie, "--normalized", "-i", instrument, "-o", out, "--size", size,
                   "--no-plot", "--follow", "strongest"])  # fmt: skip
    assert res.exit_code == 0, res.output
    table = np.genfromtxt(out / "crops.csv", delimiter=",", names=True, dtype=None,
                          encoding="utf-8")
    assert str(table["status"]) == "ok"
    x, y = float(table["x_px"]), float(table["y_px"])
    assert np.hypot(x - truth[0], y - truth[1]) <= TOLERANCE_PX
    raw = tifffile.imread(movie).astype(float)
    direct = raw / raw.mean()
    direct[raw >= 255] = np.nan  # saturated (8-bit)
    r, c = int(table["corner_row"]), int(table["corner_col"])
    np.testing.assert_allclose(tifffile.imread(out / "crops.tif"),
                               direct[r : r + size, c : c + size], rtol=2e-6)
    side = json.loads((out / "crops.csv.json").read_text())
    assert side["settings"]["normalization"]["background"] is None
    assert "flat background" in side["settings"]["normalization"]["formula"]


def test_normalised_and_background_exclude_each_other(tmp_path):
    movie = PYLM / "PS_silica.tif"
    with pytest.raises(CropError, match=r"no background given.*normalized=True"):
        run_crop(movie, None, "pylorenzmie", tmp_path / "o")
    with pytest.raises(CropError, match="takes no background"):
        run_crop(movie, BACKGROUNDS[0], "pylorenzmie", tmp_path / "o", CropConfig(normalized=True))
    res = _invoke(["crop", movie, "-i", "pylorenzmie", "-o", tmp_path / "o"])
    assert res.exit_code == 2 and "--background" in res.output and "--normalized" in res.output
    res = _invoke(["crop", movie, "--normalized", "-b", BACKGROUNDS[0], "-i", "pylorenzmie",
                   "-o", tmp_path / "o"])  # fmt: skip
    assert res.exit_code == 2 and "--normalized takes no --background" in res.output
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "option,value,expected",
    [
        ("--size", "0", "Invalid value for '--size': 0 is not in the range x>=8"),
        ("--vote-radius", "2",
         "Invalid value for '--vote-radius' / '--radius': 2.0 is not in the range x>=4"),
        ("--radius", "2", "Invalid value for '--vote-radius' / '--radius'"),  # the old name
        ("--max-particles", "0", "Invalid value for '--max-particles'"),
        ("--min-symmetry", "1.5", "Invalid value for '--min-symmetry'"),
        ("--max-jump", "0", "Invalid value for '--max-jump'"),
        ("--min-score", "-1", "Invalid value for '--min-score'"),
        ("--dark-count", "-3", "Invalid value for '--dark-count'"),
    ],
)
def test_option_values_are_checked_where_the_user_typed_them(tmp_path, option, value, expected):
    res = _invoke(["crop", PYLM / "PS_silica.tif", "--normalized", "-i", "pylorenzmie",
                   "-o", tmp_path / "o", option, value])  # fmt: skip
    assert res.exit_code == 2
    assert expected in res.output
    assert "radius_px" not in res.output and "Traceback" not in res.output
