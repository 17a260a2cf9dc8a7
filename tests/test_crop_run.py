"""The crop stage end to end: outputs, their contract, following, streaming, bad input."""

from __future__ import annotations

import json
import math
import re
import tracemalloc
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tifffile

from holofit.camera import Camera
from holofit.crop import CenterFinder, CropConfig, CropError, normalize, run_crop
from holofit.io.tiffstack import write_tiff_stack
from holofit.particles import Sphere
from holofit.simulate.holograms import simulate_movie
from holofit.status import CROP_STATUSES as STATUSES
from tests.test_crop_synthetic import (
    INSTRUMENT,
    instrument,
    multi_particle_frame,
    ring_pattern,
)

CONTRACT_COLUMNS = [
    "frame",
    "status",
    "message",
    "x_px",
    "y_px",
    "x_um",
    "y_um",
    "corner_row",
    "corner_col",
    "score",
    "n_candidates",
]
CAMERA = Camera(bit_depth=8, background_counts=120.0, read_noise_counts=0.8)


def _outputs(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()} if folder.exists() else set()


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """10 frames 180 x 200: particles in the middle, two near edges, one empty frame (4)."""
    inst = instrument()
    px = inst.pixel_size_um
    shape = (180, 200)
    xy = [(100.3, 90.2), (6.4, 91.0), (120.0, 170.7), (90.6, 80.1), (0, 0), (101.2, 95.5),
          (140.8, 60.3), (60.4, 120.9), (98.0, 88.8), (104.1, 86.2)]  # fmt: skip
    z = np.linspace(6, 25, len(xy))
    pos = np.array([(x * px, y * px, zz) for (x, y), zz in zip(xy, z, strict=True)])
    folder = tmp_path_factory.mktemp("sim")
    sim = simulate_movie(Sphere(0.5, 1.45), inst, pos, shape, seed=4, keep_frames=True,
                         out_dir=folder / "raw")  # fmt: skip
    frames = list(sim.frames)
    frames[4] = CAMERA.expose(np.ones(shape), np.random.default_rng(9))  # no particle
    write_tiff_stack(folder / "movie.tif", frames)
    truth = sim.truth.copy()
    truth.loc[4, ["x_px", "y_px"]] = np.nan
    return folder, folder / "raw" / "background.tif", truth, frames


def test_outputs_follow_the_contract(simulated, tmp_path):
    folder, background, truth, frames = simulated
    out = tmp_path / "out"
    result = run_crop(folder / "movie.tif", background, INSTRUMENT, out, CropConfig(size=100))
    assert _outputs(out) == {
        "crops.tif",
        "crops.tif.json",
        "crops.csv",
        "crops.csv.json",
        "candidates.csv",
        "candidates.csv.json",
        "crops.png",
    }
    table = pd.read_csv(out / "crops.csv")
    assert set(CONTRACT_COLUMNS) <= set(table.columns)
    assert table["frame"].tolist() == list(range(10))
    assert set(table["status"]) <= set(STATUSES)
    assert table["status"].tolist() == [
        "ok", "edge", "edge", "ok", "no_particle", "ok", "ok", "ok", "ok", "ok"
    ]  # fmt: skip
    assert result.counts == {"ok": 7, "edge": 2, "no_particle": 1, "off_track": 0, "error": 0}
    found = table["status"].isin(["ok", "edge"])
    err = np.hypot(table["x_px"] - truth["x_px"], table["y_px"] - truth["y_px"])[found]
    assert err.max() < 0.5
    pixel = instrument().pixel_size_um
    np.testing.assert_allclose(table["x_um"][found], table["x_px"][found] * pixel)
    np.testing.assert_allclose(table["y_um"][found], table["y_px"][found] * pixel)
    assert (table["n_candidates"][found] == 1).all() and table["n_candidates"][4] == 0
    assert math.isnan(table["x_px"][4]) and math.isnan(table["corner_row"][4])

    crops = tifffile.imread(out / "crops.tif")
    assert crops.shape == (10, 100, 100) and crops.dtype == np.float32
    assert np.isnan(crops[4]).all()
    bg = np.median(tifffile.imread(background), axis=0)
    for k in np.flatnonzero(found):
        row, col = int(table["corner_row"][k]), int(table["corner_col"][k])
        assert 0 <= row <= 180 - 100 and 0 <= col <= 200 - 100
        image, _ = normalize(frames[k], bg)
        np.testing.assert_array_equal(crops[k], image[row : row + 100, col : col + 100])
        if table["status"][k] == "ok":  # the centre pixel is crop pixel [50, 50]
            assert row == math.floor(table["y_px"][k] + 0.5) - 50
            assert col == math.floor(table["x_px"][k] + 0.5) - 50
    assert table["corner_col"][1] == 0 and table["corner_row"][2] == 80  # shifted inside

    meta = json.loads((out / "crops.csv.json").read_text())
    assert set(table.columns) <= set(meta["units"])
    assert meta["units"]["x_um"].startswith("um")
    assert meta["config"]["instrument"]["pixel_size_um"] == pixel
    assert meta["settings"]["size_px"] == 100
    assert meta["status_counts"]["no_particle"] == 1
    assert meta["crops"]["pages"] == 10
    cands = pd.read_csv(out / "candidates.csv")
    assert len(cands) == table["n_candidates"].sum() and cands["selected"].sum() == 9


def test_follow_nearest_tracks_the_chosen_particle(tmp_path):
    inst = instrument()
    px = inst.pixel_size_um
    shape = (200, 260)
    rng = np.random.default_rng(7)
    strong = np.array([180.0, 70.0]) + np.cumsum(rng.normal(0, 1.0, (8, 2)), axis=0)
    weak = np.array([70.0, 130.0]) + np.cumsum(rng.normal(0, 1.0, (8, 2)), axis=0)
    frames = []
    for k in range(8):
        spheres = [(Sphere(0.9, 1.59), (strong[k, 0] * px, strong[k, 1] * px, 14.0))]
        if k != 5:  # the weak particle leaves the focus in frame 5
            spheres.append((Sphere(0.5, 1.45), (weak[k, 0] * px, weak[k, 1] * px, 12.0)))
        frames.append(multi_particle_frame(spheres, inst, shape, rng))
    write_tiff_stack(tmp_path / "movie.tif", frames)
    tifffile.imwrite(tmp_path / "bg.tif", np.full(shape, 120, np.uint8))

    best = run_crop(tmp_path / "movie.tif", tmp_path / "bg.tif", inst, tmp_path / "a",
                    CropConfig(size=100, plot=False, follow="strongest")).frames  # fmt: skip
    assert np.hypot(best["x_px"] - strong[:, 0], best["y_px"] - strong[:, 1]).max() < 0.3

    near = run_crop(tmp_path / "movie.tif", tmp_path / "bg.tif", inst, tmp_path / "b",
                    CropConfig(size=100, follow="nearest", start=(72, 128),
                               plot=False)).frames  # fmt: skip
    assert near["status"][5] == "no_particle" and "max jump" in near["message"][5]
    rest = near.drop(index=5)
    err = np.hypot(rest["x_px"] - np.delete(weak[:, 0], 5), rest["y_px"] - np.delete(weak[:, 1], 5))
    assert err.max() < 0.3
    assert (rest["n_candidates"] == 2).all()


def _ring_movie(path: Path, n: int, shape: tuple[int, int], dtype=np.uint8, scale=120.0):
    rng = np.random.default_rng(0)
    frames = []
    for k in range(n):
        x0 = shape[1] / 2 + 20 * np.sin(k / 5)
        y0 = shape[0] / 2 + 15 * np.cos(k / 7)
        pattern = ring_pattern(shape, x0, y0) * scale
        frames.append(np.clip(rng.poisson(pattern), 0, np.iinfo(dtype).max).astype(dtype))
    return frames


def _peak_memory(tmp_path: Path, n: int, shape: tuple[int, int]) -> int:
    folder = tmp_path / str(n)
    folder.mkdir()
    write_tiff_stack(folder / "movie.tif", _ring_movie(folder, n, shape))
    tifffile.imwrite(folder / "bg.tif", np.full(shape, 120, np.uint8))
    tracemalloc.start()
    try:
        result = run_crop(folder / "movie.tif", folder / "bg.tif", INSTRUMENT, folder / "out",
                          CropConfig(plot=False))  # fmt: skip
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert result.counts["ok"] == n
    return peak


def test_movie_streams_frame_by_frame(tmp_path):
    """Peak memory does not grow with the movie's length (numpy reports to tracemalloc)."""
    shape = (512, 640)
    frame_float32 = shape[0] * shape[1] * 4  # 1.3 MB
    short = _peak_memory(tmp_path, 8, shape)
    long = _peak_memory(tmp_path, 48, shape)
    print(f"\npeak traced memory: {short / 1e6:.1f} MB (8 frames), {long / 1e6:.1f} MB (48 frames)")
    assert long - short < frame_float32  # 40 more frames would be 52 MB
    assert long < 48 * frame_float32 / 4


def test_folder_of_16bit_frames_and_dark_frame(tmp_path):
    inst16 = replace(instrument(), bit_depth=16)
    shape = (160, 180)
    frames = _ring_movie(tmp_path, 4, shape, np.uint16, scale=3000.0)
    movie = tmp_path / "frames"
    movie.mkdir()
    for k, f in enumerate(frames):
        tifffile.imwrite(movie / f"img{k}.tif", f + np.uint16(200))  # dark level 200
    tifffile.imwrite(tmp_path / "bg.tif", np.full(shape, 3200, np.uint16))
    tifffile.imwrite(tmp_path / "dark.tif", np.full(shape, 200, np.uint16))
    result = run_crop(movie, tmp_path / "bg.tif", inst16, tmp_path / "out",
                      CropConfig(dark=tmp_path / "dark.tif", size=80, plot=False))  # fmt: skip
    t = result.frames
    assert (t["status"] == "ok").all()
    for k in range(4):
        x0 = shape[1] / 2 + 20 * np.sin(k / 5)
        y0 = shape[0] / 2 + 15 * np.cos(k / 7)
        assert np.hypot(t["x_px"][k] - x0, t["y_px"][k] - y0) < 0.1
    meta = json.loads((tmp_path / "out" / "crops.csv.json").read_text())
    assert any(i["path"].endswith("dark.tif") for i in meta["inputs"])
    # an 8-bit instrument cannot have recorded these counts: say so instead of masking all
    with pytest.raises(CropError, match=r"bg\.tif: background counts up to 3200 exceed.*255"):
        run_crop(movie, tmp_path / "bg.tif", INSTRUMENT, tmp_path / "o2", CropConfig(plot=False))


# -- bad input -----------------------------------------------------------------------------


@pytest.fixture
def small_movie(tmp_path):
    shape = (120, 130)
    write_tiff_stack(tmp_path / "movie.tif", _ring_movie(tmp_path, 5, shape))
    tifffile.imwrite(tmp_path / "bg.tif", np.full(shape, 120, np.uint8))
    return tmp_path, shape


def _crop(folder, movie="movie.tif", bg="bg.tif", **kw):
    kw.setdefault("size", 64)
    kw.setdefault("plot", False)
    return run_crop(folder / movie, folder / bg, INSTRUMENT, folder / "out", CropConfig(**kw))


def test_unreadable_movie(small_movie):
    folder, _ = small_movie
    (folder / "junk.tif").write_bytes(b"\x00" * 100)
    with pytest.raises(CropError, match=r"junk\.tif: not a readable TIFF"):
        _crop(folder, movie="junk.tif")
    assert _outputs(folder / "out") == set()


def test_truncated_movie_gives_a_row_for_every_frame(small_movie):
    folder, _ = small_movie
    data = (folder / "movie.tif").read_bytes()
    (folder / "cut.tif").write_bytes(data[: len(data) // 2])  # 2 of 5 frames survive whole
    result = _crop(folder, movie="cut.tif")
    t = result.frames
    assert t["frame"].tolist() == [0, 1, 2, 3, 4]
    assert t["status"].tolist() == ["ok", "ok", "error", "error", "error"]
    for k in (2, 3, 4):
        assert re.match(rf".*cut\.tif: frame {k} cannot be read: the file is truncated",
                        t["message"][k])
    assert result.problems and "frames 2-4 of the 5" in result.problems[0]
    side = json.loads((folder / "out" / "crops.csv.json").read_text())
    assert side["movie"]["problems"] == result.problems
    assert np.isnan(tifffile.imread(folder / "out" / "crops.tif")[2:]).all()
    # the last directory damaged (the stack's directories follow its pixels): every pixel is
    # still there, so every frame is read, as from the intact file
    intact = _crop(folder).frames
    crops = tifffile.imread(folder / "out" / "crops.tif")
    (folder / "cut.tif").write_bytes(data[:-40])
    result = _crop(folder, movie="cut.tif")
    pd.testing.assert_frame_equal(result.frames, intact)
    np.testing.assert_array_equal(tifffile.imread(folder / "out" / "crops.tif"), crops)


def test_background_of_another_shape(small_movie):
    folder, _ = small_movie
    tifffile.imwrite(folder / "bg2.tif", np.full((100, 130), 120, np.uint8))
    with pytest.raises(CropError, match=r"bg2\.tif.*\(100, 130\).*movie\.tif.*\(120, 130\)"):
        _crop(folder, bg="bg2.tif")
    assert _outputs(folder / "out") == set()


def test_all_zero_background(small_movie):
    folder, shape = small_movie
    tifffile.imwrite(folder / "zero.tif", np.zeros(shape, np.uint8))
    with pytest.raises(CropError, match=r"zero\.tif: background is zero everywhere"):
        _crop(folder, bg="zero.tif")
    with pytest.raises(CropError, match=r"bg\.tif: background is zero everywhere"):
        _crop(folder, dark=120)  # dark level equal to the background
    assert _outputs(folder / "out") == set()


def test_nans_in_background_and_in_a_frame(small_movie):
    folder, shape = small_movie
    bg = np.full(shape, 120.0, np.float32)
    bg[7, 9] = np.nan
    tifffile.imwrite(folder / "nanbg.tif", bg)
    with pytest.raises(CropError, match=r"nanbg\.tif.*non-finite.*row 7, column 9"):
        _crop(folder, bg="nanbg.tif")
    frames = [f.astype(np.float32) for f in _ring_movie(folder, 4, shape)]
    frames[2][10, 11] = np.nan
    write_tiff_stack(folder / "float.tif", frames)
    result = _crop(folder, movie="float.tif")
    t = result.frames
    assert t["status"].tolist() == ["ok", "ok", "error", "ok"]
    assert "float.tif" in t["message"][2] and "frame 2" in t["message"][2]
    assert "row 10, column 11" in t["message"][2]


def test_empty_movie_and_every_frame_failing(small_movie):
    folder, shape = small_movie
    (folder / "empty").mkdir()
    with pytest.raises(CropError, match=r"empty: folder contains no TIFF or PNG frames"):
        _crop(folder, movie="empty")
    write_tiff_stack(folder / "dark.tif", [np.zeros(shape, np.uint8)] * 3)
    with pytest.raises(CropError, match=r"every frame failed.*frame 0.*dark level"):
        _crop(folder, movie="dark.tif")
    assert _outputs(folder / "out") == set()  # nothing half-written, no temporary files


def test_failed_rerun_keeps_previous_complete_outputs(small_movie):
    folder, shape = small_movie
    first = _crop(folder)
    before = (folder / "out" / "crops.csv").read_bytes()
    write_tiff_stack(folder / "dark.tif", [np.zeros(shape, np.uint8)] * 3)
    with pytest.raises(CropError):
        _crop(folder, movie="dark.tif")
    assert (folder / "out" / "crops.csv").read_bytes() == before
    assert len(tifffile.imread(folder / "out" / "crops.tif")) == len(first.frames)
    assert not [p for p in (folder / "out").iterdir() if p.name.endswith(".part")]


def test_parameter_errors(small_movie):
    folder, _ = small_movie
    with pytest.raises(CropError, match="crop size 200 does not fit"):
        _crop(folder, size=200)
    tifffile.imwrite(folder / "darkframe.tif", np.zeros((10, 10), np.uint8))
    with pytest.raises(CropError, match=r"darkframe\.tif: dark frame has shape"):
        _crop(folder, dark=folder / "darkframe.tif")
    with pytest.raises(ValueError, match="follow must be one of"):
        _crop(folder, follow="closest")
    with pytest.raises(ValueError, match="start point is only used"):
        _crop(folder, start=(3, 4))
    with pytest.raises(CropError, match="no such instrument"):
        run_crop(folder / "movie.tif", folder / "bg.tif", "no_such_scope", folder / "out")
    with pytest.raises(ValueError, match="radius_px"):
        _crop(folder, finder=CenterFinder(radius_px=1))
