"""Background division and normalisation (the paper's I_measured), masks and reference frames."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from holofit.crop import CropError, Normalizer, normalize
from holofit.crop.reference import read_dark, read_reference_frame
from tests.conftest import DATA


def _paper(frame, bg, dark):
    """The paper's formula written out directly (float64)."""
    d = frame.astype(float) - dark
    b = bg.astype(float) - dark
    return d / b * b.mean() / d.mean()


def test_formula_matches_paper():
    rng = np.random.default_rng(0)
    bg = rng.uniform(90, 140, (40, 50))
    frame = np.rint(bg * rng.uniform(0.7, 1.3, bg.shape) * 1.1).astype(np.uint8)
    image, mask = normalize(frame, bg, 7.0)
    assert not mask.any()
    np.testing.assert_allclose(image, _paper(frame, bg, 7.0), rtol=2e-6)
    assert image.dtype == np.float32


def test_dark_frame_equals_dark_count_and_brightness_cancels():
    rng = np.random.default_rng(1)
    bg = rng.uniform(100, 200, (30, 30))
    frame = bg * rng.uniform(0.8, 1.2, bg.shape) + 13
    a, _ = normalize(frame, bg + 13, 13)
    b, _ = normalize(frame, bg + 13, np.full(bg.shape, 13.0))
    np.testing.assert_allclose(a, b, rtol=1e-6)
    # a brighter lamp (all frame counts above dark x 1.5) changes nothing: mean ratio
    c, _ = normalize((frame - 13) * 1.5 + 13, bg + 13, 13)
    np.testing.assert_allclose(a, c, rtol=1e-5)
    assert float(np.mean(a)) == pytest.approx(1.0, abs=0.05)


def test_zero_background_pixels_are_masked_not_divided():
    bg = np.full((20, 20), 100.0)
    bg[3, 4] = 0.0  # dead pixel
    bg[10, 11] = 1.5  # essentially dark (below 2 % of the median)
    frame = np.full((20, 20), 100, np.uint16)
    norm = Normalizer(bg)
    image, mask = norm(frame)
    assert norm.n_masked_background == 2
    assert mask[3, 4] and mask[10, 11] and mask.sum() == 2
    assert np.isnan(image[3, 4]) and np.isnan(image[10, 11])
    assert np.all(np.isfinite(image[~mask]))
    assert np.allclose(image[~mask], 1.0)


def test_saturated_pixels_masked_only_when_asked():
    bg = np.full((10, 10), 100.0)
    frame = np.full((10, 10), 100, np.uint8)
    frame[5, 5] = 255
    image, mask = normalize(frame, bg, saturation=255)
    assert mask[5, 5] and np.isnan(image[5, 5]) and mask.sum() == 1
    image, mask = normalize(frame, bg)
    assert not mask.any() and np.isfinite(image).all()


@pytest.mark.parametrize(
    "bg,frame,dark,match",
    [
        (np.zeros((8, 8)), np.ones((8, 8)), None, "zero everywhere"),
        (np.full((8, 8), 5.0), np.ones((8, 8)), 5.0, "zero everywhere"),
        (np.where(np.arange(64).reshape(8, 8) < 40, 0.0, 9.0), np.ones((8, 8)), None, "62%"),
        (np.full((8, 8), np.nan), np.ones((8, 8)), None, "non-finite"),
        (np.ones((8, 8)), np.ones((8, 9)), None, "shape"),
        (np.ones((8, 8)), np.full((8, 8), np.nan, np.float32), None, "first at row 0"),
        (np.full((8, 8), 50.0), np.full((8, 8), 3.0), 3.0, "dark level"),
        (np.ones((8, 8)), np.ones((8, 8)), np.ones((4, 4)), "dark frame has shape"),
    ],
)
def test_bad_input_gives_clear_errors(bg, frame, dark, match):
    with pytest.raises(ValueError, match=match):
        normalize(frame, bg, dark)


def test_holopy_image01_published_pixel(tmp_path):
    """HoloPy's tutorial: (raw - df) / (mean(bg01..03) - df) gives 0.91964285 at [0, 0]."""
    folder = DATA / "holopy"
    raw = tifffile.imread(folder / "image01.tif")
    bgs = np.stack([tifffile.imread(folder / f"bg0{k}.tif") for k in (1, 2, 3)])
    dark = tifffile.imread(folder / "df01.tif")
    image, _ = normalize(raw, bgs.astype(float).mean(axis=0), dark)
    ratio = (bgs.mean(axis=0) - dark).mean() / (raw.astype(float) - dark).mean()
    assert image[0, 0] / ratio == pytest.approx(0.91964285, abs=1e-6)


def test_reference_stack_reduced_by_median(tmp_path):
    rng = np.random.default_rng(2)
    frames = rng.integers(90, 110, (5, 12, 14)).astype(np.uint16)
    frames[2, 4, 4] = 60000  # a cosmic ray in one frame does not survive the median
    tifffile.imwrite(tmp_path / "bg.tif", frames)
    bg = read_reference_frame(tmp_path / "bg.tif")
    np.testing.assert_array_equal(bg, np.median(frames, axis=0))
    folder = tmp_path / "bgdir"
    folder.mkdir()
    for k, f in enumerate(frames[:3]):
        tifffile.imwrite(folder / f"bg{k}.tif", f)
    np.testing.assert_array_equal(read_reference_frame(folder), np.median(frames[:3], axis=0))
    single = tmp_path / "one.tif"
    tifffile.imwrite(single, frames[0])
    np.testing.assert_array_equal(read_reference_frame(single), frames[0])
    assert read_dark(13) == 13.0 and read_dark(None) is None


def test_reference_errors_name_the_file(tmp_path):
    bad = tmp_path / "bg.tif"
    bad.write_bytes(b"not a tiff at all")
    with pytest.raises(CropError, match=r"background: .*bg\.tif"):
        read_reference_frame(bad)
    nan = tmp_path / "nan.tif"
    data = np.ones((2, 6, 6), np.float32)
    data[1, 2, 3] = np.nan
    tifffile.imwrite(nan, data)
    with pytest.raises(CropError, match=r"nan\.tif.*frame 1 at row 2, column 3"):
        read_reference_frame(nan)
    with pytest.raises(CropError, match="finite"):
        read_dark(float("nan"))
