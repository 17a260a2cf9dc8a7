"""``static.json``: each track's static parameters, averaged over its initial-pass rows.

The robust average over a track's ``ok`` rows of ``initial.csv`` (median, with the spread as
1.4826 times the median absolute deviation) fixes the static parameters (a rod's a, b, n; a
Janus particle's core radius, cap and indices) for that track's final pass. Per track by
default (tracks of different particles); ``pooled``, one average over every track's rows
(one batch of identical particles).

The file holds ``tracks`` (track id -> ``values``, ``spread``, ``mean``, ``std``,
``n_frames``) and, for one track or pooled statics, the same at the top level, so that a
``static.json`` of one run can fix the statics of another (``--static``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.config import ConfigError
from holofit.fit.errors import FitStageError
from holofit.holomodel.parameters import static_parameters, static_values
from holofit.io.tables import write_json
from holofit.particles import ParticleModel
from holofit.provenance import sidecar
from holofit.status import OK

__all__ = ["MAD_TO_SIGMA", "STATIC_MODES", "read_static", "static_average", "static_doc",
           "write_static"]

#: how the static parameters of several tracks are found
STATIC_MODES = ("per-track", "pooled")

#: spread of a normal sample from its median absolute deviation
MAD_TO_SIGMA = 1.4826


def static_average(table: pd.DataFrame, model: ParticleModel) -> dict[str, Any]:
    """Robust average of the static parameters over a table's ``ok`` rows.

    Returns
    -------
    dict
        ``{"values": {name: median}, "spread": {name: 1.4826 MAD}, "mean": ..., "std": ...,
        "n_frames": n}``.

    Raises
    ------
    FitStageError
        No ``ok`` row.
    """
    ok = table[table["status"] == OK]
    if len(ok) < 1:
        raise FitStageError("the initial pass has no ok frame: no static parameters to fix "
                            "(see initial.csv's status and message)")
    out: dict[str, Any] = {"values": {}, "spread": {}, "mean": {}, "std": {},
                           "n_frames": len(ok)}
    for p in static_parameters(model):
        v = ok[p.name].to_numpy(dtype=float)
        v = v[np.isfinite(v)]
        med = float(np.median(v))
        out["values"][p.name] = med
        out["spread"][p.name] = (float(MAD_TO_SIGMA * np.median(np.abs(v - med)))
                                 if v.size >= 3 else math.nan)
        out["mean"][p.name] = float(np.mean(v))
        out["std"][p.name] = float(np.std(v, ddof=1)) if v.size > 1 else 0.0
    return out


def read_static(path: str | Path, model: ParticleModel, particle: int | None = None
                ) -> dict[str, float]:
    """The static parameters of a ``static.json`` (checked against ``model``): track
    ``particle``'s, or the file's top-level ones (one track, pooled, or a file from another
    run) where it has no entry for that track.

    Raises
    ------
    ConfigError
        Missing file, not JSON, another particle model, or a missing parameter.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: static-parameter file not found") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    if doc.get("particle_model") not in (None, model.kind):
        raise ConfigError(f"{path}: static parameters of a {doc.get('particle_model')!r}, "
                          f"not of this {model.kind!r}")
    track = (doc.get("tracks") or {}).get(str(particle)) if particle is not None else None
    values = (track or doc).get("values")
    if not isinstance(values, dict):
        where = f"track {particle}" if particle is not None else "the file"
        raise ConfigError(f"{path}: no static parameters for {where}")
    missing = [p.name for p in static_parameters(model) if p.name not in values]
    if missing:
        raise ConfigError(f"{path}: missing static parameter(s) {', '.join(missing)}")
    return {k: float(values[k]) for k in (p.name for p in static_parameters(model))}


def write_static(path: Path, initial: Path, table: pd.DataFrame, model: ParticleModel,
                 mode: str = "per-track") -> Path:
    """Write ``static.json`` from the initial pass's table (read from ``initial``): each
    track's robust average, or (``pooled``) one over every track's rows; returns ``path``.

    Raises
    ------
    FitStageError
        A track (or, pooled, every track) without an ``ok`` row; the message names it.
    """
    if mode not in STATIC_MODES:
        raise FitStageError(f"static mode {mode!r}: expected one of {', '.join(STATIC_MODES)}")
    tracks: dict[str, Any] = {}
    top: dict[str, Any] = {}
    ids = sorted(int(p) for p in table["particle"].unique()) if len(table) else [0]
    if mode == "pooled":
        try:
            top = static_average(table, model)
        except FitStageError as exc:
            raise FitStageError(f"pooled static parameters: {exc}") from None
        tracks = {str(p): top for p in ids}
    else:
        for p in ids:
            try:
                tracks[str(p)] = static_average(table[table["particle"] == p], model)
            except FitStageError as exc:
                raise FitStageError(f"particle {p}: {exc}") from None
        if len(ids) == 1:
            top = tracks[str(ids[0])]
    write_json(path, {
        **sidecar(kind="static parameters (robust average of the initial pass)",
                  units={p.name: p.unit for p in static_parameters(model)},
                  inputs=[initial]),
        "particle_model": model.kind, "static_mode": mode, **top, "tracks": tracks,
        "start": dict(static_values(model)),
    })
    return path


def static_doc(path: Path, particle: int | None = None) -> dict[str, Any]:
    """What a final pass's sidecar records of a ``static.json``: values, spread, frames (of
    track ``particle`` where the file has it)."""
    doc = json.loads(Path(path).read_text())
    track = (doc.get("tracks") or {}).get(str(particle)) if particle is not None else None
    src = track or doc
    return {k: src[k] for k in ("values", "spread", "n_frames") if k in src}
