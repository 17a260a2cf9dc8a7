"""Optional FFTW backend (pyFFTW) for the DDA convolution, with plan wisdom cached on disk.

FFTW's measured plans run the convolution's batched 1-D transforms 1.4-1.9x faster than
numpy's pocketfft on the DDA grids, but measuring costs ~0.5 s per new grid. The wisdom is
therefore saved to ``$XDG_CACHE_HOME/holofit/fftw-wisdom-<version>.pkl`` (like numba's compiled
kernels, a one-time cost per machine and grid). Without pyFFTW, or with ``HOLOFIT_FFT=numpy``,
holofit uses numpy's FFT.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["available", "plans"]

try:  # pragma: no cover - depends on the installation
    import pyfftw

    _HAVE = True
except ImportError:  # pragma: no cover
    pyfftw = None
    _HAVE = False

_LOADED = False


def available() -> bool:
    """True if the FFTW backend is installed and not disabled."""
    return _HAVE and os.environ.get("HOLOFIT_FFT", "").lower() != "numpy"


def _wisdom_file() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    version = getattr(pyfftw, "__version__", "x")
    return base / "holofit" / f"fftw-wisdom-{version}.pkl"


def _load_wisdom() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    with contextlib.suppress(Exception):
        with _wisdom_file().open("rb") as fh:
            pyfftw.import_wisdom(pickle.load(fh))


def _save_wisdom() -> None:
    path = _wisdom_file()
    with contextlib.suppress(Exception):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".part")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(pyfftw.export_wisdom(), fh)
        os.replace(tmp, path)


@dataclass
class Plans:
    """In-place forward/backward plans along z, y, x on three aligned buffers."""

    buffers: tuple[Any, Any, Any]
    forward: tuple[Any, Any, Any]
    backward: tuple[Any, Any, Any]


def plans(shape1: tuple[int, ...], shape2: tuple[int, ...], shape3: tuple[int, ...],
          dtype: np.dtype) -> Plans | None:
    """Plans for the pruned convolution (None if FFTW is not available)."""
    if not available():
        return None
    _load_wisdom()
    bufs = tuple(pyfftw.empty_aligned(s, dtype=dtype) for s in (shape1, shape2, shape3))
    for b in bufs:
        b[...] = 0
    flags = ("FFTW_MEASURE",)
    kw: dict[str, Any] = {"threads": 1, "flags": flags}
    before = pyfftw.export_wisdom()
    fwd = tuple(
        pyfftw.FFTW(b, b, axes=(axis,), **kw) for b, axis in zip(bufs, (1, 2, 3), strict=True)
    )
    bwd = tuple(
        pyfftw.FFTW(b, b, axes=(axis,), direction="FFTW_BACKWARD", normalise_idft=False, **kw)
        for b, axis in zip(bufs, (1, 2, 3), strict=True)
    )
    if pyfftw.export_wisdom() != before:
        _save_wisdom()
    return Plans(bufs, fwd, bwd)
