"""``static.json``: each track's model and static parameters, averaged over its initial rows.

The robust average over a track's ``ok`` initial rows of the model it was given (median, with
the spread as 1.4826 times the median absolute deviation) fixes the static parameters (a
rod's a, b, n; a Janus particle's core radius, cap and indices; a sphere's radius and index)
for that track's final pass. Per track by default (tracks of different particles);
``pooled``: one average per model over every track given that model (one batch of identical
particles).

The file holds ``tracks`` (track id -> ``model``, ``status``, ``values``, ``spread``,
``mean``, ``std``, ``n_frames`` and, for a model of the run's configs, ``start``: the config's
values; a track left out: its ``status``, ``reason`` and ``remedy``), the primary model's
config values as ``start`` and, for one fitted track or pooled statics of one model, the same
values at the top level, so that a ``static.json`` of one run can fix the statics of another
(``--static``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
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

__all__ = ["MAD_TO_SIGMA", "STATIC_MODES", "TrackStatic", "read_static", "read_track_statics",
           "static_average", "static_doc", "write_static"]

#: spread of a normal sample from its median absolute deviation
MAD_TO_SIGMA = 1.4826
#: how the static parameters of several tracks are found
STATIC_MODES = ("per-track", "pooled")


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


@dataclass(frozen=True)
class TrackStatic:
    """A track's entry of ``static.json``: its model's label, its status (``fitted`` or why
    not), the static parameters (empty when left out) and the whole entry."""

    model: str
    status: str
    values: dict[str, float]
    doc: dict[str, Any] = field(default_factory=dict)

    @property
    def fitted(self) -> bool:
        return self.status == "fitted"


def _load(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: static-parameter file not found") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: not a static-parameter file")
    return doc


def read_static(path: str | Path, model: ParticleModel, particle: int | None = None
                ) -> dict[str, float]:
    """The static parameters of ``model`` in a ``static.json``: track ``particle``'s, or the
    file's top-level ones (one track, pooled, or a file from another run) where it has no
    fitted entry of that model for the track.

    Raises
    ------
    ConfigError
        Missing file, not JSON, another particle model, or a missing parameter.
    """
    path = Path(path)
    doc = _load(path)
    track = (doc.get("tracks") or {}).get(str(particle)) if particle is not None else None
    if isinstance(track, dict) and track.get("model", model.kind) == model.kind \
            and isinstance(track.get("values"), dict):
        values = track["values"]
    else:
        if doc.get("particle_model") not in (None, model.kind):
            raise ConfigError(f"{path}: static parameters of a {doc.get('particle_model')!r}, "
                              f"not of this {model.kind!r}")
        values = doc.get("values")
    if not isinstance(values, dict):
        where = f"track {particle}" if particle is not None else "the file"
        raise ConfigError(f"{path}: no static parameters for {where}")
    missing = [p.name for p in static_parameters(model) if p.name not in values]
    if missing:
        raise ConfigError(f"{path}: missing static parameter(s) {', '.join(missing)}")
    return {k: float(values[k]) for k in (p.name for p in static_parameters(model))}


def read_track_statics(path: str | Path, tracks: list[int], primary: ParticleModel
                       ) -> dict[int, TrackStatic]:
    """Each track's entry of a ``static.json``; a file without an entry for a track (one
    from another run, ``--static``) gives the track its top-level values of ``primary``.

    Raises
    ------
    ConfigError
        As :func:`read_static`, for a track that has no usable entry.
    """
    path = Path(path)
    doc = _load(path)
    entries = doc.get("tracks") or {}
    out: dict[int, TrackStatic] = {}
    for p in tracks:
        entry = entries.get(str(p))
        if isinstance(entry, dict) and entry.get("status", "fitted") != "fitted":
            out[p] = TrackStatic(str(entry.get("model", primary.kind)), str(entry["status"]),
                                 {}, entry)
            continue
        if isinstance(entry, dict) and entry.get("model", primary.kind) != primary.kind:
            out[p] = TrackStatic(str(entry["model"]), "fitted",
                                 {k: float(v) for k, v in entry["values"].items()}, entry)
            continue
        out[p] = TrackStatic(primary.kind, "fitted", read_static(path, primary, p),
                             entry if isinstance(entry, dict) else {})
    return out


def write_static(path: Path, inputs: list[Path], tracks: Mapping[int, dict[str, Any]],
                 primary: ParticleModel, mode: str = "per-track") -> Path:
    """Write ``static.json``: each track's entry (``model``, ``status`` and its average, or
    why it was left out; see the module docstring), with the top-level values of one fitted
    track or of pooled statics of one model; returns ``path``."""
    if mode not in STATIC_MODES:
        raise FitStageError(f"static mode {mode!r}: expected one of {', '.join(STATIC_MODES)}")
    fitted = {p: e for p, e in tracks.items() if e.get("status") == "fitted"}
    top: dict[str, Any] = {}
    models = {e.get("model") for e in fitted.values()}
    if (len(fitted) == 1 or mode == "pooled") and len(models) == 1 and fitted:
        first = next(iter(fitted.values()))
        top = {k: first[k] for k in ("values", "spread", "mean", "std", "n_frames")
               if k in first}
    kind = next(iter(models)) if len(models) == 1 else primary.kind
    write_json(path, {
        **sidecar(kind="static parameters (robust average of the initial pass)",
                  units={p.name: p.unit for p in static_parameters(primary)},
                  inputs=list(inputs)),
        "particle_model": kind, "static_mode": mode,
        "start": dict(static_values(primary)), **top,
        "tracks": {str(p): e for p, e in sorted(tracks.items())},
    })
    return path


def static_doc(path: Path, particle: int | None = None) -> dict[str, Any]:
    """What a final pass's sidecar records of a ``static.json``: values, spread, frames (of
    track ``particle`` where the file has it)."""
    doc = json.loads(Path(path).read_text())
    track = (doc.get("tracks") or {}).get(str(particle)) if particle is not None else None
    src = track or doc
    return {k: src[k] for k in ("model", "values", "spread", "n_frames") if k in src}
