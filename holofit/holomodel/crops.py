"""What the model kit needs of a set of crops: a protocol, so that the kit reads no stage's
files (the crop folder's reader is :class:`holofit.tables.cropset.CropSet`)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

__all__ = ["CropSource"]


class CropSource(Protocol):
    """Crops by key (a frame number, or a ``(particle, frame)`` tuple), with their table
    rows."""

    def row(self, frame: Any) -> dict[str, Any]:
        """The crop-table row of ``frame`` (``corner_row``, ``corner_col``, ``status``, ...)."""
        ...

    def crop(self, frame: Any) -> NDArray[np.float32]:
        """The crop of ``frame`` (NaN marks pixels to leave out)."""
        ...
