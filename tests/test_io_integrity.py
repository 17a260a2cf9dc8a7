"""Nothing a movie file claims is dropped silently; compressed TIFFs are read exactly.

Truncation: each file is written by a real writer (Pillow, tifffile in its ImageJ, shaped,
separate-page and LZW layouts, holofit's own stack writer), then cut in the middle of frame
``m``'s pixel data, located in the intact file. The truth is then known without holofit: every
frame before ``m`` is complete and must be read bit for bit; frame ``m`` and every later frame
must raise an error naming the file and the frame; and the movie must be at least ``m + 1``
frames long (all ``N`` when the file's header declares them).
"""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest
import tifffile

from holofit.io import Movie, MovieError, open_movie, write_tiff_stack
from holofit.io.logcapture import capture_log

N = 10
SHAPE = (48, 40)


def _frames(dtype=np.uint8, n=N, seed=0):
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    return np.array([rng.integers(0, top, SHAPE, dtype=dtype) for _ in range(n)])


def _write_pillow(path, frames):
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:])


def _write_separate_pages(path, frames):
    with tifffile.TiffWriter(path) as tif:
        for frame in frames:
            tif.write(frame, contiguous=False)


WRITERS = {
    # name: (writer, does the header declare the frame count?)
    "pillow": (_write_pillow, False),
    "imagej": (lambda p, f: tifffile.imwrite(p, f, imagej=True), True),
    "tifffile": (lambda p, f: tifffile.imwrite(p, f), True),
    "holofit": (lambda p, f: write_tiff_stack(p, list(f)), True),
    "separate_pages": (_write_separate_pages, False),
    "lzw": (lambda p, f: tifffile.imwrite(p, f, compression="lzw"), True),
}


@pytest.mark.parametrize("cut_frame", [1, 5, N - 1])
@pytest.mark.parametrize("layout", sorted(WRITERS))
def test_truncated_movie_accounts_for_every_frame(tmp_path, layout, cut_frame):
    write, declares = WRITERS[layout]
    frames = _frames()
    path = tmp_path / f"{layout}.tif"
    write(path, frames)
    with tifffile.TiffFile(path) as tif:  # where frame m's pixels lie in the intact file
        page = tif.pages[cut_frame]
        cut = int(page.dataoffsets[0]) + int(page.databytecounts[0]) // 2
    path.write_bytes(path.read_bytes()[:cut])

    with open_movie(path) as movie:
        assert len(movie) >= cut_frame + 1
        if declares:
            assert len(movie) == N
        for k in range(cut_frame):
            np.testing.assert_array_equal(movie[k], frames[k])
        for k in range(cut_frame, len(movie)):
            with pytest.raises(MovieError, match=rf"{layout}\.tif: frame {k} .*truncated"):
                movie[k]
        assert len(movie.problems) == 1
        assert f"{layout}.tif" in movie.problems[0]
        assert re.search(rf"frames? {cut_frame}\b", movie.problems[0])


def test_intact_layouts_read_exactly_and_report_nothing(tmp_path):
    frames = _frames()
    for layout, (write, _) in WRITERS.items():
        path = tmp_path / f"{layout}.tif"
        write(path, frames)
        with open_movie(path) as movie:
            assert len(movie) == N, layout
            np.testing.assert_array_equal(np.array(list(movie)), frames)
            assert movie.problems == [] and movie.notes == [], layout


def test_truncation_messages_name_what_is_lost(tmp_path):
    frames = _frames()
    path = tmp_path / "pil.tif"
    _write_pillow(path, frames)
    with tifffile.TiffFile(path) as tif:
        cut = int(tif.pages[5].offset) - 1  # the chain breaks before frame 5's directory
    path.write_bytes(path.read_bytes()[:cut])
    with open_movie(path) as movie:
        assert len(movie) == 6
        assert "frame 5 and any frames after it" in movie.problems[0]
        with pytest.raises(MovieError, match=r"frame 5 cannot be read: the file is truncated: "
                                             r"its directory, at byte \d+, lies past the end"):
            movie[5]
        # tifffile's own complaint is kept, not printed
        assert any("invalid page offset" in note for note in movie.notes)


def test_tifffile_log_lines_are_not_printed(tmp_path, capsys):
    frames = _frames()
    path = tmp_path / "cut.tif"
    _write_pillow(path, frames)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with open_movie(path) as movie:
        for k in range(len(movie)):
            try:
                movie[k]
            except MovieError:
                pass
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


def test_capture_log_collects_and_restores():
    logger = logging.getLogger("tifffile")
    before = (logger.propagate, list(logger.handlers))
    with capture_log("tifffile") as lines:
        logger.warning("invalid page offset %d", 42)
        logger.warning("invalid page offset %d", 42)
        logger.info("not a warning")
    assert lines == ["invalid page offset 42"]
    assert (logger.propagate, list(logger.handlers)) == before


@pytest.mark.parametrize(
    "options",
    [
        {"compression": "lzw"},
        {"compression": "lzw", "predictor": True},
        {"compression": "zlib"},
        {"compression": "adobe_deflate", "predictor": True},
        {"compression": "packbits"},
        {"compression": "zstd"},
    ],
    ids=lambda o: "+".join(str(v) for v in o.values()),
)
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_compressed_movies_are_read_exactly(tmp_path, options, dtype):
    frames = _frames(dtype, n=4)
    for name, kwargs in (("stack.tif", {"photometric": "minisblack"}),
                         ("imagej.tif", {"imagej": True})):
        path = tmp_path / name
        tifffile.imwrite(path, frames, **kwargs, **options)
        with tifffile.TiffFile(path) as tif:
            assert int(tif.pages[0].compression) != 1  # really compressed
        with open_movie(path) as movie:
            assert len(movie) == 4
            np.testing.assert_array_equal(np.array(list(movie)), frames)
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, frame in enumerate(frames):
        tifffile.imwrite(folder / f"f{k}.tif", frame, **options)
    with open_movie(folder) as movie:
        np.testing.assert_array_equal(np.array(list(movie)), frames)


def _set_compression_tag(path, code):
    """Rewrite the Compression tag of every page in place (values stored inline)."""
    with tifffile.TiffFile(path, mode="r+b") as tif:
        for page in tif.pages:
            page.tags["Compression"].overwrite(code)


def test_unknown_compression_is_named(tmp_path):
    path = tmp_path / "odd.tif"
    tifffile.imwrite(path, _frames(n=5))
    _set_compression_tag(path, 60001)
    with pytest.raises(MovieError, match=r"odd\.tif: frames are compressed with TIFF "
                                         r"compression 60001 .*cannot decode"):
        Movie(path)


def test_missing_codec_library_is_named(tmp_path, monkeypatch):
    """Without imagecodecs, tifffile has no LZW decoder: the message says so."""

    class WithoutImagecodecs(dict):
        def __getitem__(self, code):
            if code == 1:
                return lambda data, **_: data
            raise KeyError(f"<COMPRESSION.LZW: {code}> requires the 'imagecodecs' package")

    path = tmp_path / "lzw.tif"
    tifffile.imwrite(path, _frames(n=5), compression="lzw")
    monkeypatch.setattr(tifffile.TIFF, "DECOMPRESSORS", WithoutImagecodecs())
    with pytest.raises(MovieError, match=r"lzw\.tif: frames are compressed with LZW .*needs the "
                                         r"imagecodecs package"):
        Movie(path)


def test_a_second_series_is_not_a_lost_frame(tmp_path):
    """A thumbnail after the frames (another series) is neither a frame nor a loss."""
    frames = _frames(n=6)
    path = tmp_path / "thumb.tif"
    with tifffile.TiffWriter(path) as tif:
        tif.write(frames, contiguous=False, compression="zlib")
        tif.write(frames[0, ::4, ::4], compression="zlib")
    with open_movie(path) as movie:
        assert len(movie) == 6 and movie.problems == []
        np.testing.assert_array_equal(np.array(list(movie)), frames)
