"""Writing TIFF stacks frame by frame, atomically."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from holofit.io.atomic import publish

__all__ = ["TiffStackWriter", "write_tiff_stack"]


class TiffStackWriter:
    """Stream frames into a multi-page TIFF that appears under its name only when complete.

    Frames go to a temporary file beside the target; :meth:`close` renames it, and leaving the
    ``with`` block through an exception deletes it. Memory use is one frame.

    Parameters
    ----------
    path : str or Path
        Target file.
    metadata : dict, optional
        Stored as the TIFF ImageDescription (JSON) of the first page.
    """

    def __init__(self, path: str | Path, metadata: dict[str, Any] | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent
        )
        os.close(fd)
        self._tmp = Path(tmp)
        self._writer = tifffile.TiffWriter(self._tmp, bigtiff=True)
        self._metadata = metadata or {}
        self._shape: tuple[int, ...] | None = None
        self._dtype: np.dtype | None = None
        self.frames_written = 0

    def write(self, frame: NDArray) -> None:
        """Append one 2-D frame (all frames must share shape and dtype)."""
        frame = np.asarray(frame)
        if frame.ndim != 2:
            raise ValueError(f"{self.path}: frames must be 2-D, got shape {frame.shape}")
        if self._shape is None:
            self._shape, self._dtype = frame.shape, frame.dtype
        elif frame.shape != self._shape or frame.dtype != self._dtype:
            raise ValueError(
                f"{self.path}: frame {self.frames_written} has shape {frame.shape}/{frame.dtype}, "
                f"earlier frames {self._shape}/{self._dtype}"
            )
        self._writer.write(
            frame,
            contiguous=True,
            metadata=self._metadata if self.frames_written == 0 else None,
        )
        self.frames_written += 1

    def close(self) -> None:
        """Finish the file and move it into place."""
        self._writer.close()
        publish(self._tmp, self.path)

    def abort(self) -> None:
        """Discard everything written."""
        with contextlib.suppress(Exception):
            self._writer.close()
        with contextlib.suppress(FileNotFoundError):
            self._tmp.unlink()

    def __enter__(self) -> TiffStackWriter:
        return self

    def __exit__(self, exc_type: object, *rest: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_tiff_stack(
    path: str | Path, frames: Iterable[NDArray], metadata: dict[str, Any] | None = None
) -> int:
    """Write ``frames`` to a multi-page TIFF atomically; returns the number of frames."""
    with TiffStackWriter(path, metadata) as writer:
        for frame in frames:
            writer.write(frame)
        return writer.frames_written
