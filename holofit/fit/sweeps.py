"""The continuity sweeps after the final pass, as batches.

Frames of each track that look like a wrong local minimum are refitted from their good
neighbours' orientations (the rule: :func:`holofit.fit.continuity.repair_by_continuity`),
track by track; each sweep of a track is a batch of its own through the stage skeleton
(``continuity/sweep_p<particle>_<K>.csv``, keyed on the table it started from), so an
interrupted run resumes where it stopped. A short sweep runs in this process, in memory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch import BatchSettings, Precomputed, run_frame
from holofit.batch.stage import StageTable, fingerprint, run_stage
from holofit.fit.continuity import (
    ContinuityReport,
    ContinuitySettings,
    NeighbourStart,
    repair_by_continuity,
)
from holofit.fit.task import FitPayload, PassConfig, fit_columns, fit_frame_task
from holofit.io.tables import read_table
from holofit.quality import flag_outliers
from holofit.tables.cropset import PARTICLE_KEY

__all__ = ["SweepRun", "continuity_sweeps"]

#: the refits of a continuity sweep: at most two neighbour starts, no mirror
_SWEEP_STARTS = 2
#: a sweep with fewer frames runs in this process, in memory (its engine kept from sweep to
#: sweep, no table written)
_SERIAL_SWEEP_FRAMES = 8

Loader = Callable[[Any], Any]


@dataclass(frozen=True)
class SweepRun:
    """Where and how the sweeps of one pass run: the pass, its frame loader, the batch
    settings, the sweeps' folder, the sidecar they inherit, and the key of the table they
    start from."""

    config: PassConfig
    load: Loader
    batch: BatchSettings | None
    folder: Path
    meta: dict[str, Any]
    key: str


def continuity_sweeps(table: pd.DataFrame, run: SweepRun, cont: ContinuitySettings,
                      outlier_factor: float) -> tuple[pd.DataFrame, dict[int, ContinuityReport]]:
    """Run the continuity sweeps on each track's rows of a final-pass table; the table with
    better refits merged (and frames still improbable flagged), and each track's report."""
    model = run.config.particle.model
    parts, reports = [], {}
    for p, rows in table.groupby("particle", sort=True):
        sweeps = _Sweeps(run, int(p))
        part = rows.drop(columns="particle")
        fixed, reports[int(p)] = repair_by_continuity(
            part, sweeps.refit, cont, head_tail=model.head_tail_symmetric,
            ambiguity_chi2=run.config.options.ambiguity_chi2,
            refinish=lambda t: flag_outliers(t, outlier_factor))
        parts.append(fixed.assign(particle=int(p)))
    out = pd.concat(parts, ignore_index=True) if parts else table
    return out[[*table.columns, *[c for c in out.columns if c not in table.columns]]], reports


class _Sweeps:
    """The refits of one track's sweeps: each a batch (``sweep_p<P>_<K>.csv``) or, when short,
    run here in memory."""

    def __init__(self, run: SweepRun, particle: int) -> None:
        cfg = run.config
        self.cfg = replace(cfg, options=replace(cfg.options, n_starts=_SWEEP_STARTS,
                                                mirror=False))
        self.columns = fit_columns(cfg.particle.model, cfg.free)
        self.run, self.particle = run, particle
        self.meta = {k: v for k, v in run.meta.items() if k not in ("batch", "continuity")}
        self.key = fingerprint({"table": run.key, "particle": particle})

    def refit(self, sweep: int, starts: dict[int, NeighbourStart]) -> pd.DataFrame:
        """Refit the frames of ``starts`` from their neighbour starts; their rows (without
        ``particle``)."""
        load = partial(_load_sweep, self.run.load, starts)
        keys = [(self.particle, f) for f in sorted(starts)]
        if len(starts) < _SERIAL_SWEEP_FRAMES:
            rows = []
            for key in keys:
                payload = load(key)
                if not isinstance(payload, Precomputed):
                    rows.append(run_frame(fit_frame_task, self.cfg, key, payload,
                                          key_columns=PARTICLE_KEY))
            return pd.DataFrame(rows, columns=list(self.columns)).drop(columns="particle")
        meta = {**self.meta, "kind": f"DDA fit table (continuity sweep {sweep} of track "
                                     f"{self.particle}: refits from the neighbours' "
                                     "orientations)"}
        out = self.run.folder / f"sweep_p{self.particle}_{sweep}.csv"
        table = StageTable(out, self.columns, meta, _sweep_fingerprint(self.key, sweep, starts),
                           f"fit (continuity {sweep}, particle {self.particle})",
                           key_columns=PARTICLE_KEY)
        run_stage(fit_frame_task, self.cfg, keys, load, table, batch=self.run.batch)
        return read_table(out).drop(columns="particle")


def _load_sweep(load: Loader, starts: dict[int, NeighbourStart],
                key: tuple[int, int]) -> FitPayload | Precomputed:
    """The final pass's payload of ``key``, started from its neighbours'."""
    payload = load(key)
    if isinstance(payload, Precomputed):
        return payload
    s = starts[int(key[1])]
    return FitPayload(payload.crop, payload.corner,
                      {**payload.start, "z_um": s.z_um, "alpha": s.alpha}, s.candidates)


def _sweep_fingerprint(key: str, sweep: int, starts: dict[int, NeighbourStart]) -> str:
    return fingerprint(
        {"key": key, "sweep": sweep,
         "starts": {f: [s.sources, [(c.psi, c.theta, c.phi) for c in s.candidates],
                        s.z_um, s.alpha] for f, s in sorted(starts.items())}})


def sweep_settings_doc(cont: ContinuitySettings) -> dict[str, Any]:
    """The sweeps' settings as the sidecar records them."""
    return asdict(cont)
