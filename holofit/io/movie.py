"""Lazy, frame-by-frame reading of hologram movies.

A movie is a multi-page TIFF (plain, ImageJ or OME-TIFF stack) or a folder of single-frame
TIFF files. Frames are read one at a time, so a 2000-frame megapixel movie never sits in memory
whole. 8- and 16-bit (and float) pixels are returned unchanged in their own dtype.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import NDArray

__all__ = ["Movie", "MovieError", "open_movie"]

TIFF_SUFFIXES = (".tif", ".tiff", ".TIF", ".TIFF")


class MovieError(ValueError):
    """A movie cannot be read; the message names the file and, where it applies, the frame."""


def _natural_key(path: Path) -> list[object]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


class Movie:
    """A hologram movie, read lazily frame by frame.

    Parameters
    ----------
    path : str or Path
        A (multi-page / OME) TIFF file or a folder of TIFF frames (sorted in natural order:
        ``frame2.tif`` before ``frame10.tif``).

    Attributes
    ----------
    path : Path
        The source.
    frame_shape : tuple of int
        ``(rows, columns)`` of every frame.
    dtype : numpy.dtype
        Pixel type.

    Examples
    --------
    >>> with Movie("raw.tif") as movie:          # doctest: +SKIP
    ...     for index, frame in enumerate(movie):
    ...         ...
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._tif: tifffile.TiffFile | None = None
        self._files: list[Path] = []
        if not self.path.exists():
            raise MovieError(f"{self.path}: no such file or folder")
        if self.path.is_dir():
            self._files = sorted(
                (p for p in self.path.iterdir() if p.suffix in TIFF_SUFFIXES), key=_natural_key
            )
            if not self._files:
                raise MovieError(f"{self.path}: folder contains no TIFF frames (.tif/.tiff)")
            first = self._read_file(0)
            self.frame_shape = first.shape
            self.dtype = first.dtype
            self._n = len(self._files)
        else:
            self._open_stack()

    # -- stacks --------------------------------------------------------------------------
    def _open_stack(self) -> None:
        try:
            self._tif = tifffile.TiffFile(self.path)
            series = self._tif.series[0]
            shape, axes = tuple(series.shape), series.axes
        except Exception as exc:  # tifffile raises many types for corrupt input
            self.close()
            raise MovieError(f"{self.path}: not a readable TIFF file ({exc})") from None
        if len(shape) < 2:
            self.close()
            raise MovieError(f"{self.path}: TIFF series has shape {shape}, expected 2-D frames")
        if axes.endswith("S"):
            # every other leading axis (T, Z, C, I, Q: ImageJ and tifffile label plain stacks
            # variously) is read as frames, page after page
            self.close()
            raise MovieError(
                f"{self.path}: colour images (axes {axes!r}, shape {shape}) are not supported; "
                "convert to one grey channel"
            )
        self.frame_shape = shape[-2:]
        self.dtype = np.dtype(series.dtype)
        self._pages = series.pages
        self._n = int(np.prod(shape[:-2], dtype=int)) if len(shape) > 2 else 1
        declared = (self._tif.imagej_metadata or {}).get("images") if self._tif.is_imagej else None
        if declared is not None and int(declared) > self._n:
            self.close()
            raise MovieError(
                f"{self.path}: ImageJ header declares {declared} images but only {self._n} can "
                "be read; the file is truncated"
            )
        if len(self._pages) != self._n:
            self.close()
            raise MovieError(
                f"{self.path}: series of shape {shape} has {len(self._pages)} pages, expected "
                f"{self._n}; the file may be truncated"
            )

    def _read_file(self, index: int) -> NDArray:
        file = self._files[index]
        try:
            img = tifffile.imread(file)
        except Exception as exc:
            raise MovieError(f"{file}: frame {index} is not a readable TIFF ({exc})") from None
        img = np.squeeze(img)
        if img.ndim != 2:
            raise MovieError(f"{file}: frame {index} has shape {img.shape}, expected 2-D")
        return img

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
        if self._tif is None:
            raise MovieError(f"{self.path}: movie is closed")
        try:
            img = self._pages[index].asarray()
        except Exception as exc:
            raise MovieError(
                f"{self.path}: frame {index} cannot be read ({exc}); the file may be truncated"
            ) from None
        return np.squeeze(img).reshape(self.frame_shape)

    def __iter__(self) -> Iterator[NDArray]:
        for i in range(len(self)):
            yield self[i]

    def frame_source(self, index: int) -> str:
        """Human-readable origin of frame ``index`` (for error messages and tables)."""
        if self._files:
            return str(self._files[index])
        return f"{self.path}[{index}]"

    def close(self) -> None:
        if self._tif is not None:
            self._tif.close()
            self._tif = None

    def __enter__(self) -> Movie:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"Movie({str(self.path)!r}, frames={len(self)}, shape={self.frame_shape}, "
            f"dtype={self.dtype})"
        )


def open_movie(path: str | Path) -> Movie:
    """Open a movie (see :class:`Movie`); an empty movie is an error."""
    movie = Movie(path)
    if len(movie) == 0:
        movie.close()
        raise MovieError(f"{path}: movie has no frames")
    return movie
