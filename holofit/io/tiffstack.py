"""Writing TIFF stacks frame by frame, atomically."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from holofit.io.atomic import create_temporary, publish

__all__ = ["TiffStackWriter", "write_tiff_stack"]


class TiffStackWriter:
    """Stream frames into a multi-page TIFF that appears under its name only when complete.

    Frames go to a temporary file beside the target; :meth:`close` renames it, and leaving the
    ``with`` block through an exception deletes it; a temporary left by a killed writer is
    removed by the next writer of the same file (:func:`holofit.io.atomic.create_temporary`).
    Memory use is one frame.

    Parameters
    ----------
    path : str or Path
        Target file.
    metadata : dict, optional
        Stored as the TIFF ImageDescription (JSON) of the first page.
    """

    def __init__(self, path: str | Path, metadata: dict[str, Any] | None = None) -> None:
        self.path = Path(path)
        self._tmp, self._lock_fd = create_temporary(self.path)
        try:
            self._writer = tifffile.TiffWriter(self._tmp, bigtiff=True)
        except BaseException:
            self._release()
            raise
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
        try:
            self._writer.close()
            publish(self._tmp, self.path)
        except BaseException:
            self._release()
            raise
        self._close_lock()

    def abort(self) -> None:
        """Discard everything written."""
        with contextlib.suppress(Exception):
            self._writer.close()
        self._release()

    def _release(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self._tmp.unlink()
        self._close_lock()

    def _close_lock(self) -> None:
        if self._lock_fd >= 0:
            os.close(self._lock_fd)
            self._lock_fd = -1

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
