"""Movies as users have them: pages appended one by one, Pillow stacks, AVI, PNG folders, HDF5,
and 16-bit movies given an 8-bit instrument (issue 24, items 1, 2 and 13).

The truths: the frames written (read back bit-exact), and the crop of the same frames stored
as a plain TIFF stack.
"""

from __future__ import annotations

import dataclasses
import sys

import cv2
import numpy as np
import pandas as pd
import pytest
import tifffile
from PIL import Image

from holofit.crop import CropConfig, CropError, run_crop
from holofit.io.movie import MovieError, open_movie
from holofit.io.tiffstack import write_tiff_stack
from tests.test_crop_synthetic import instrument, ring_pattern

SHAPE = (128, 128)
CENTRES = [(60.0 + 2 * k, 64.0 - k) for k in range(6)]


def _frames(dtype=np.uint8, scale=100.0):
    return [(scale * (1 + ring_pattern(SHAPE, x, y, amplitude=0.3))).round().astype(dtype)
            for x, y in CENTRES]


def _odd_one_out():
    frames = _frames()
    frames[3] = np.full((128, 200), 100, np.uint8)
    return frames


def _check_odd_movie(path, frames):
    with open_movie(path) as movie:
        assert len(movie) == len(frames)
        for k, frame in enumerate(frames):
            if k == 3:
                with pytest.raises(MovieError, match=r"frame 3 .*shape \(128, 200\), the first "
                                                     r"frame has \(128, 128\)") as info:
                    movie[k]
                assert "keyframe" not in str(info.value)
            else:
                np.testing.assert_array_equal(movie[k], frame)


def test_pages_appended_one_by_one_are_all_frames(tmp_path):
    path = tmp_path / "appended.tif"
    frames = _odd_one_out()
    for frame in frames:
        tifffile.imwrite(path, frame, append=True)
    _check_odd_movie(path, frames)
    result = run_crop(path, None, instrument(), tmp_path / "out",
                      CropConfig(normalized=True, size=64, plot=False))
    table = result.frames.set_index("frame")
    assert len(table) == 6
    assert table.loc[3, "status"] == "error" and "shape (128, 200)" in table.loc[3, "message"]
    ok = table.drop(index=3)
    assert (ok["status"] == "ok").all()
    truth = pd.DataFrame(CENTRES, columns=["x_px", "y_px"]).drop(index=3)
    np.testing.assert_allclose(ok[["x_px", "y_px"]].to_numpy(), truth.to_numpy(), atol=0.5)


def test_pillow_stack_with_a_page_of_another_shape(tmp_path):
    path = tmp_path / "pillow.tif"
    frames = _odd_one_out()
    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:])
    _check_odd_movie(path, frames)


def test_pillow_stack_of_equal_pages(tmp_path):
    path = tmp_path / "pillow.tif"
    frames = _frames()
    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:])
    with open_movie(path) as movie:
        assert len(movie) == len(frames)
        for k, frame in enumerate(frames):
            np.testing.assert_array_equal(movie[k], frame)


def _crop_positions(path, tmp_path, name, **kw):
    result = run_crop(path, None, kw.pop("inst", instrument()), tmp_path / name,
                      CropConfig(normalized=True, size=64, plot=False, **kw))
    assert (result.frames["status"] == "ok").all(), result.frames["message"].tolist()
    return result.frames[["x_px", "y_px"]].to_numpy()


def test_avi_png_folder_and_hdf5_read_as_the_tiff_stack(tmp_path):
    frames = _frames()
    avi = tmp_path / "movie.avi"
    writer = cv2.VideoWriter(str(avi), cv2.VideoWriter_fourcc(*"FFV1"), 10, SHAPE[::-1],
                             isColor=False)
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()
    pngs = tmp_path / "pngs"
    pngs.mkdir()
    frames16 = _frames(np.uint16, 1000.0)
    for k, frame in enumerate(frames16):
        assert cv2.imwrite(str(pngs / f"frame{k}.png"), frame)  # natural order: 2 before 10
    import h5py

    h5 = tmp_path / "movie.h5"
    with h5py.File(h5, "w") as f:
        f["data/frames"] = np.stack(frames16)
    for path, truth in ((avi, frames), (pngs, frames16), (h5, frames16)):
        with open_movie(path) as movie:
            assert len(movie) == len(truth) and movie.dtype == truth[0].dtype, path
            for k, frame in enumerate(truth):
                np.testing.assert_array_equal(movie[k], frame)
    tiff = tmp_path / "movie.tif"
    write_tiff_stack(tiff, frames)
    reference = _crop_positions(tiff, tmp_path, "tiff")
    np.testing.assert_allclose(_crop_positions(avi, tmp_path, "avi"), reference)
    sixteen = dataclasses.replace(instrument(), bit_depth=16)
    np.testing.assert_allclose(_crop_positions(pngs, tmp_path, "png", inst=sixteen), reference,
                               atol=0.05)
    np.testing.assert_allclose(_crop_positions(h5, tmp_path, "h5", inst=sixteen), reference,
                               atol=0.05)


def test_hdf5_with_several_datasets_is_named_by_the_user(tmp_path):
    import h5py

    h5 = tmp_path / "two.h5"
    frames = np.stack(_frames())
    with h5py.File(h5, "w") as f:
        f["a"] = frames
        f["b"] = frames[::-1]
    with pytest.raises(MovieError, match=r"two\.h5: several image datasets \(/a, /b\); name "
                                         r"the movie's as FILE\.h5:DATASET"):
        open_movie(h5)
    with open_movie(f"{h5}:b") as movie:
        np.testing.assert_array_equal(movie[0], frames[-1])


def test_colour_video_frames_are_refused_as_for_tiff(tmp_path):
    avi = tmp_path / "colour.avi"
    writer = cv2.VideoWriter(str(avi), cv2.VideoWriter_fourcc(*"FFV1"), 10, SHAPE[::-1])
    rng = np.random.default_rng(1)
    for _ in range(2):
        writer.write(rng.integers(0, 255, (*SHAPE, 3), dtype=np.uint8))
    writer.release()
    with pytest.raises(MovieError, match=r"colour\.avi: frame 0: colour images .* convert to "
                                         "one grey channel"):
        open_movie(avi)


def test_unsupported_formats_name_what_is_supported(tmp_path, monkeypatch):
    text = tmp_path / "movie.dat"
    text.write_text("not a movie")
    with pytest.raises(MovieError, match=r"movie\.dat: not a movie format holofit reads .*"
                                         r"TIFF.*PNG.*\.avi.*\.h5"):
        open_movie(text)
    avi = tmp_path / "movie.avi"
    writer = cv2.VideoWriter(str(avi), cv2.VideoWriter_fourcc(*"FFV1"), 10, SHAPE[::-1],
                             isColor=False)
    writer.write(_frames()[0])
    writer.release()
    # imageio not installed: an import of it fails
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v3", None)
    with pytest.raises(MovieError, match=r"movie\.avi: reading video files needs the optional "
                                         r"package 'imageio': pip install 'holofit\[movies\]'"):
        open_movie(avi)


@pytest.mark.parametrize("with_background", [False, True])
def test_sixteen_bit_movie_with_an_eight_bit_instrument_is_an_error(tmp_path, with_background):
    frames = _frames(np.uint16, 1000.0)
    movie = tmp_path / "m16.tif"
    write_tiff_stack(movie, frames)
    background = None
    if with_background:
        background = tmp_path / "bg.tif"
        tifffile.imwrite(background, np.full(SHAPE, 200, np.uint8))
    with pytest.raises(CropError) as info:
        run_crop(movie, background, instrument(), tmp_path / "out",
                 CropConfig(normalized=not background, size=64, plot=False))
    message = str(info.value)
    assert "m16.tif: frame 0 has counts up to" in message
    assert "exceed the full scale 255" in message and "bit_depth = 8" in message
    assert "16-bit integers (uint16)" in message and "--keep-saturated" in message
    assert not (tmp_path / "out" / "crops.csv").exists()
    # with the camera's bit depth the same movie is cropped
    sixteen = dataclasses.replace(instrument(), bit_depth=16)
    assert (run_crop(movie, None, sixteen, tmp_path / "ok",
                     CropConfig(normalized=True, size=64,
                                plot=False)).frames["status"] == "ok").all()


def test_a_later_frame_beyond_full_scale_is_an_error_row(tmp_path):
    frames = _frames(np.uint16, 100.0)
    frames[2] = frames[2] * 10  # counts above 255
    movie = tmp_path / "m.tif"
    write_tiff_stack(movie, frames)
    result = run_crop(movie, None, instrument(), tmp_path / "out",
                      CropConfig(normalized=True, size=64, plot=False))
    table = result.frames.set_index("frame")
    assert table.loc[2, "status"] == "error"
    assert "frame 2: counts up to" in table.loc[2, "message"]
    assert "exceed the full scale 255" in table.loc[2, "message"]
    assert (table.drop(index=2)["status"] == "ok").all()


def test_sixteen_bit_grey_video_keeps_its_counts(tmp_path):
    av = pytest.importorskip("av")
    frames = [(np.arange(64 * 80).reshape(64, 80) * 13 + 100 * k).astype(np.uint16)
              for k in range(4)]
    path = tmp_path / "g16.avi"
    container = av.open(str(path), "w")
    stream = container.add_stream("ffv1", rate=10)
    stream.width, stream.height, stream.pix_fmt = 80, 64, "gray16le"
    for frame in frames:
        for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="gray16le")):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()
    with open_movie(path) as movie:
        assert len(movie) == 4 and movie.dtype == np.uint16
        for k, frame in enumerate(frames):
            np.testing.assert_array_equal(movie[k], frame)


def test_planar_rgb_is_colour_not_a_frame_of_another_shape(tmp_path):
    path = tmp_path / "planar.tif"
    tifffile.imwrite(path, np.stack(_frames()[:3]), photometric="rgb", planarconfig="separate")
    with pytest.raises(MovieError, match=r"planar\.tif: colour images \(axes 'SYX'.*"
                                         "photometric='minisblack'"):
        open_movie(path)
