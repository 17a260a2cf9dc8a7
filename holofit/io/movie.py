"""Lazy, frame-by-frame reading of hologram movies.

A movie is a multi-page TIFF (plain, ImageJ, OME-TIFF, or one header per page as Pillow and
many cameras write it) or a folder of single-frame TIFF files; video files (AVI, ...), folders of
PNG frames and HDF5 datasets are read through the optional readers of
:mod:`holofit.io.readers`. Frames are read one at a time,
so a 2000-frame megapixel movie never sits in memory whole. 8- and 16-bit (and float) pixels
are returned unchanged in their own dtype; compressed pages (LZW, deflate, ...) are decoded by
tifffile, with the ``imagecodecs`` package for the codecs Python does not ship.

Nothing a file claims is dropped silently: a movie is as long as the file says it is (its
header's frame count, or the pages its directory chain points to: every page is a frame), and a
frame that cannot be read (a truncated file, a page whose pixel data lie past the end of the
file, a page of another shape than the first) raises
:class:`MovieError` naming the file and the frame when it is read, so that a stage can record it
and go on. What is wrong with the file as a whole is in :attr:`Movie.problems`.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from holofit.io.logcapture import capture_log
from holofit.io.readers import (
    HDF5_SUFFIXES,
    IMAGE_SUFFIXES,
    SUPPORTED,
    VIDEO_SUFFIXES,
    Hdf5Reader,
    ImageFolderReader,
    ReaderError,
    VideoReader,
    grey_frame,
    sniff,
    split_dataset,
)

__all__ = ["Movie", "MovieError", "open_movie"]

TIFF_SUFFIXES = (".tif", ".tiff", ".TIF", ".TIFF")


class MovieError(ValueError):
    """A movie cannot be read; the message names the file and, where it applies, the frame."""


def _natural_key(path: Path) -> list[object]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def _compression_name(code: int) -> str:
    try:
        return f"{tifffile.COMPRESSION(code).name} (TIFF compression {code})"
    except ValueError:
        return f"TIFF compression {code} (unknown to tifffile)"


def _codec_problem(path: Path, page: Any) -> str | None:
    """Why the pages of ``path`` cannot be decoded here (None if they can)."""
    code = int(page.compression)
    if code == 1:
        return None
    try:
        tifffile.TIFF.DECOMPRESSORS[code]
    except KeyError as exc:
        reason = str(exc).strip("'\"")
        if "imagecodecs" in reason:
            return (
                f"{path}: frames are compressed with {_compression_name(code)}, which needs the "
                "imagecodecs package (pip install imagecodecs), a dependency of holofit; "
                "reinstall holofit or save the movie uncompressed"
            )
        return (
            f"{path}: frames are compressed with {_compression_name(code)}, which holofit "
            "cannot decode; save the movie uncompressed (or with LZW or deflate)"
        )
    return None


@dataclass(frozen=True)
class _Page:
    """A frame that is one TIFF page (directory) tifffile parsed."""

    page: Any  # tifffile.TiffPage | tifffile.TiffFrame


@dataclass(frozen=True)
class _Block:
    """A frame of an uncompressed contiguous stack, read by its byte offset."""

    offset: int


@dataclass(frozen=True)
class _Odd:
    """A page of the file that is not a frame like the first (another shape or pixel type)."""

    reason: str


@dataclass(frozen=True)
class _Lost:
    """A frame the file claims but that cannot be read."""

    reason: str
    #: the file's directory chain ends here: how many frames followed is unknown
    open_ended: bool = False


class Movie:
    """A hologram movie, read lazily frame by frame.

    Parameters
    ----------
    path : str or Path
        A (multi-page / OME) TIFF file or a folder of TIFF frames (sorted in natural order:
        ``frame2.tif`` before ``frame10.tif``); or, through :mod:`holofit.io.readers`, a video
        file, a folder of PNG frames, or an HDF5 file (``FILE.h5:DATASET`` names its dataset).

    Attributes
    ----------
    path : Path
        The source.
    frame_shape : tuple of int
        ``(rows, columns)`` of every frame.
    dtype : numpy.dtype
        Pixel type.
    problems : list of str
        What is wrong with the file as a whole (e.g. truncation: which frames are lost); empty
        for a sound file. Reading a lost frame raises :class:`MovieError`.
    notes : list of str
        What the TIFF library reported while reading (kept here instead of printed).

    Examples
    --------
    >>> with Movie("raw.tif") as movie:          # doctest: +SKIP
    ...     for index, frame in enumerate(movie):
    ...         ...
    """

    def __init__(self, path: str | Path) -> None:
        self.path, dataset = split_dataset(Path(path))
        self._tif: tifffile.TiffFile | None = None
        self._files: list[Path] = []
        self._reader: VideoReader | ImageFolderReader | Hdf5Reader | None = None
        self._sources: list[_Page | _Block | _Odd | _Lost] = []
        self.problems: list[str] = []
        self.notes: list[str] = []
        if not self.path.exists():
            raise MovieError(f"{self.path}: no such file or folder")
        if self.path.is_dir():
            self._files = sorted(
                (p for p in self.path.iterdir() if p.suffix in TIFF_SUFFIXES), key=_natural_key
            )
            if not self._files:
                images = sorted((p for p in self.path.iterdir()
                                 if p.suffix.lower() in IMAGE_SUFFIXES), key=_natural_key)
                if not images:
                    raise MovieError(
                        f"{self.path}: folder contains no TIFF or PNG frames; holofit reads "
                        f"{SUPPORTED}"
                    )
                self._open_reader(lambda: ImageFolderReader(images))
                return
            first = self._read_file(0)
            self.frame_shape = first.shape
            self.dtype = first.dtype
            self._n = len(self._files)
            return
        kind = sniff(self.path)
        suffix = self.path.suffix.lower()
        if kind == "video" or (not kind and suffix in VIDEO_SUFFIXES):
            self._open_reader(lambda: VideoReader(self.path))
        elif kind == "hdf5" or (not kind and suffix in HDF5_SUFFIXES):
            self._open_reader(lambda: Hdf5Reader(self.path, dataset))
        elif kind == "image":
            raise MovieError(
                f"{self.path}: a single image, not a movie: put the frames in a folder "
                f"(holofit reads {SUPPORTED})"
            )
        elif kind != "tiff" and suffix not in TIFF_SUFFIXES:
            raise MovieError(
                f"{self.path}: not a movie format holofit reads (file starts with "
                f"{_head(self.path)!r}); holofit reads {SUPPORTED}"
            )
        else:
            try:
                self._open_stack()
            except BaseException:
                self.close()
                raise

    def _open_reader(self, make: Any) -> None:
        """Open a non-TIFF movie; its first frame gives the frame shape and pixel type."""
        try:
            self._reader = make()
            self._n = self._reader.n
            first = self._read_other(0)
        except ReaderError as exc:
            self.close()
            raise MovieError(str(exc)) from None
        except BaseException:
            self.close()
            raise
        self.frame_shape = first.shape
        self.dtype = first.dtype

    def _read_other(self, index: int) -> NDArray:
        reader = self._reader
        if reader is None:
            raise MovieError(f"{self.path}: movie is closed")
        where = (f"{reader.files[index]}: frame {index}" if isinstance(reader, ImageFolderReader)
                 else f"{self.path}: frame {index}")
        try:
            img = reader.read(index)
        except Exception as exc:  # the readers raise many types for a bad frame
            raise MovieError(f"{where} cannot be read ({exc})") from None
        try:
            return grey_frame(img, where)
        except ReaderError as exc:
            raise MovieError(str(exc)) from None

    # -- stacks --------------------------------------------------------------------------
    def _open_stack(self) -> None:
        with capture_log("tifffile") as log:
            try:
                self._tif = tif = tifffile.TiffFile(self.path)
            except Exception as exc:  # tifffile raises many types for corrupt input
                raise MovieError(f"{self.path}: not a readable TIFF file ({exc})") from None
            try:
                s0: Any = tif.series[0]
                shape, axes = tuple(s0.shape), s0.axes
                first = s0.pages[0] if len(s0.pages) else tif.pages[0]
            except Exception as exc:
                # tifffile could not make one series of the pages (pages of different shapes
                # in a file that says they are alike, as Pillow writes them): read the pages
                # one by one, each a frame like the first, or an error row saying why not
                tif.pages.useframes = False  # full directories, not frames like a keyframe
                pages, _ = _readable_pages(tif.pages, log)
                if not pages:
                    raise MovieError(f"{self.path}: not a readable TIFF file ({exc})") from None
                s0, first = None, pages[0]
                shape, axes = tuple(first.shape), first.axes
            self._size = self.path.stat().st_size
            if len(shape) < 2 or first is None:
                raise MovieError(
                    f"{self.path}: TIFF series has shape {shape}, expected 2-D frames"
                )
            if "S" in axes:
                # every other leading axis (T, Z, C, I, Q: ImageJ and tifffile label plain
                # stacks variously) is read as frames, page after page
                planar = (" (3 or 4 grey frames written as one array without "
                          "photometric='minisblack' are stored as one planar RGB image)"
                          if axes.startswith("S") else "")
                raise MovieError(
                    f"{self.path}: colour images (axes {axes!r}, shape {shape}) are not "
                    f"supported; convert to one grey channel{planar}"
                )
            self.frame_shape = shape[-2:]
            self.dtype = np.dtype(first.dtype if s0 is None else s0.dtype)
            self._frame_bytes = int(np.prod(self.frame_shape)) * self.dtype.itemsize
            codec = _codec_problem(self.path, first)
            if codec is not None:
                raise MovieError(codec)
            n_series = int(np.prod(shape[:-2], dtype=int)) if len(shape) > 2 else 1
            declared = max(n_series, self._declared_frames())
            offset = s0.dataoffset if s0 is not None and _plain(first) else None
            if offset is not None and declared > 1:
                # one uncompressed block of frames (tifffile's own contiguous layout, ImageJ):
                # frame k lies at a known offset, whatever became of the directories
                self._sources = [
                    _Block(int(offset) + k * self._frame_bytes) for k in range(declared)
                ]
            else:
                self._pages_as_frames(tif, s0, n_series, declared, log)
        self._note(log)
        self._n = len(self._sources)
        lost = [k for k, src in enumerate(self._sources) if isinstance(src, _Lost)]
        lost += [k for k, src in enumerate(self._sources) if self._beyond_end(src)]
        if lost:
            last = self._sources[-1]
            which = _frame_list(sorted(set(lost)))
            if isinstance(last, _Lost) and last.open_ended:
                which += " and any frames after it (the file does not say how many it had)"
            else:
                which += f" of the {self._n} in the file"
            self.problems.append(
                f"{self.path}: the file is truncated ({self._size} bytes): {which} cannot be "
                "read"
            )

    def _pages_as_frames(self, tif: Any, s0: Any, n_series: int, declared: int,
                         log: list[str]) -> None:
        """Frames that are pages of their own (compressed, or one header per page)."""
        pages, broken = _readable_pages(s0.pages, log) if s0 is not None else ([], False)
        generic = not (tif.is_ome or tif.is_imagej)
        if len(pages) == n_series > 1 and not broken and not (generic and
                                                              len(tif.pages) > len(pages)):
            chain = pages  # the series is whole: its pages are the file's directories
        else:
            chain, broken = _readable_pages(tif.pages, log)  # every directory reached
        if not chain:
            raise MovieError(f"{self.path}: not a readable TIFF file (no readable directory)")

        def is_frame(page: Any) -> bool:
            return (
                page.shape is not None
                and tuple(s for s in page.shape if s != 1) == tuple(self.frame_shape)
                and np.dtype(page.dtype) == self.dtype
            )

        # every page of the file is a frame, except reduced-resolution copies: pages marked
        # so, and pages after the last frame at most half its size each way (thumbnails)
        full = [p for p in chain if not getattr(p, "is_reduced", False)]
        while len(full) > 1 and self._thumbnail(full[-1]):
            self.notes.append(f"page {full[-1].index} (shape {tuple(full[-1].shape)}) is "
                              "taken for a thumbnail, not a frame")
            full.pop()
        if len(pages) < n_series <= len(chain) and all(map(is_frame, chain)):
            pages = chain  # tifffile parsed fewer pages than the series has
        elif len(full) > len(pages) and (n_series == 1 or generic):
            # pages that tifffile grouped into several series (separately written pages,
            # a page of another shape among them, a header that tifffile could not apply):
            # every page of the file is a frame, in file order; one that is not like the
            # first is an error row. (An OME or ImageJ file's further series are other
            # positions or channels, not frames.)
            pages = full
        self._sources = [_Page(p) if is_frame(p) else _Odd(self._odd(p)) for p in pages]
        found = len(self._sources)
        if declared > found:
            self._sources += [
                _Lost(f"its header declares {declared} frames, the file holds the directories "
                      f"of {found}")
            ] * (declared - found)
        elif pages and pages[-1] is chain[-1]:
            if broken:
                self._sources.append(_Lost("its directory is corrupted", open_ended=True))
            else:
                self._check_chain_end(chain[-1])

    def _thumbnail(self, page: Any) -> bool:
        shape = tuple(s for s in (page.shape or ()) if s != 1)
        return len(shape) in (2, 3) and all(
            2 * s <= f for s, f in zip(shape[:2], self.frame_shape, strict=True))

    def _odd(self, page: Any) -> str:
        """Why a page is not a frame like the first."""
        shape = tuple(page.shape) if page.shape is not None else None
        if shape is not None and len(shape) > 2 and shape[-1] in (3, 4):
            return f"it is a colour image (shape {shape}); convert to one grey channel"
        if shape is not None and tuple(s for s in shape if s != 1) != tuple(self.frame_shape):
            return f"it has shape {shape}, the first frame has {tuple(self.frame_shape)}"
        return f"its pixels are {np.dtype(page.dtype)}, the first frame's {self.dtype}"

    def _declared_frames(self) -> int:
        """Frames the file's own header declares (0 if it declares none)."""
        tif = self._tif
        assert tif is not None
        found = 0
        if tif.is_imagej:
            images = (tif.imagej_metadata or {}).get("images")
            if images is not None:
                found = max(found, int(images))
        for meta in (tif.shaped_metadata or ())[:1]:  # the first series'
            shape = meta.get("shape") if isinstance(meta, dict) else None
            if shape and len(shape) > 2:
                lead = shape[:-3] if shape[-1] in (3, 4) and len(shape) > 3 else shape[:-2]
                found = max(found, int(np.prod(lead, dtype=int)))
        return found

    def _check_chain_end(self, last: Any) -> None:
        """A last directory that points to another one that cannot be read: a lost frame."""
        tif = self._tif
        assert tif is not None
        fmt = tif.tiff
        try:
            fh = tif.filehandle
            fh.seek(last.offset)
            (n_tags,) = struct.unpack(fmt.tagnoformat, fh.read(fmt.tagnosize))
            fh.seek(last.offset + fmt.tagnosize + n_tags * fmt.tagsize)
            (following,) = struct.unpack(fmt.offsetformat, fh.read(fmt.offsetsize))
        except (OSError, struct.error):
            return
        if following == 0:
            return
        if following < self._size:
            # a directory tifffile can read (another series: a thumbnail, say) is no loss
            with capture_log("tifffile"):
                every, _ = _readable_pages(tif.pages, [])
            if any(int(page.offset) == following for page in every):
                return
        what = (
            f"lies past the end of the file ({self._size} bytes)"
            if following >= self._size
            else "is corrupted"
        )
        self._sources.append(_Lost(f"its directory, at byte {following}, {what}", open_ended=True))

    def _beyond_end(self, source: _Page | _Block | _Odd | _Lost) -> bool:
        return self._data_end(source) > self._size

    def _data_end(self, source: _Page | _Block | _Odd | _Lost) -> int:
        if isinstance(source, _Block):
            return source.offset + self._frame_bytes
        if isinstance(source, _Page):
            page = source.page
            ends = [o + c for o, c in zip(page.dataoffsets, page.databytecounts, strict=False)]
            return max(ends, default=0)
        return 0

    def _note(self, messages: list[str]) -> None:
        for message in messages:
            text = f"tifffile: {message}"
            if text not in self.notes:
                self.notes.append(text)

    def _read_file(self, index: int) -> NDArray:
        file = self._files[index]
        with capture_log("tifffile") as log:
            try:
                img = tifffile.imread(file)
            except Exception as exc:
                raise MovieError(
                    f"{file}: frame {index} is not a readable TIFF ({exc})"
                    + "".join(f"; tifffile: {m}" for m in log)
                ) from None
        self._note(log)
        img = np.squeeze(img)
        if img.ndim != 2:
            raise MovieError(f"{file}: frame {index} has shape {img.shape}, expected 2-D")
        return img

    def _read_page(self, index: int) -> NDArray:
        source = self._sources[index]
        prefix = f"{self.path}: frame {index}"
        if isinstance(source, _Lost):
            later = "; any later frames are lost with it" if source.open_ended else ""
            raise MovieError(
                f"{prefix} cannot be read: the file is truncated: {source.reason}{later}"
            )
        if isinstance(source, _Odd):
            raise MovieError(f"{prefix} cannot be used: {source.reason}")
        end = self._data_end(source)
        if end > self._size:
            raise MovieError(
                f"{prefix} cannot be read: the file is truncated: its pixel data end at byte "
                f"{end}, the file at byte {self._size}"
            )
        if self._tif is None:
            raise MovieError(f"{self.path}: movie is closed")
        with capture_log("tifffile") as log:
            try:
                if isinstance(source, _Block):
                    dtype = self.dtype.newbyteorder(self._tif.byteorder)
                    img = self._tif.filehandle.read_array(
                        dtype, int(np.prod(self.frame_shape)), source.offset
                    ).astype(self.dtype, copy=False)
                else:
                    img = source.page.asarray()
            except Exception as exc:
                raise MovieError(
                    f"{prefix} cannot be read ({exc})" + "".join(f"; tifffile: {m}" for m in log)
                ) from None
        self._note(log)
        return np.squeeze(img).reshape(self.frame_shape)

    # -- public API ----------------------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    def __getitem__(self, index: int) -> NDArray:
        """Frame ``index`` as a 2-D array in the file's dtype."""
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"{self.path}: frame {index} out of range (movie has {n} frames)")
        index %= n
        if self._files:
            img = self._read_file(index)
            if img.shape != self.frame_shape:
                raise MovieError(
                    f"{self._files[index]}: frame {index} has shape {img.shape}, the first "
                    f"frame has {self.frame_shape}"
                )
            return img
        if self._reader is not None:
            img = self._read_other(index)
            if img.shape != tuple(self.frame_shape) or img.dtype != self.dtype:
                raise MovieError(
                    f"{self.frame_source(index)}: frame {index} has shape {img.shape} "
                    f"({img.dtype}), the first frame {tuple(self.frame_shape)} ({self.dtype})"
                )
            return img
        return self._read_page(index)

    def __iter__(self) -> Iterator[NDArray]:
        for i in range(len(self)):
            yield self[i]

    def frame_source(self, index: int) -> str:
        """Human-readable origin of frame ``index`` (for error messages and tables)."""
        if self._files:
            return str(self._files[index])
        if isinstance(self._reader, ImageFolderReader):
            return str(self._reader.files[index])
        return f"{self.path}[{index}]"

    def close(self) -> None:
        if self._tif is not None:
            self._tif.close()
            self._tif = None
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def __enter__(self) -> Movie:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"Movie({str(self.path)!r}, frames={len(self)}, shape={self.frame_shape}, "
            f"dtype={self.dtype})"
        )


def _plain(page: Any) -> bool:
    """Uncompressed pixels in one piece, readable by offset."""
    return (
        int(page.compression) == 1
        and len(page.dataoffsets) == 1
        and bool(page.is_contiguous)
        and page.fillorder == 1
        and page.predictor == 1
    )


def _readable_pages(pages: Any, log: list[str]) -> tuple[list[Any], bool]:
    """The pages of a tifffile page sequence up to the first that cannot be parsed.

    Returns the pages and whether one could not be parsed (a corrupted directory).
    """
    found: list[Any] = []
    try:
        for page in pages:
            if page is not None:
                found.append(page)
    except Exception as exc:  # tifffile raises many types for a corrupted directory
        message = f"directory {len(found)}: {exc}"
        if message not in log:
            log.append(message)
        return found, True
    return found, False


def _head(path: Path) -> bytes:
    try:
        with path.open("rb") as fh:
            return fh.read(8)
    except OSError:
        return b""


def _frame_list(frames: list[int]) -> str:
    """``[5, 6, 7, 9]`` -> ``"frames 5-7, 9"``."""
    runs: list[str] = []
    start = prev = frames[0]
    for f in [*frames[1:], None]:
        if f is not None and f == prev + 1:
            prev = f
            continue
        runs.append(str(start) if start == prev else f"{start}-{prev}")
        if f is not None:
            start = prev = f
    word = "frame" if len(frames) == 1 else "frames"
    return f"{word} {', '.join(runs)}"


def open_movie(path: str | Path) -> Movie:
    """Open a movie (see :class:`Movie`); an empty movie is an error."""
    movie = Movie(path)
    if len(movie) == 0:
        movie.close()
        raise MovieError(f"{path}: movie has no frames")
    return movie
