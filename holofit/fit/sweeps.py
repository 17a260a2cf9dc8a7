"""The continuity sweeps after the final pass, as batches.

Frames of the final pass that look like a wrong local minimum are refitted from their good
neighbours' orientations (the rule: :func:`holofit.fit.continuity.repair_by_continuity`);
each sweep is a batch of its own (``continuity/sweep_K.csv`` beside ``fit.csv``, keyed on the
table it started from), so an interrupted run resumes where it stopped. Better fits replace
their rows in ``fit.csv``, written back atomically.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.runner import BatchOptions, Precomputed, run_batch, run_frame
from holofit.batch.stage import fingerprint
from holofit.fit.continuity import (
    ContinuityReport,
    ContinuitySettings,
    NeighbourStart,
    repair_by_continuity,
)
from holofit.fit.task import FitConfig, FitPayload, fit_columns, fit_frame_task
from holofit.holomodel.result import flag_outliers
from holofit.io.tables import read_table, sidecar_path, write_table

__all__ = ["continuity_sweeps"]


#: the refits of a continuity sweep: at most two neighbour starts, no mirror
_SWEEP_STARTS = 2
#: a sweep with fewer frames runs in this process, in memory (its engine kept from sweep to
#: sweep, no table written): the last sweeps, eating a long run of bad frames from its ends,
#: have a few frames and a few seconds each
_SERIAL_SWEEP_FRAMES = 8

Loader = Callable[[int], Any]


def continuity_sweeps(path: Path, cfg: FitConfig, load: Loader, cont: ContinuitySettings,
                      batch: BatchOptions | None, outlier_factor: float) -> ContinuityReport:
    """Run the continuity sweeps on the final pass's table and write it back (atomically).

    Each sweep is a batch of its own (``continuity/sweep_K.csv`` beside ``fit.csv``, keyed on
    the table it started from), so an interrupted run resumes where it stopped; a table whose
    sidecar records sweeps with these settings is left as it is.
    """
    meta = json.loads(sidecar_path(path).read_text())
    key = fingerprint({"batch": meta.get("batch", {}).get("fingerprint"),
                       "continuity": asdict(cont)})
    done = meta.get("continuity")
    if isinstance(done, dict) and done.get("key") == key:
        return ContinuityReport(**{k: done[k] for k in ContinuityReport.__dataclass_fields__
                                   if k in done})
    model = cfg.particle.model
    columns = fit_columns(model, cfg.free)
    sweeps = _Sweeps(cfg, load, batch, key, meta, path.parent / "continuity")
    table, report = repair_by_continuity(
        read_table(path), sweeps.refit, cont, head_tail=model.head_tail_symmetric,
        ambiguity_chi2=cfg.options.ambiguity_chi2,
        refinish=lambda t: flag_outliers(t, outlier_factor))
    meta["continuity"] = {**report.as_dict(), "key": key, "settings": asdict(cont),
                          "sweeps_folder": str(sweeps.folder)}
    extra = [c for c in table.columns if c not in columns]  # e.g. the tracking's columns
    write_table(path, table[[*columns, *extra]], meta)
    return report


class _Sweeps:
    """The refits of the sweeps: each a batch (``continuity/sweep_K.csv``) or, when short,
    run here in memory."""

    def __init__(self, cfg: FitConfig, load: Loader, batch: BatchOptions | None, key: str,
                 meta: dict[str, Any], folder: Path) -> None:
        self.cfg = replace(cfg, options=replace(cfg.options, n_starts=_SWEEP_STARTS,
                                                mirror=False))
        self.columns = fit_columns(cfg.particle.model, cfg.free)
        self.load, self.batch, self.key, self.folder = load, batch, key, folder
        self.meta = {k: v for k, v in meta.items() if k not in ("batch", "continuity")}

    def refit(self, sweep: int, starts: dict[int, NeighbourStart]) -> pd.DataFrame:
        """Refit the frames of ``starts`` from their neighbour starts; their rows."""
        load = partial(_load_sweep, self.load, starts)
        if len(starts) < _SERIAL_SWEEP_FRAMES:
            rows = []
            for frame in sorted(starts):
                payload = load(frame)
                if not isinstance(payload, Precomputed):
                    rows.append(run_frame(fit_frame_task, self.cfg, frame, payload))
            return pd.DataFrame(rows, columns=list(self.columns))
        meta = {**self.meta, "kind": f"DDA fit table (continuity sweep {sweep}: refits from "
                                     "the neighbours' orientations)"}
        out = self.folder / f"sweep_{sweep}.csv"
        run_batch(fit_frame_task, self.cfg, sorted(starts), load, out, self.columns,
                  fingerprint=_sweep_fingerprint(self.key, sweep, starts), meta=meta,
                  options=self.batch, desc=f"fit (continuity {sweep})")
        return read_table(out)


def _load_sweep(load: Loader, starts: dict[int, NeighbourStart],
                frame: int) -> FitPayload | Precomputed:
    """The final pass's payload of ``frame``, started from its neighbours'."""
    payload = load(frame)
    if isinstance(payload, Precomputed):
        return payload
    s = starts[frame]
    return FitPayload(payload.crop, payload.corner,
                      {**payload.start, "z_um": s.z_um, "alpha": s.alpha}, s.candidates)


def _sweep_fingerprint(key: str, sweep: int, starts: dict[int, NeighbourStart]) -> str:
    return fingerprint(
        {"key": key, "sweep": sweep,
         "starts": {f: [s.sources, [(c.psi, c.theta, c.phi) for c in s.candidates],
                        s.z_um, s.alpha] for f, s in sorted(starts.items())}})
