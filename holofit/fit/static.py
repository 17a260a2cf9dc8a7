"""``static.json``: the static parameters of the particle, averaged over the initial pass.

The robust average over the ``ok`` frames of ``initial.csv`` (median, with the spread as
1.4826 times the median absolute deviation) fixes the static parameters (a rod's a, b, n; a
Janus particle's core radius, cap and indices) for the final pass.
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

__all__ = ["MAD_TO_SIGMA", "read_static", "static_average", "static_doc",
           "write_static"]

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


def read_static(path: str | Path, model: ParticleModel) -> dict[str, float]:
    """The static parameters of a ``static.json`` (checked against ``model``).

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
    values = doc.get("values", {})
    missing = [p.name for p in static_parameters(model) if p.name not in values]
    if missing:
        raise ConfigError(f"{path}: missing static parameter(s) {', '.join(missing)}")
    return {k: float(values[k]) for k in (p.name for p in static_parameters(model))}


def write_static(path: Path, initial: Path, table: pd.DataFrame,
                 model: ParticleModel) -> Path:
    """Write ``static.json``: the robust average of ``table`` (the initial pass, read from
    ``initial``) and the start values; returns ``path``."""
    avg = static_average(table, model)
    write_json(path, {
        **sidecar(kind="static parameters (robust average of the initial pass)",
                  units={p.name: p.unit for p in static_parameters(model)},
                  inputs=[initial]),
        "particle_model": model.kind, **avg,
        "start": dict(static_values(model)),
    })
    return path


def static_doc(path: Path) -> dict[str, Any]:
    """What the final pass's sidecar records of a ``static.json``: values, spread, frames."""
    doc = json.loads(Path(path).read_text())
    return {k: doc[k] for k in ("values", "spread", "n_frames") if k in doc}
