"""The per-frame fit table: the contract between ``holofit fit`` (writer) and ``holofit analyze``.

One row per attempted frame, one column per quantity, the unit in the column name. Writers:
the fit stage (:mod:`holofit.fit.stage`: ``initial.csv``, ``fit.csv``) through the stage
skeleton's batch runner, which writes each row as it comes and the table atomically, with the
sidecar of :func:`fit_table_meta` (units, ``frame_interval_s``, the schema's name and
version); the simulator through :func:`write_fit_table` (the same sidecar, after
:func:`validate_fit_table`). The analysis reads it through :func:`read_fit_table`, which
tolerates missing frames (no row) and frames whose fit did not succeed (``status != "ok"``):
both become gaps in the trajectory.

Columns
-------
=================  =======  =========================================================
column             unit     meaning
=================  =======  =========================================================
``frame``          index    frame number in the movie (integer >= 0, unique) [required]
``time_s``         s        time of the frame, ``t0 + frame * frame_interval`` [required]
``x_um``           um       full-frame x of the particle centre (columns)
``y_um``           um       full-frame y of the particle centre (rows)
``z_um``           um       height above the focal plane, positive toward the source
``ux, uy, uz``     1        unit symmetry axis ``u = R z_hat`` (lab frame)
``theta_rad``      rad      polar angle of ``u`` from lab +z
``psi_rad``        rad      azimuth of ``u`` from lab +x
``phi_rad``        rad      spin about the particle axis (zyz Euler, see conventions)
``alpha``          1        scattered-field scaling
static parameters  (name)   the particle model's own parameters, e.g. ``a_um``, ``b_um``,
                            ``radius_um``; refractive indices ``n`` / ``index`` (real part)
                            with ``<name>_imag`` for the imaginary part
``chi2``           1        per-pixel chi-square: mean squared residual of the hologram
``r2``             1        coefficient of determination of the fit (paper's R^2)
``n_eval``         count    model evaluations the fit used
``status``         text     one of :data:`STATUSES` [required]
``message``        text     why a frame failed, or empty
``d_<name>``       (name)   1-sigma uncertainty of column ``<name>``, same unit
=================  =======  =========================================================

Orientation may be given as ``ux, uy, uz``, as ``theta_rad, psi_rad`` or both (then they
must agree); the reader fills in the missing form. Rows whose status is not ``"ok"`` may hold
NaN anywhere except ``frame`` and ``status``. A column whose name ends in a unit (``_um``,
``_rad``, ``_s``, ``_deg``) must be numeric; any other column is kept and ignored.

The sidecar JSON (``<table>.csv.json``) holds the units of every column, the provenance and
``frame_interval_s``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.conventions import angles_from_axis, axis_from_angles
from holofit.io.tables import sidecar_path, write_table
from holofit.provenance import sidecar
from holofit.status import FIT_STATUSES, OK

__all__ = [
    "AXIS_COLUMNS",
    "COLUMN_UNITS",
    "POSITION_COLUMNS",
    "REQUIRED_COLUMNS",
    "SCHEMA_VERSION",
    "STATUSES",
    "STATUS_OK",
    "FitTable",
    "FitTableError",
    "column_unit",
    "fit_table_meta",
    "read_fit_table",
    "validate_fit_table",
    "write_fit_table",
]

SCHEMA_VERSION = 1

#: the status words (:mod:`holofit.status`)
STATUSES = FIT_STATUSES
STATUS_OK = OK

REQUIRED_COLUMNS = ("frame", "time_s", "status")
POSITION_COLUMNS = ("x_um", "y_um", "z_um")
AXIS_COLUMNS = ("ux", "uy", "uz")
ANGLE_COLUMNS = ("theta_rad", "psi_rad", "phi_rad")
TEXT_COLUMNS = ("status", "message")

#: Units of the standard columns; others are inferred from their name (:func:`column_unit`).
COLUMN_UNITS: dict[str, str] = {
    "frame": "index",
    "time_s": "s",
    "x_um": "um",
    "y_um": "um",
    "z_um": "um",
    "ux": "1",
    "uy": "1",
    "uz": "1",
    "theta_rad": "rad",
    "psi_rad": "rad",
    "phi_rad": "rad",
    "alpha": "1",
    "chi2": "1 (mean squared residual per pixel, normalised intensity^2)",
    "chi2_red": "1 (residual sum of squares / (noise_sd^2 (pixels - parameters)))",
    "noise_sd": "1 (pixel noise of the normalised hologram, given or estimated)",
    "r2": "1 (coefficient of determination)",
    "n_pixels": "count (pixels fitted)",
    "n_eval": "count (holograms computed, Jacobian columns included)",
    "fit_time_s": "s (wall time of the fit)",
    "status": "text (" + ", ".join(STATUSES) + ")",
    "message": "text",
}

#: Canonical column order for writing (static parameters and extras follow ``alpha``).
_LEADING = ("frame", "time_s", *POSITION_COLUMNS, *AXIS_COLUMNS, *ANGLE_COLUMNS, "alpha")
_TRAILING = ("chi2", "r2", "n_eval", "status", "message")

#: a column whose name ends in a unit must be numeric
_UNIT_SUFFIXES = ("_um", "_rad", "_s", "_deg")

#: |u| may differ from 1 by this much in an "ok" row before it counts as an error.
AXIS_NORM_TOLERANCE = 1e-3
#: ``u`` and ``(theta, psi)`` given together must agree to this angle, rad.
AXIS_ANGLE_TOLERANCE = 1e-4
#: time stamps may deviate from ``t0 + frame * dt`` by this fraction of ``dt``.
TIME_TOLERANCE = 1e-3


class FitTableError(ValueError):
    """A fit table breaks the schema; the message names the file, the column and the frame."""


def column_unit(name: str) -> str:
    """Unit of a fit-table column, from the standard list or from its name.

    ``d_<name>`` has the unit of ``<name>``; names ending in ``_um``, ``_rad``, ``_s`` are
    in um, rad, s; anything else is dimensionless.
    """
    if name in COLUMN_UNITS:
        return COLUMN_UNITS[name]
    if name.startswith("d_") and len(name) > 2:
        return column_unit(name[2:])
    for suffix, unit in (("_um", "um"), ("_rad", "rad"), ("_s", "s"), ("_deg", "deg")):
        if name.endswith(suffix):
            return unit
    return "1"


@dataclass
class FitTable:
    """A validated fit table.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per attempted frame, sorted by frame, orientation columns completed.
    frame_interval_s : float
        Time between consecutive frames, s.
    meta : dict
        The sidecar JSON (empty if there was none).
    source : str
        Where the table came from (for messages).
    """

    table: pd.DataFrame
    frame_interval_s: float
    meta: dict[str, Any] = field(default_factory=dict)
    source: str = "<table>"

    @property
    def ok(self) -> np.ndarray:
        """Boolean mask of the rows with a successful fit."""
        return (self.table["status"] == STATUS_OK).to_numpy()

    @property
    def has_orientation(self) -> bool:
        """True if the table carries the particle's orientation."""
        return all(c in self.table.columns for c in AXIS_COLUMNS)

    def static_columns(self) -> list[str]:
        """Names of the numeric columns that are neither standard nor uncertainties."""
        standard = set(COLUMN_UNITS)
        return [
            c
            for c in self.table.columns
            if c not in standard
            and not c.startswith("d_")
            and pd.api.types.is_numeric_dtype(self.table[c])
        ]

    def static_summary(self) -> dict[str, dict[str, float]]:
        """Median, standard deviation and count of each static parameter over the ok rows.

        A parameter the fit held fixed (constant in the table) takes its spread and count from
        where its value came from when the sidecar says (``static``: the initial pass's robust
        average, written by ``holofit fit``), so its uncertainty is not lost; its ``held`` is
        then 1 (the ``std`` is the initial pass's robust spread, 1.4826 MAD over ``count``
        frames, not a spread of this table), else 0.
        """
        out: dict[str, dict[str, float]] = {}
        rows = self.table[self.ok]
        static = self.meta.get("static")
        source = static if isinstance(static, dict) else {}
        for c in self.static_columns():
            values = rows[c].to_numpy(dtype=float)
            values = values[np.isfinite(values)]
            if values.size:
                spread = values.size > 1 and np.ptp(values) > 0
                out[c] = {
                    "median": float(np.median(values)),
                    "std": float(np.std(values, ddof=1)) if spread else 0.0,
                    "count": int(values.size),
                    "held": 0,
                }
                held_std = source.get("spread", {}).get(c)
                held_count = source.get("n_frames")
                if (not spread and isinstance(held_std, int | float)
                        and isinstance(held_count, int | float)):
                    out[c].update(std=float(held_std), count=int(held_count), held=1)
        return out


def _fail(source: str, text: str) -> FitTableError:
    return FitTableError(f"{source}: {text}")


def _first_frames(frames: pd.Series, mask: np.ndarray, limit: int = 5) -> str:
    bad = pd.unique(frames.to_numpy()[mask])[:limit]
    more = " ..." if pd.unique(frames.to_numpy()[mask]).size > limit else ""
    return ", ".join(str(int(f)) for f in bad) + more


def _numeric(df: pd.DataFrame, column: str, source: str) -> None:
    if pd.api.types.is_numeric_dtype(df[column]):
        df[column] = df[column].astype(float)
        return
    converted = pd.to_numeric(df[column], errors="coerce")
    bad = converted.isna() & df[column].notna() & (df[column].astype(str).str.strip() != "")
    if bad.any():
        first = int(np.flatnonzero(bad.to_numpy())[0])
        raise _fail(
            source,
            f"column '{column}' must be numeric; frame {df['frame'].iloc[first]} holds "
            f"{df[column].iloc[first]!r}",
        )
    df[column] = converted.astype(float)


def validate_fit_table(
    table: pd.DataFrame, source: str = "<table>", frame_interval_s: float | None = None
) -> FitTable:
    """Check a fit table against the schema and return it normalised.

    Parameters
    ----------
    table : pandas.DataFrame
        The table as read or as about to be written.
    source : str
        Name used in error messages (the file path).
    frame_interval_s : float, optional
        Time between frames, s; inferred from ``time_s`` of the ok rows when not given.

    Returns
    -------
    FitTable
        Sorted by frame; ``status`` lower-case; orientation completed (``u`` from angles or
        angles from ``u``, ``u`` renormalised).

    Raises
    ------
    FitTableError
        Missing required column, duplicate or non-integer frame, unknown status, an ok row with
        a NaN position or orientation, a non-unit axis, axis and angles that disagree, or time
        stamps that are not evenly spaced in frame number. The message names the file, the
        column and the first offending frames.
    """
    df = table.copy()
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise _fail(source, f"missing required column(s) {', '.join(missing)}")
    if df.empty:
        raise _fail(source, "the table has no rows")
    df = _checked_frames(df, source)
    _check_statuses(df, source)
    for c in df.columns:
        if c in TEXT_COLUMNS or c == "frame":
            continue
        if (
            c in COLUMN_UNITS
            or c.startswith("d_")
            or c.endswith(_UNIT_SUFFIXES)
            or pd.api.types.is_numeric_dtype(df[c])
        ):
            _numeric(df, c, source)
    ok = (df["status"] == STATUS_OK).to_numpy()
    _check_positions(df, ok, source)
    _complete_orientation(df, ok, source)
    dt = _check_times(df, ok, source, frame_interval_s)
    return FitTable(df, dt, {}, source)


def _checked_frames(df: pd.DataFrame, source: str) -> pd.DataFrame:
    """``frame`` as unique integers >= 0; the table sorted by it."""
    frames = pd.to_numeric(df["frame"], errors="coerce")
    if frames.isna().any() or not np.all(np.mod(frames, 1) == 0) or (frames < 0).any():
        bad = int(np.flatnonzero(frames.isna() | (np.mod(frames, 1) != 0) | (frames < 0))[0])
        raise _fail(
            source, f"column 'frame' must hold integers >= 0; row {bad} holds {df['frame'][bad]!r}"
        )
    df["frame"] = frames.astype(np.int64)
    dup = df["frame"].duplicated(keep=False).to_numpy()
    if dup.any():
        raise _fail(source, f"frame(s) {_first_frames(df['frame'], dup)} appear more than once")
    return df.sort_values("frame", kind="stable").reset_index(drop=True)


def _check_statuses(df: pd.DataFrame, source: str) -> None:
    """``status`` lower-case and known; ``message`` text."""
    status = df["status"].astype(str).str.strip().str.lower()
    unknown = ~status.isin(STATUSES).to_numpy()
    if unknown.any():
        first = int(np.flatnonzero(unknown)[0])
        raise _fail(
            source,
            f"column 'status' at frame {df['frame'][first]} holds {df['status'][first]!r}; "
            f"expected one of {', '.join(STATUSES)}",
        )
    df["status"] = status
    df["message"] = df["message"].fillna("").astype(str) if "message" in df.columns else ""


def _check_positions(df: pd.DataFrame, ok: np.ndarray, source: str) -> None:
    """All three position columns or none; finite time and position at ok rows."""
    present = [c for c in POSITION_COLUMNS if c in df.columns]
    if present and len(present) != 3:
        missing_pos = sorted(set(POSITION_COLUMNS) - set(present))
        raise _fail(source, f"position needs x_um, y_um, z_um; missing {', '.join(missing_pos)}")
    for c in ("time_s", *present):
        nan_ok = ok & ~np.isfinite(df[c].to_numpy())
        if nan_ok.any():
            raise _fail(
                source,
                f"column '{c}' is NaN or missing at ok frame(s) "
                f"{_first_frames(df['frame'], nan_ok)}",
            )


def _complete_orientation(df: pd.DataFrame, ok: np.ndarray, source: str) -> None:
    has_u = [c in df.columns for c in AXIS_COLUMNS]
    has_angles = "theta_rad" in df.columns and "psi_rad" in df.columns
    if any(has_u) and not all(has_u):
        raise _fail(source, "orientation axis needs all of ux, uy, uz")
    if ("theta_rad" in df.columns) != ("psi_rad" in df.columns):
        raise _fail(source, "orientation angles need both theta_rad and psi_rad")
    if not all(has_u) and not has_angles:
        return
    if has_angles:
        for c in ("theta_rad", "psi_rad"):
            bad = ok & ~np.isfinite(df[c].to_numpy())
            if bad.any():
                raise _fail(
                    source, f"column '{c}' is NaN at ok frame(s) {_first_frames(df['frame'], bad)}"
                )
        u_angles = axis_from_angles(df["theta_rad"].to_numpy(), df["psi_rad"].to_numpy())
    if all(has_u):
        u = df[list(AXIS_COLUMNS)].to_numpy(dtype=float)
        norm = np.linalg.norm(u, axis=1)
        bad = ok & ~(np.abs(norm - 1.0) <= AXIS_NORM_TOLERANCE)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            raise _fail(
                source,
                f"axis (ux, uy, uz) is not a unit vector at ok frame(s) "
                f"{_first_frames(df['frame'], bad)} (|u| = {norm[first]:.6g} at frame "
                f"{df['frame'][first]})",
            )
        with np.errstate(invalid="ignore", divide="ignore"):
            u = u / norm[:, None]
        if has_angles:
            cosang = np.clip(np.sum(u * u_angles, axis=1), -1.0, 1.0)
            bad = ok & ~(np.arccos(cosang) <= AXIS_ANGLE_TOLERANCE)
            if bad.any():
                raise _fail(
                    source,
                    "axis (ux, uy, uz) disagrees with (theta_rad, psi_rad) at frame(s) "
                    f"{_first_frames(df['frame'], bad)}",
                )
        else:
            theta, psi = angles_from_axis(u)
            df["theta_rad"], df["psi_rad"] = theta, psi
    else:
        u = u_angles
    df["ux"], df["uy"], df["uz"] = u[:, 0], u[:, 1], u[:, 2]


def _check_times(
    df: pd.DataFrame, ok: np.ndarray, source: str, frame_interval_s: float | None
) -> float:
    f = df["frame"].to_numpy()[ok].astype(float)
    t = df["time_s"].to_numpy()[ok]
    if frame_interval_s is None:
        if f.size < 2:
            raise _fail(source, "need two ok frames (or a frame interval) to know the time step")
        steps = np.diff(t) / np.diff(f)
        frame_interval_s = float(np.median(steps))
    if not (np.isfinite(frame_interval_s) and frame_interval_s > 0):
        raise _fail(source, f"time_s does not increase with frame (step {frame_interval_s:g} s)")
    if f.size:
        t0 = float(np.median(t - f * frame_interval_s))
        off = np.abs(t - (t0 + f * frame_interval_s)) > TIME_TOLERANCE * frame_interval_s
        if off.any():
            frames_ok = df["frame"][ok].reset_index(drop=True)
            raise _fail(
                source,
                "time_s is not t0 + frame * "
                f"{frame_interval_s:.6g} s at frame(s) {_first_frames(frames_ok, off)}",
            )
    return float(frame_interval_s)


def read_fit_table(path: str | Path, frame_interval_s: float | None = None,
                   drop_empty: bool = False) -> FitTable:
    """Read and validate a fit table (CSV) and its sidecar JSON.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    frame_interval_s : float, optional
        Overrides the sidecar's ``frame_interval_s`` and the time stamps' spacing.
    drop_empty : bool
        Drop the columns empty on every row before the checks (a run of several particle
        models writes every model's columns: a sphere's rows hold no orientation).

    Raises
    ------
    FileNotFoundError
        No such file.
    FitTableError
        The table breaks the schema (see :func:`validate_fit_table`).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: fit table not found")
    try:
        df = pd.read_csv(path, dtype={"status": str, "message": str}, keep_default_na=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise FitTableError(f"{path}: not a readable CSV table ({exc})") from None
    meta: dict[str, Any] = {}
    side = sidecar_path(path)
    if side.is_file():
        try:
            meta = json.loads(side.read_text())
        except json.JSONDecodeError as exc:
            raise FitTableError(f"{side}: sidecar is not valid JSON ({exc})") from None
    if frame_interval_s is None and isinstance(meta.get("frame_interval_s"), int | float):
        frame_interval_s = float(meta["frame_interval_s"])
    if drop_empty:
        df = df.drop(columns=[c for c in df.columns
                              if c not in REQUIRED_COLUMNS and df[c].isna().all()])
    fit = validate_fit_table(df, str(path), frame_interval_s)
    fit.meta = meta
    return fit


def fit_table_meta(
    columns: Iterable[str],
    *,
    kind: str = "fit table",
    config: dict[str, Any] | None = None,
    inputs: list[str | Path] | None = None,
    frame_interval_s: float | None = None,
    extra: dict[str, Any] | None = None,
    status_unit: str | None = None,
) -> dict[str, Any]:
    """The sidecar of a fit table: units of ``columns`` (:func:`column_unit`; ``status_unit``
    for ``status`` if given), the schema's name and version, ``frame_interval_s`` (when
    known), provenance (:func:`holofit.provenance.sidecar`) and ``extra``."""
    units = {c: column_unit(c) for c in columns}
    if status_unit is not None and "status" in units:
        units["status"] = status_unit
    return sidecar(
        kind=kind,
        units=units,
        config=config,
        inputs=inputs,
        extra={
            "schema": {"name": "holofit fit table", "version": SCHEMA_VERSION},
            **({"frame_interval_s": frame_interval_s} if frame_interval_s else {}),
            **(extra or {}),
        },
    )


def write_fit_table(
    path: str | Path,
    table: pd.DataFrame,
    *,
    frame_interval_s: float | None = None,
    kind: str = "fit table",
    config: dict[str, Any] | None = None,
    inputs: list[str | Path] | None = None,
    extra: dict[str, Any] | None = None,
) -> FitTable:
    """Validate ``table`` and write it (CSV + sidecar JSON, atomically) in canonical order.

    Returns
    -------
    FitTable
        What was written, as the reader will see it.
    """
    fit = validate_fit_table(table, str(path), frame_interval_s)
    df = fit.table
    lead = [c for c in _LEADING if c in df.columns]
    trail = [c for c in _TRAILING if c in df.columns]
    middle = [c for c in df.columns if c not in lead and c not in trail]
    df = df[lead + middle + trail]
    doc = fit_table_meta(df.columns, kind=kind, config=config, inputs=inputs,
                         frame_interval_s=fit.frame_interval_s, extra=extra)
    write_table(path, df, doc)
    fit.table = df
    fit.meta = doc
    return fit
