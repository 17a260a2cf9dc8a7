"""Movie reading (multi-page, OME, folders, 8/16 bit, lazily) and atomic table output."""

import json
import tracemalloc

import numpy as np
import pandas as pd
import pytest
import tifffile

from holofit.io import (
    Movie,
    MovieError,
    TiffStackWriter,
    open_movie,
    read_table,
    write_table,
    write_tiff_stack,
)
from holofit.io.tables import sidecar_path
from holofit.provenance import sidecar


def _frames(n=6, shape=(20, 30), dtype=np.uint8, seed=0):
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    return [rng.integers(0, top, shape, dtype=dtype) for _ in range(n)]


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_multipage_tiff_roundtrip(tmp_path, dtype):
    frames = _frames(dtype=dtype)
    path = tmp_path / "movie.tif"
    assert write_tiff_stack(path, frames) == len(frames)
    with open_movie(path) as movie:
        assert len(movie) == len(frames)
        assert movie.frame_shape == (20, 30) and movie.dtype == dtype
        for got, want in zip(movie, frames, strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(movie[-1], frames[-1])


def test_ome_tiff_stack(tmp_path):
    frames = np.stack(_frames(n=4, dtype=np.uint16))
    path = tmp_path / "movie.ome.tif"
    tifffile.imwrite(path, frames, ome=True, metadata={"axes": "TYX"})
    with Movie(path) as movie:
        assert len(movie) == 4
        np.testing.assert_array_equal(movie[2], frames[2])


def test_imagej_hyperstack_with_z_and_t(tmp_path):
    data = np.arange(2 * 3 * 8 * 9, dtype=np.uint16).reshape(2, 3, 8, 9)
    path = tmp_path / "ij.tif"
    tifffile.imwrite(path, data, imagej=True, metadata={"axes": "TZYX"})
    with Movie(path) as movie:
        assert len(movie) == 6
        np.testing.assert_array_equal(movie[4], data[1, 1])


def test_folder_of_frames_in_natural_order(tmp_path):
    frames = _frames(n=12)
    for i, f in enumerate(frames):
        tifffile.imwrite(tmp_path / f"frame{i}.tif", f)
    (tmp_path / "notes.txt").write_text("ignored")
    with open_movie(tmp_path) as movie:
        assert len(movie) == 12
        np.testing.assert_array_equal(movie[10], frames[10])  # frame10 after frame9


def test_folder_frame_of_wrong_shape_names_file(tmp_path):
    tifffile.imwrite(tmp_path / "a1.tif", np.zeros((4, 4), np.uint8))
    tifffile.imwrite(tmp_path / "a2.tif", np.zeros((5, 4), np.uint8))
    movie = open_movie(tmp_path)
    with pytest.raises(MovieError, match=r"a2\.tif: frame 1 has shape"):
        movie[1]


def test_reading_is_lazy(tmp_path):
    """Iterating a 60 MB movie never holds more than a few frames."""
    path = tmp_path / "big.tif"
    frame_bytes = 512 * 512 * 2
    with TiffStackWriter(path) as w:
        for i in range(120):
            w.write(np.full((512, 512), i, np.uint16))
    tracemalloc.start()
    with open_movie(path) as movie:
        total = 0
        for i, frame in enumerate(movie):
            total += int(frame[0, 0])
            assert frame[0, 0] == i
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert total == sum(range(120))
    assert peak < 6 * frame_bytes


def test_truncated_tiff_names_file_and_frame(tmp_path):
    path = tmp_path / "cut.tif"
    write_tiff_stack(path, _frames(n=10, shape=(64, 64)))
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(MovieError, match=r"cut\.tif"):
        movie = open_movie(path)
        for _ in movie:
            pass


def test_not_a_tiff_and_missing_and_empty(tmp_path):
    bad = tmp_path / "bad.tif"
    bad.write_text("hello")
    with pytest.raises(MovieError, match=r"bad\.tif: not a readable TIFF"):
        open_movie(bad)
    with pytest.raises(MovieError, match="no such file"):
        open_movie(tmp_path / "missing.tif")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(MovieError, match=r"no TIFF or PNG frames.*holofit reads"):
        open_movie(empty)


def test_truncated_imagej_stack_keeps_its_declared_length(tmp_path):
    path = tmp_path / "ij.tif"
    frames = np.arange(10, dtype=np.uint8)[:, None, None] * np.ones((64, 64), np.uint8)
    tifffile.imwrite(path, frames, imagej=True)
    assert len(open_movie(path)) == 10
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    with open_movie(path) as movie:
        assert len(movie) == 10  # the header's count, not the pages that survived
        for k in range(5):
            np.testing.assert_array_equal(movie[k], frames[k])
        for k in range(5, 10):
            with pytest.raises(MovieError, match=rf"ij\.tif: frame {k} cannot be read: the file "
                                                 "is truncated"):
                movie[k]
        assert movie.problems == [
            f"{path}: the file is truncated ({len(raw) // 2} bytes): frames 5-9 of the 10 in "
            "the file cannot be read"
        ]


def test_outputs_get_ordinary_permissions(tmp_path):
    import os

    mask = os.umask(0)
    os.umask(mask)
    write_tiff_stack(tmp_path / "s.tif", _frames(n=2))
    write_table(tmp_path / "t.csv", pd.DataFrame({"a": [1]}), {"kind": "x"})
    for name in ("s.tif", "t.csv", "t.csv.json"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~mask


def test_rgb_is_refused(tmp_path):
    path = tmp_path / "rgb.tif"
    tifffile.imwrite(path, np.zeros((8, 8, 3), np.uint8), photometric="rgb")
    with pytest.raises(MovieError, match="colour"):
        open_movie(path)


def test_stack_writer_leaves_nothing_on_failure(tmp_path):
    path = tmp_path / "out.tif"
    with pytest.raises(RuntimeError):
        with TiffStackWriter(path) as w:
            w.write(np.zeros((4, 4), np.uint8))
            raise RuntimeError("crash")
    assert list(tmp_path.iterdir()) == []


def test_stack_writer_rejects_mixed_shapes(tmp_path):
    with pytest.raises(ValueError, match="frame 1 has shape"):
        with TiffStackWriter(tmp_path / "x.tif") as w:
            w.write(np.zeros((4, 4), np.uint8))
            w.write(np.zeros((5, 4), np.uint8))
    assert not (tmp_path / "x.tif").exists()


def test_table_with_sidecar(tmp_path):
    df = pd.DataFrame({"frame": [0, 1], "x_um": [1.25, 2.5]})
    meta = sidecar(kind="test table", units={"x_um": "um"}, config={"a": 1}, inputs=[tmp_path])
    path = write_table(tmp_path / "t.csv", df, meta)
    pd.testing.assert_frame_equal(read_table(path), df)
    doc = json.loads(sidecar_path(path).read_text())
    assert doc["units"]["x_um"] == "um" and doc["config"] == {"a": 1}
    assert doc["versions"]["numpy"] == np.__version__ and "command" in doc


def test_table_write_failure_keeps_old_file(tmp_path):
    path = tmp_path / "t.csv"
    write_table(path, pd.DataFrame({"a": [1]}))

    class Boom(pd.DataFrame):
        def to_csv(self, *a, **k):
            raise OSError("disk full")

    with pytest.raises(OSError):
        write_table(path, Boom({"a": [2]}))
    assert read_table(path)["a"].tolist() == [1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]
