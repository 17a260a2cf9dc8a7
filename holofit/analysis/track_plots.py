"""PNG figures of a multi-particle analysis: every track on the field of view, MSDs per track."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from holofit.analysis.tracks import TracksResult
from holofit.io.atomic import atomic_path

__all__ = ["plot_field_of_view", "plot_track_msds", "write_track_plots"]

_STATUS_STYLE = {"analysed": "-", "poor_fit": ":", "flagged": ":", "short": "--",
                 "failed": ":"}


def _save(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)
    return path


def plot_field_of_view(result: TracksResult, path: Path) -> Path:
    """Every analysed track's x-y path (um) on one picture, labelled by its id and status."""
    fig, ax = plt.subplots(figsize=(6.5, 6.0))
    for t in result.tracks:
        if t.result is None:
            continue
        traj = t.result.trajectory
        x, y = traj.position_um[:, 0], traj.position_um[:, 1]
        line, = ax.plot(x, y, _STATUS_STYLE.get(t.status, "-"), lw=0.8)
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.any():
            i = int(np.flatnonzero(ok)[0])
            ax.annotate(f"{t.particle}" + ("" if t.status == "analysed" else f" ({t.status})"),
                        (x[i], y[i]), color=line.get_color(), fontsize=8)
    ax.set_xlabel("x (um)")
    ax.set_ylabel("y (um)")
    ax.invert_yaxis()  # image rows grow downwards
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("tracks in the field of view (dotted: poor fit; left out of the pool)")
    return _save(fig, path)


#: lab-frame MSDs a track's analysis may hold, and ``MSD / (D_t tau)`` of each
_LAB_MSDS = {"xy": 4.0, "lab_3d": 6.0, "lab_x": 2.0}


def _lab_msd(stats: dict) -> str | None:
    return next((name for name in _LAB_MSDS if name in stats), None)


def plot_track_msds(result: TracksResult, path: Path) -> Path:
    """A lab-frame MSD of every analysed track (its model's: x-y for a sphere, 3D for a
    rod), with each model's pooled ``D_t`` as a line."""
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    tau_max: dict[str, float] = {}
    names: dict[str, set[str]] = {}
    for t in result.tracks:
        name = _lab_msd(t.result.stats) if t.result is not None else None
        if t.result is None or name is None:
            continue
        names.setdefault(t.model, set()).add(name)
        st = t.result.stats[name]
        ok = np.isfinite(st.mean)
        ax.errorbar(st.tau_s[ok], st.mean[ok], yerr=st.sem[ok], fmt="o-", ms=2, lw=0.6,
                    elinewidth=0.5, label=f"particle {t.particle}, {t.model} ({name})"
                    + ("" if t.status == "analysed" else f" ({t.status})"))
        if ok.any():
            tau_max[t.model] = max(tau_max.get(t.model, 0.0), float(st.tau_s[ok][-1]))
    for model, used in names.items():
        pooled = result.estimate("D_t", model)
        if pooled is None or len(used) != 1 or not tau_max.get(model, 0.0) > 0:
            continue
        k = _LAB_MSDS[next(iter(used))]
        tau = np.linspace(0.0, tau_max[model], 50)
        ax.plot(tau, k * pooled.value * tau, "--", lw=1.2,
                label=f"{k:g} D tau, pooled {model} D_t {pooled.value:.3g} um^2/s")
    ax.set_xlabel("lag time (s)")
    ax.set_ylabel("lab-frame MSD (um$^2$)")
    if names:
        ax.legend(fontsize=7)
    return _save(fig, path)


def write_track_plots(result: TracksResult, out_dir: str | Path) -> list[Path]:
    """Write ``tracks.png`` and ``track_msds.png`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [plot_field_of_view(result, out / "tracks.png"),
            plot_track_msds(result, out / "track_msds.png")]
