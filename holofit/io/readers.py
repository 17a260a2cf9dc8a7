"""Movies that are not TIFF: video files, folders of PNG frames, HDF5 datasets.

Read through two optional, well-kept packages (``pip install 'holofit[movies]'``): imageio
(with its PyAV plugin, the FFmpeg libraries packaged for Python) for video files and image
folders, and h5py for HDF5. A movie in one of these formats without its package installed is a
one-line :class:`~holofit.io.movie.MovieError` saying which package to install.

Pixels are handled as for TIFF (:mod:`holofit.io.movie`): 8- and 16-bit grey frames are returned
in their own dtype; a colour frame is an error, except one whose three channels are equal (grey
video codecs often decode to RGB), which is its grey channel.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "HDF5_SUFFIXES",
    "IMAGE_SUFFIXES",
    "SUPPORTED",
    "VIDEO_SUFFIXES",
    "Hdf5Reader",
    "ImageFolderReader",
    "ReaderError",
    "VideoReader",
    "grey_frame",
    "sniff",
]

VIDEO_SUFFIXES = (".avi", ".mp4", ".mov", ".mkv")
IMAGE_SUFFIXES = (".png", ".bmp")
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")

#: what holofit reads, for messages
SUPPORTED = (
    "multi-page TIFF / OME-TIFF (.tif, .tiff), a folder of TIFF or PNG frames, video "
    f"({', '.join(VIDEO_SUFFIXES)}) and HDF5 ({', '.join(HDF5_SUFFIXES)}; FILE.h5:DATASET "
    "picks a dataset)"
)

#: optional package -> what it is for (``pip install 'holofit[movies]'`` installs all)
_PACKAGES = {"imageio": "imageio", "av": "av", "h5py": "h5py"}


class ReaderError(ValueError):
    """A movie of these formats cannot be read (the message names the file)."""


def _need(module: str, path: Path, what: str) -> ModuleType:
    """Import an optional package, or say which one to install."""
    try:
        return importlib.import_module(module)
    except ImportError:
        package = _PACKAGES[module.split(".")[0]]
        raise ReaderError(
            f"{path}: reading {what} needs the optional package {package!r}: "
            f"pip install 'holofit[movies]' (or pip install {package})"
        ) from None


def sniff(path: Path) -> str:
    """The format of a file by its first bytes: ``tiff``, ``video``, ``hdf5``, ``image`` or ''."""
    try:
        with path.open("rb") as fh:
            head = fh.read(12)
    except OSError:
        return ""
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return "tiff"
    if head[:8] == b"\x89HDF\r\n\x1a\n":
        return "hdf5"
    avi = head[:4] == b"RIFF" and head[8:12] == b"AVI "
    if avi or head[4:8] == b"ftyp" or head[:4] == b"\x1aE\xdf\xa3":  # AVI, MP4/MOV, MKV
        return "video"
    if head[:8] == b"\x89PNG\r\n\x1a\n" or head[:2] == b"BM":
        return "image"
    return ""


def grey_frame(img: NDArray, where: str) -> NDArray:
    """A frame as one grey 2-D array; colour is an error unless its channels are equal.

    Parameters
    ----------
    img : ndarray
        ``(rows, cols)``, or ``(rows, cols, 3 or 4)`` (RGB, RGBA).
    where : str
        The file and frame, for the message.
    """
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        rgb = img[..., :3]
        if np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2]):
            return np.ascontiguousarray(rgb[..., 0])
        raise ReaderError(
            f"{where}: colour images (shape {img.shape}) are not supported; convert to one "
            "grey channel"
        )
    img = np.squeeze(img)
    if img.ndim != 2:
        raise ReaderError(f"{where}: frame has shape {img.shape}, expected 2-D")
    return img


class VideoReader:
    """A video file (AVI, MP4, ...) read frame by frame through imageio's PyAV plugin.

    Grey video (``gray``, ``gray16le``, ... pixel formats) is decoded as grey in its own bit
    depth; colour video as RGB (an error unless its channels are equal).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        iio = _need("imageio.v3", path, "video files")
        _need("av", path, "video files")
        try:
            self._file = iio.imopen(path, "r", plugin="pyav")
            meta = self._file.metadata()
            props = self._file.properties(index=...)
        except Exception as exc:  # imageio / FFmpeg raise many types for a bad file
            raise ReaderError(f"{path}: not a readable video file ({exc})") from None
        source_format = str(meta.get("video_format", ""))
        if source_format.startswith("gray"):
            self._format = "gray" if source_format in ("gray", "gray8") else "gray16le"
        else:
            self._format = "rgb24"
        self.n = int(props.n_images or 0)
        if self.n <= 0:  # the container does not say: count by decoding
            self.n = sum(1 for _ in self._file.iter(format=self._format))

    def read(self, index: int) -> NDArray:
        return np.asarray(self._file.read(index=index, format=self._format))

    def close(self) -> None:
        self._file.close()


class ImageFolderReader:
    """A folder of single-frame image files (PNG, BMP), read through imageio."""

    def __init__(self, files: list[Path]) -> None:
        self.files = files
        self.n = len(files)
        self._iio = _need("imageio.v3", files[0].parent, "PNG frames")

    def read(self, index: int) -> NDArray:
        return np.asarray(self._iio.imread(self.files[index]))

    def close(self) -> None:
        pass


class Hdf5Reader:
    """A dataset of an HDF5 file: frames along its first axis (a 2-D dataset is one frame).

    Parameters
    ----------
    path : Path
        The file.
    dataset : str, optional
        The dataset's name; by default the file's only dataset of 2 or more dimensions.
    """

    def __init__(self, path: Path, dataset: str | None = None) -> None:
        self.path = path
        h5py = _need("h5py", path, "HDF5 files")
        try:
            self._file = h5py.File(path, "r")
        except Exception as exc:
            raise ReaderError(f"{path}: not a readable HDF5 file ({exc})") from None
        try:
            self._ds = self._dataset(h5py, dataset)
        except BaseException:
            self._file.close()
            raise
        self.dataset = self._ds.name
        self.n = 1 if self._ds.ndim == 2 else int(self._ds.shape[0])

    def _dataset(self, h5py: Any, name: str | None) -> Any:
        found: list[Any] = []
        self._file.visititems(lambda _, obj: found.append(obj) if isinstance(obj, h5py.Dataset)
                              and obj.ndim >= 2 and obj.dtype.kind in "uif" else None)
        names = ", ".join(d.name for d in found) or "none"
        if name is not None:
            obj = self._file.get(name)
            if not isinstance(obj, h5py.Dataset):
                raise ReaderError(f"{self.path}: no dataset {name!r} (image datasets: {names})")
            return obj
        if len(found) != 1:
            what = "no image dataset" if not found else f"several image datasets ({names})"
            raise ReaderError(f"{self.path}: {what}; name the movie's as FILE.h5:DATASET")
        return found[0]

    def read(self, index: int) -> NDArray:
        return np.asarray(self._ds[()] if self._ds.ndim == 2 else self._ds[index])

    def close(self) -> None:
        self._file.close()


def split_dataset(path: Path) -> tuple[Path, str | None]:
    """``movie.h5:/frames`` -> (``movie.h5``, ``/frames``); other paths unchanged."""
    match = re.fullmatch(r"(.*\.(?:h5|hdf5|hdf)):(.+)", str(path), re.IGNORECASE)
    if match and not path.exists() and Path(match.group(1)).is_file():
        return Path(match.group(1)), match.group(2)
    return path, None
