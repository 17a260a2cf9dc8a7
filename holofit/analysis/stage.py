"""``holofit analyze``: the diffusion analysis of a fit table of one track or many.

A table keyed by ``(particle, frame)`` with one track is analysed as one trajectory
(:func:`holofit.analysis.pipeline.analyze_trajectory`): ``summary.csv`` (+ sidecar),
``summary.json``, ``msd.csv`` and the plots. With several tracks each is analysed on its own
and the tracks are pooled (:mod:`holofit.analysis.tracks`): each analysed track's files with
the prefix ``particle_<id>_``, ``tracks.csv``, ``pooled.csv``, ``tracks.png``,
``track_msds.png`` and, last, ``summary.csv`` with every analysed track's rows and one row for
each track left out, each with its ``particle``, analysis ``model``, ``track_status`` and
``reason`` (the file ``make`` waits for). Each track is analysed with its own model
(:mod:`holofit.analysis.population`) unless the selection imposes one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.population import (
    TrackSelection,
    analysis_model_of,
    settings_for_model,
    track_kinds,
)
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.summary import format_report, write_summary
from holofit.analysis.track_tables import format_tracks_report, model_records, write_tracks
from holofit.analysis.tracks import TrackPooling, TracksResult, analyze_tracks, n_tracks
from holofit.analysis.trajectory import Trajectory
from holofit.io.tables import write_table
from holofit.provenance import sidecar
from holofit.tables.fit import read_fit_table

__all__ = ["AnalysisRun", "analyze_table", "run_analysis"]


@dataclass
class AnalysisRun:
    """What :func:`run_analysis` found and wrote.

    Attributes
    ----------
    result : AnalysisResult, optional
        The analysis of a table of one track.
    tracks : TracksResult, optional
        The analysis of every track of a table of several, and their pooling.
    files : dict
        What was written, by name.
    """

    result: AnalysisResult | None = None
    tracks: TracksResult | None = None
    files: dict[str, Path] = field(default_factory=dict)

    def report(self) -> str:
        """The short text report of ``holofit analyze``."""
        if self.tracks is not None:
            return format_tracks_report(self.tracks)
        assert self.result is not None
        return format_report(self.result)


def analyze_table(
    path: str | Path, settings: AnalysisConfig, frame_interval_s: float | None = None
) -> AnalysisResult:
    """Read a fit table of one track (validating it; columns empty on every row, another
    particle model's, left out) and analyse it."""
    fit = read_fit_table(path, frame_interval_s, drop_empty=True)
    traj = Trajectory.from_fit_table(fit, bool(settings.drop_ambiguous))
    return analyze_trajectory(traj, settings)


def run_analysis(
    path: str | Path,
    settings: AnalysisConfig,
    out_dir: str | Path,
    *,
    plots: bool = True,
    frame_interval_s: float | None = None,
    pooling: TrackPooling | None = None,
    selection: TrackSelection | None = None,
) -> AnalysisRun:
    """Analyse a fit table of one track or several and write the summary files and plots
    (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The fit table (``holofit fit``'s ``fit.csv``, or a prefit table of spheres).
    settings : AnalysisConfig
        The model, temperature, sizes and fit ranges.
    out_dir : str or Path
        Where the files go.
    plots : bool
        Draw the PNG plots.
    frame_interval_s : float, optional
        The time between frames, s, where the table's sidecar does not say it.
    pooling : TrackPooling, optional
        How several tracks are pooled.
    selection : TrackSelection, optional
        The tracks analysed (``--particle`` / ``--exclude-particle``) and a model imposed on
        all (``--model``); default: every track, each with its own model.

    Raises
    ------
    FitTableError, AnalysisError
        Naming the file and what is wrong.
    """
    selection = selection or TrackSelection()
    if n_tracks(path) > 1:
        return _run_tracks(path, settings, Path(out_dir), plots, frame_interval_s, pooling,
                           selection)
    result = analyze_table(path, _single_track_settings(path, settings, selection),
                           frame_interval_s)
    pngs: list[Path] = []
    if plots:
        from holofit.analysis.plots import write_plots

        Path(out_dir).mkdir(parents=True, exist_ok=True)
        pngs = list(write_plots(result, out_dir))
    files = write_summary(result, out_dir, inputs=[path])  # summary.csv last: make waits
    for p in pngs:
        files[p.stem + "_png"] = p
    return AnalysisRun(result=result, files=files)


def _single_track_settings(path: str | Path, settings: AnalysisConfig,
                           selection: TrackSelection) -> AnalysisConfig:
    """The settings of a table of one track: its own model where the fit table's ``model``
    column names one and none is imposed; the selection checked against the track.

    Raises
    ------
    AnalysisError
        A selection the table does not meet.
    """
    try:
        head = pd.read_csv(path, usecols=lambda c: c in ("particle", "model"), dtype=str)
    except (OSError, ValueError, pd.errors.ParserError, pd.errors.EmptyDataError):
        return settings  # the reader that follows names the problem
    if "particle" in head.columns and (selection.particles or selection.exclude_particles):
        ids = pd.to_numeric(head["particle"], errors="coerce").dropna().astype(int)
        selection.kept(set(ids), str(path))
    if selection.model is not None:
        return settings_for_model(settings, selection.model)
    kinds = track_kinds(head) if "particle" in head.columns else {}
    if not kinds and "model" in head.columns and head["model"].notna().any():
        kinds = {0: str(head["model"].dropna().mode().iloc[0])}
    if not kinds:
        return settings
    model, _ = analysis_model_of(next(iter(kinds.values())))
    # a kind that alone does not decide (a dimer): the settings' model, the sidecar's or given
    return settings if model is None else settings_for_model(settings, model)


def _run_tracks(path: str | Path, settings: AnalysisConfig, out: Path, plots: bool,
                frame_interval_s: float | None, pooling: TrackPooling | None,
                selection: TrackSelection) -> AnalysisRun:
    """Every track of a table of several, each one's files prefixed, then the pooling."""
    result = analyze_tracks(path, settings, pooling=pooling, frame_interval_s=frame_interval_s,
                            selection=selection)
    files: dict[str, Path] = {}
    rows = []
    for t in result.tracks:
        head = {"particle": t.particle, "model": t.model, "track_status": t.status,
                "reason": t.message}
        if t.result is None:
            rows.append({**head, "quantity": "", "remedy": t.remedy})
            continue
        prefix = f"particle_{t.particle}_"
        if plots:
            from holofit.analysis.plots import write_plots

            for png in write_plots(t.result, out, prefix):
                files[png.stem + "_png"] = png
        for name, f in write_summary(t.result, out, inputs=[path], prefix=prefix).items():
            files[f"{prefix}{name}"] = f
        rows += [{**head, **r} for r in t.result.rows]
    files.update(write_tracks(result, out, inputs=[path]))
    if plots:
        from holofit.analysis.track_plots import write_track_plots

        for png in write_track_plots(result, out):
            files[png.stem + "_png"] = png
    files["summary_csv"] = write_table(
        out / "summary.csv", pd.DataFrame(rows),
        sidecar(kind="diffusion analysis summary, one block per track (one row for a track "
                     "left out)",
                config={"settings": settings.__dict__, "selection": selection.summary()},
                inputs=[path],
                extra={"notes": result.notes, "models": model_records(result)}))
    return AnalysisRun(tracks=result, files=files)
