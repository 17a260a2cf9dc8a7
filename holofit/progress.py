"""Progress bars for long runs (frames done, rate, time left), quiet when not on a terminal."""

from __future__ import annotations

import sys
from typing import Any

from tqdm import tqdm

__all__ = ["progress_bar"]


def progress_bar(total: int, desc: str, unit: str = "frame", **kwargs: Any) -> tqdm:
    """A tqdm bar on stderr; disabled automatically when stderr is not a terminal.

    Parameters
    ----------
    total : int
        Number of items.
    desc : str
        Label (the stage name).
    unit : str
        What an item is.
    """
    kwargs.setdefault("disable", None)  # None: off when not a TTY
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        dynamic_ncols=True,
        smoothing=0.1,
        **kwargs,
    )
