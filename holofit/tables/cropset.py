"""Reading the output of ``holofit crop``: the crops, their table, and the instrument.

A crop folder holds

- ``crops.tif``: float32 normalised crops (background ~1), one page per row of the table, in
  the table's order; NaN marks pixels to leave out (outside the frame, saturated);
- ``crops.csv``: one row per frame with ``frame``, ``status`` (``ok``, ``edge``,
  ``no_particle``, ``error``), ``message``, the hologram centre ``x_px``, ``y_px`` (full-frame
  pixels, x = column), and ``corner_row``, ``corner_col`` (full-frame index of the crop's
  pixel ``[0, 0]``);
- ``crops.csv.json``: its sidecar, whose ``instrument`` entry (top level, or under
  ``config`` or ``extra``) describes the microscope.

Crops are read lazily, one page at a time.

Every row is keyed by ``(particle, frame)`` (:attr:`CropSet.key_columns`,
:attr:`CropSet.keys`): a track is the group of keys of one ``particle``. A table without the
``particle`` column (one track) is track 0. :meth:`CropSet.row` and :meth:`CropSet.crop` take a
key; a frame number alone names the frame of a folder of one track.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.config import ConfigError, Instrument, instrument_from_dict
from holofit.io.movie import Movie, MovieError
from holofit.io.tables import sidecar_path
from holofit.tables.crop import REQUIRED_CROP_COLUMNS

__all__ = [
    "PARTICLE_KEY",
    "CropSet",
    "CropSetError",
    "open_crops",
]

#: the key columns of every stage table
PARTICLE_KEY: tuple[str, ...] = ("particle", "frame")


class CropSetError(ValueError):
    """A crop folder is incomplete or inconsistent; the message names the file."""


def _find_instrument(doc: Mapping[str, Any]) -> Mapping[str, Any] | None:
    for where in (doc, doc.get("config"), doc.get("extra")):
        if isinstance(where, Mapping) and isinstance(where.get("instrument"), Mapping):
            return where["instrument"]
    return None


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class CropSet:
    """The crops of one crop folder, read lazily.

    Attributes
    ----------
    directory : Path
        The folder.
    table : pandas.DataFrame
        The crop table (one row per page of ``crops.tif``).
    instrument : Instrument or None
        From the table's sidecar, if it has one.
    crop_shape : tuple of int
        ``(rows, cols)`` of every crop.
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.stack_path = self.directory / "crops.tif"
        self.table_path = self.directory / "crops.csv"
        for p in (self.stack_path, self.table_path):
            if not p.exists():
                raise CropSetError(f"{p}: not found (is {self.directory} a crop folder?)")
        try:
            self.table = pd.read_csv(self.table_path)
        except (ValueError, pd.errors.ParserError) as exc:
            raise CropSetError(f"{self.table_path}: not a readable CSV table ({exc})") from None
        missing = [c for c in REQUIRED_CROP_COLUMNS if c not in self.table.columns]
        if missing:
            raise CropSetError(f"{self.table_path}: missing column(s) {', '.join(missing)}")
        if "particle" not in self.table.columns:
            self.table.insert(0, "particle", 0)
        dup = self.table.duplicated(["particle", "frame"])
        if dup.any():
            first = self.table[dup].iloc[0]
            raise CropSetError(
                f"{self.table_path}: repeated (particle, frame) rows (particle "
                f"{int(first['particle'])}, frame {int(first['frame'])}): a track holds one "
                "hologram per frame")
        frames = self.table["frame"].to_numpy()
        #: several tracks: rows keyed by (particle, frame)
        self.multi = int(self.table["particle"].nunique()) > 1
        if "message" not in self.table.columns:
            self.table["message"] = ""
        self.table["message"] = [
            "" if (isinstance(m, float) and math.isnan(m)) else str(m)
            for m in self.table["message"]
        ]
        try:
            self._movie = Movie(self.stack_path)
        except MovieError as exc:
            raise CropSetError(str(exc)) from None
        pages = (self.table["page"].to_numpy(dtype=int) if "page" in self.table.columns
                 else np.arange(len(self.table)))
        if ("page" not in self.table.columns and len(self._movie) != len(self.table)) or (
                len(pages) and (pages.min() < 0 or pages.max() >= len(self._movie))):
            n_pages = len(self._movie)
            self._movie.close()
            raise CropSetError(
                f"{self.stack_path}: has {n_pages} crop(s) but {self.table_path} has "
                f"{len(self.table)} row(s)"
            )
        self.crop_shape: tuple[int, int] = tuple(self._movie.frame_shape)  # type: ignore[assignment]
        particles = self.table["particle"].to_numpy()
        keys = [(int(p), int(f)) for p, f in zip(particles, frames, strict=True)]
        #: key -> page of the stack; key -> row of the table
        self._position: dict[Any, int] = {k: int(i) for k, i in zip(keys, pages, strict=True)}
        self._row_of: dict[Any, int] = {k: i for i, k in enumerate(keys)}
        self.sidecar: dict[str, Any] = {}
        side = sidecar_path(self.table_path)
        if side.exists():
            try:
                self.sidecar = json.loads(side.read_text())
            except ValueError as exc:
                raise CropSetError(f"{side}: not valid JSON ({exc})") from None
        inst = _find_instrument(self.sidecar)
        self.instrument: Instrument | None = None
        if inst is not None:
            try:
                self.instrument = instrument_from_dict(inst, str(side))
            except ConfigError as exc:
                raise CropSetError(str(exc)) from None

    @property
    def frames(self) -> list[int]:
        """Frame numbers, in table order (with several tracks, a frame once per track)."""
        return [int(f) for f in self.table["frame"]]

    @property
    def key_columns(self) -> tuple[str, ...]:
        """What names a row: ``("particle", "frame")``."""
        return PARTICLE_KEY

    @property
    def keys(self) -> list[tuple[int, int]]:
        """Every row's ``(particle, frame)`` key, in table order."""
        return list(self._position)

    @property
    def particles(self) -> list[int]:
        """The track ids."""
        return sorted(int(p) for p in self.table["particle"].unique())

    def __len__(self) -> int:
        return len(self.table)

    def row(self, frame: Any) -> dict[str, Any]:
        """The crop-table row of ``frame`` (a key: :attr:`keys`) as plain Python values."""
        rec = self.table.iloc[self._index(frame)].to_dict()
        return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in rec.items()}

    def crop(self, frame: Any) -> NDArray[np.float32]:
        """The crop of ``frame`` (a key: :attr:`keys`; float32, NaN = leave out)."""
        try:
            return np.asarray(self._movie[self._position[self._key(frame)]], dtype=np.float32)
        except MovieError as exc:
            raise CropSetError(f"{exc} (the crop of movie frame {frame})") from None

    def key(self, frame: Any) -> tuple[int, int]:
        """The ``(particle, frame)`` key of ``frame`` (a key, or a frame number of a folder of
        one track)."""
        return self._key(frame)

    def _key(self, frame: Any) -> tuple[int, int]:
        if isinstance(frame, tuple) and len(frame) == 2:
            key = (int(frame[0]), int(frame[1]))
        elif self.multi:
            raise CropSetError(f"{self.table_path}: holds several tracks; a row is named "
                               f"by (particle, frame), not {frame!r}")
        else:
            f = int(frame[-1]) if isinstance(frame, tuple) else int(frame)
            key = (self.particles[0] if self.particles else 0, f)
        if key not in self._position:
            what = (f"particle {key[0]} in frame {key[1]}" if self.multi
                    else f"frame {key[1]}")
            raise CropSetError(f"{self.table_path}: no {what}")
        return key

    def _index(self, frame: Any) -> int:
        return self._row_of[self._key(frame)]

    def fingerprint(self) -> dict[str, Any]:
        """Identity of the inputs: checksum of the table, size of the stack."""
        return {
            "crops_csv_sha256": _sha256(self.table_path),
            "crops_tif_bytes": self.stack_path.stat().st_size,
        }

    def close(self) -> None:
        self._movie.close()

    def __enter__(self) -> CropSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: instrument values that must agree between the crops and a replacement instrument
_INSTRUMENT_KEYS = ("wavelength_um", "medium_index", "pixel_size_um", "polarization_rad")


def resolve_instrument(crops: CropSet, given: Instrument | None, override: bool = False
                       ) -> Instrument:
    """The instrument a stage uses for a crop folder.

    The crops' own (recorded by the crop stage) unless ``given``; a ``given`` one that differs
    from the recorded one in wavelength, medium index, pixel size or polarisation is refused
    unless ``override`` (a wrong instrument silently gives wrong sizes and heights).

    Raises
    ------
    CropSetError
        No instrument at all, or a contradicting one without ``override``.
    """
    if given is None:
        if crops.instrument is None:
            raise CropSetError(
                f"{crops.table_path}: its sidecar names no instrument; give one with --instrument"
            )
        return crops.instrument
    rec = crops.instrument
    if rec is not None and not override:
        diff = [k for k in _INSTRUMENT_KEYS
                if not math.isclose(getattr(rec, k), getattr(given, k), rel_tol=1e-6,
                                    abs_tol=1e-9)]
        if diff:
            detail = ", ".join(f"{k} {getattr(given, k):g} vs {getattr(rec, k):g}" for k in diff)
            raise CropSetError(
                f"instrument {given.name!r} ({given.path or 'given'}) contradicts the one the "
                f"crops in {crops.directory} were made with, {rec.name!r} ({detail}); use "
                "--override-instrument if that is really intended"
            )
    return given


def open_crops(directory: str | Path) -> CropSet:
    """Open a crop folder (see the module docstring)."""
    return CropSet(directory)
