"""T-matrix files: an ``.npz`` with the matrix blocks and its JSON provenance, refused for any
other model, lattice, wavelength, medium or settings.

The provenance (:func:`describe`) records what determines the matrix: the model (kind and
parameters), the dipole size, the vacuum wavelength, the medium index, the polarisability
prescription, the filling rule, a fingerprint of the lattice (positions, fractions, indices),
and the build's own numbers (order, truncation estimate, solver tolerance, solves, measured
validation error, holofit version). :func:`check_compatible` compares a file's provenance with
what a run needs and raises :class:`TMatrixMismatch` naming the file and the first field that
differs. A T-matrix built with a looser solver tolerance than the run's settings ask for is
refused too. The polarisation is not part of it: one T-matrix serves every polarisation.

:func:`load_tmatrix` keeps loaded matrices in a module-level cache keyed by the resolved path,
modification time and size, so a worker process reads a file once.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

import holofit
from holofit.cache import LRUCache
from holofit.dda.lattice import Lattice
from holofit.dda.settings import DDASettings
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.tmatrix import TMatrix

__all__ = [
    "FORMAT",
    "TMatrixMismatch",
    "check_compatible",
    "clear_cache",
    "describe",
    "lattice_fingerprint",
    "load_tmatrix",
    "save_tmatrix",
]

FORMAT = "holofit-tmatrix/1"
#: model parameters identified by the lattice fingerprint rather than by value
_BY_FINGERPRINT = {"path"}
#: loaded T-matrices kept per process (a worker serves one particle's, a study a few)
_CACHE: LRUCache[tuple, TMatrix] = LRUCache(4)


class TMatrixMismatch(ValueError):
    """A T-matrix file does not belong to the model, optics or settings of this run."""


def _jsonable(value: Any) -> Any:
    if isinstance(value, complex):
        return [value.real, value.imag]
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def lattice_fingerprint(lattice: Lattice) -> str:
    """SHA-256 of the lattice's spacing, box, origin, occupied voxels, fractions and indices."""
    h = hashlib.sha256()
    h.update(np.array([lattice.d], dtype=np.float64).tobytes())
    h.update(np.asarray(lattice.shape, dtype=np.int64).tobytes())
    h.update(np.round(np.asarray(lattice.origin, dtype=float), 12).tobytes())
    h.update(np.ascontiguousarray(lattice.ijk, dtype=np.int64).tobytes())
    h.update(np.round(lattice.fractions, 13).tobytes())
    h.update(np.asarray(lattice.indices, dtype=complex).tobytes())
    return h.hexdigest()


def describe(model: ParticleModel, dipole_size_um: float, optics: Optics,
             settings: DDASettings, lattice: Lattice) -> dict[str, Any]:
    """The provenance fields that decide whether a T-matrix fits a run."""
    return {
        "format": FORMAT,
        "model": {"kind": model.kind,
                  "parameters": {k: _jsonable(v) for k, v in model.parameters().items()}},
        "dipole_size_um": float(dipole_size_um),
        "wavelength_um": float(optics.wavelength_um),
        "n_medium": float(optics.n_medium),
        "polarizability": settings.polarizability,
        "filling": settings.filling,
        "lattice_fingerprint": lattice_fingerprint(lattice),
        "holofit_version": holofit.__version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        try:
            return bool(np.isclose(float(a), float(b), rtol=1e-12, atol=0.0))
        except (TypeError, ValueError):
            return False
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def check_compatible(provenance: dict[str, Any], expected: dict[str, Any], source: str,
                     tolerance: float | None = None) -> None:
    """Raise :class:`TMatrixMismatch` unless ``provenance`` (of the file ``source``) was made
    for the model, lattice, optics and settings described by ``expected`` (:func:`describe`),
    with a solver tolerance no looser than ``tolerance``."""
    if provenance.get("format") != FORMAT:
        raise TMatrixMismatch(f"{source}: not a holofit T-matrix file (format "
                              f"{provenance.get('format')!r}, expected {FORMAT!r})")

    def fail(name: str, got: Any, want: Any) -> None:
        raise TMatrixMismatch(
            f"{source}: T-matrix was built for {name} = {got!r}, but this run has {want!r}; "
            "rebuild it (holofit builds and saves one when none fits)"
        )

    got_model, want_model = provenance["model"], expected["model"]
    if got_model["kind"] != want_model["kind"]:
        fail("model", got_model["kind"], want_model["kind"])
    for name, want in want_model["parameters"].items():
        if name in _BY_FINGERPRINT:
            continue
        got = got_model["parameters"].get(name)
        if not _same(got, want):
            fail(f"model parameter {name}", got, want)
    for name in ("dipole_size_um", "wavelength_um", "n_medium", "polarizability", "filling",
                 "lattice_fingerprint"):
        if not _same(provenance.get(name), expected[name]):
            fail(name, provenance.get(name), expected[name])
    built_tol = provenance.get("tolerance")
    if tolerance is not None and built_tol is not None and built_tol > tolerance * (1 + 1e-9):
        raise TMatrixMismatch(
            f"{source}: T-matrix was built with solver tolerance {built_tol:g}, looser than this "
            f"run's tolerance {tolerance:g}; rebuild it"
        )


def save_tmatrix(tmatrix: TMatrix, path: str | Path) -> Path:
    """Write ``tmatrix`` to ``path`` (``.npz``; written atomically) and a readable copy of its
    provenance beside it (``<path>.json``, not read back). Returns the path."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_suffix(path.suffix + ".npz") if path.suffix else path.with_suffix(".npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(tmatrix.provenance, indent=2, sort_keys=True, default=_jsonable)
    arrays: dict[str, np.ndarray | np.generic] = {
        "order": np.int64(tmatrix.order), "k": np.float64(tmatrix.k),
        "radius_um": np.float64(tmatrix.radius_um), "modulus": np.int64(tmatrix.modulus),
        "provenance": np.array(text),
        **{f"block_{i}": b for i, b in enumerate(tmatrix.blocks)},
    }
    tmp = path.with_name(path.name + ".part")
    with tmp.open("wb") as fh:
        # numpy's stub lets a **dict fill savez's keyword allow_pickle (a bool): a typing gap
        np.savez(fh, **arrays)  # type: ignore[arg-type]
    os.replace(tmp, path)
    path.with_name(path.name + ".json").write_text(text + "\n")
    return path


def load_tmatrix(path: str | Path) -> TMatrix:
    """Read a T-matrix file (cached per path, modification time and size)."""
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: T-matrix file not found") from None
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    tm = _CACHE.get(key)
    if tm is not None:
        return tm
    try:
        with np.load(path, allow_pickle=False) as data:
            provenance = json.loads(str(data["provenance"]))
            modulus = int(data["modulus"])
            blocks = [np.ascontiguousarray(data[f"block_{i}"]) for i in range(modulus)]
            tm = TMatrix(int(data["order"]), float(data["k"]), float(data["radius_um"]),
                         modulus, blocks, provenance)
    except (KeyError, ValueError, OSError) as exc:
        raise TMatrixMismatch(f"{path}: not a readable holofit T-matrix file ({exc})") from None
    if provenance.get("format") != FORMAT:
        raise TMatrixMismatch(f"{path}: not a holofit T-matrix file (format "
                              f"{provenance.get('format')!r}, expected {FORMAT!r})")
    return _CACHE.put(key, tm)


def clear_cache() -> None:
    """Forget every loaded T-matrix."""
    _CACHE.clear()
