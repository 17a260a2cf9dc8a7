"""PNG figures of an analysis: MSDs with fits, orientation statistics, the trajectory."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from holofit.analysis.linefit import FitResult
from holofit.analysis.msd import LagStatistics
from holofit.analysis.projection import projection_correlation
from holofit.analysis.recipes import MsdPanel, recipe_for
from holofit.analysis.results import AnalysisResult
from holofit.io.atomic import atomic_path

__all__ = ["plot_msd", "plot_orientation", "plot_trajectory", "write_plots"]

LABELS = {
    "par": r"$\langle \Delta r_\parallel^2 \rangle$",
    "perp": r"$\langle \Delta r_\perp^2 \rangle$",
    "lab_x": r"$\langle \Delta x^2 \rangle$",
    "lab_y": r"$\langle \Delta y^2 \rangle$",
    "lab_z": r"$\langle \Delta z^2 \rangle$",
    "lab_3d": r"$\langle |\Delta \mathbf{r}|^2 \rangle$",
    "xy": r"$\langle \Delta x^2 + \Delta y^2 \rangle$",
    "orient": r"$\langle |\Delta \mathbf{u}|^2 \rangle$",
    "proj": r"$\langle \mathbf{p}(t) \cdot \mathbf{p}(t+\tau) \rangle$",
}


def _save(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)
    return path


def _errorbars(ax, st: LagStatistics, label: str, color: str, **kw) -> None:
    ok = np.isfinite(st.mean)
    ax.errorbar(st.tau_s[ok], st.mean[ok], yerr=st.sem[ok], fmt="o", ms=3, color=color,
                elinewidth=0.8, capsize=1.5, label=label, **kw)


def _fit_line(ax, f: FitResult, tau_max: float, color: str, label: str) -> None:
    inside = np.linspace(f.tau_s[0], f.tau_s[-1], 200)
    ax.plot(inside, f.curve(inside), "-", color=color, lw=1.5, label=label)
    beyond = np.geomspace(f.tau_s[-1], max(tau_max, f.tau_s[-1] * 1.01), 100)
    ax.plot(beyond, f.curve(beyond), "--", color=color, lw=1.0, alpha=0.6)


def _msd_panel(ax, panel: MsdPanel, result: AnalysisResult, tau_max: float) -> None:
    st, fits, meas = result.stats, result.fits, result.measured
    for curve in panel.curves:
        _errorbars(ax, st[curve.observable], LABELS[curve.observable], curve.colour)
        if curve.measured is not None:
            m = meas[curve.measured]
            symbol = curve.symbol or curve.measured
            _fit_line(ax, fits[curve.observable], tau_max, curve.colour,
                      f"fit: {symbol} = {m.value:.4g} $\\pm$ {m.error:.2g} $\\mu$m$^2$/s")
    if panel.title is not None:
        ax.set_title(panel.title)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(r"lag $\tau$ (s)")
    ax.set_ylabel(r"MSD ($\mu$m$^2$)")
    ax.legend(fontsize=8)


def plot_msd(result: AnalysisResult, path: str | Path) -> Path:
    """Translational MSDs with block-decorrelated error bars and the weighted fits (the
    panels of the model's recipe)."""
    panels = recipe_for(result.settings.model).msd_panels
    n = len(panels)
    fig, axes = plt.subplots(1, n, figsize=(6.0 if n == 1 else 5.5 * n, 4.5), squeeze=False)
    tau_max = max(s.tau_s[-1] for s in result.stats.values())
    for ax, panel in zip(axes[0], panels, strict=True):
        _msd_panel(ax, panel, result, tau_max)
    fig.suptitle("mean-square displacements (solid: fit range; dashed: extrapolation)",
                 fontsize=10)
    fig.tight_layout()
    return _save(fig, Path(path))


def _orientation_msd(ax, result: AnalysisResult, tau_max: float) -> None:
    """Rods: <|du|^2> with its fit."""
    st, fits, meas = result.stats, result.fits, result.measured
    _errorbars(ax, st["orient"], LABELS["orient"], "C2")
    m = meas["D_r"]
    _fit_line(ax, fits["orient"], tau_max, "C2",
              f"fit: D_r = {m.value:.4g} $\\pm$ {m.error:.2g} s$^{{-1}}$")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylabel(r"$\langle |\mathbf{u}(t+\tau) - \mathbf{u}(t)|^2 \rangle$")


def _projection(ax, result: AnalysisResult, tau_max: float) -> None:
    """Janus particles: <p . p'> with the full series, the single exponential and the l = 1
    term."""
    st, fits, meas = result.stats, result.fits, result.measured
    _errorbars(ax, st["proj"], LABELS["proj"], "C2")
    m = meas["D_r"]
    _fit_line(ax, fits["proj"], tau_max, "C2",
              f"full series: D_r = {m.value:.4g} $\\pm$ {m.error:.2g} s$^{{-1}}$")
    if "proj_single_exp" in fits:
        f1 = fits["proj_single_exp"]
        _fit_line(ax, f1, tau_max, "C7",
                  f"single exponential: D_r = {f1.value('D'):.4g} s$^{{-1}}$")
    tau = np.geomspace(st["proj"].tau_s[0], tau_max, 200)
    fp = fits["proj"]
    amp = fp.value("A") if "A" in fp.model.params else 1.0
    ax.plot(tau, amp * projection_correlation(m.value, tau, n_odd=1), ":", color="C1",
            lw=1, label=r"$\ell=1$ term alone (same $D_r$, A)")
    ax.set_xscale("log")
    ax.set_ylabel(r"$\langle \mathbf{p}(t) \cdot \mathbf{p}(t+\tau) \rangle$")
    ax.axhline(0, color="0.7", lw=0.5)


#: how each rotational observable is drawn
ORIENTATION_PLOTS: dict[str, Callable[..., None]] = {
    "orient": _orientation_msd,
    "proj": _projection,
}


def plot_orientation(result: AnalysisResult, path: str | Path) -> Path | None:
    """The rotational observable of the model with its fits (None for translation only)."""
    rotation = recipe_for(result.settings.model).rotation
    if rotation is None:
        return None
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    tau_max = max(s.tau_s[-1] for s in result.stats.values())
    ORIENTATION_PLOTS[rotation.observable](ax, result, tau_max)
    ax.set_xlabel(r"lag $\tau$ (s)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_trajectory(result: AnalysisResult, path: str | Path) -> Path:
    """Position and axis versus time; rejected frames and flips marked."""
    traj = result.trajectory
    t = traj.time_s
    has_axis = traj.axis is not None and recipe_for(result.settings.model).orientation
    fig, axes = plt.subplots(2 if has_axis else 1, 1, figsize=(11, 6 if has_axis else 3.5),
                             sharex=True, squeeze=False)
    ax = axes[0, 0]
    for k, (name, color) in enumerate((("x", "C0"), ("y", "C1"), ("z", "C2"))):
        ax.plot(t, traj.position_um[:, k], "-", color=color, lw=0.8, label=name)
    ax.set_ylabel(r"position ($\mu$m)")
    gaps = ~traj.valid
    if gaps.any():
        ax.plot(t[gaps], np.full(gaps.sum(), np.nanmin(traj.position_um)), "|", color="0.5",
                ms=6, label="gap (no fit)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    if has_axis:
        ax = axes[1, 0]
        cl = result.cleaning
        axis = cl.axis if cl is not None else traj.axis
        assert axis is not None and traj.axis is not None  # has_axis
        for k, (name, color) in enumerate((("u_x", "C0"), ("u_y", "C1"), ("u_z", "C2"))):
            ax.plot(t, axis[:, k], "-", color=color, lw=0.8, label=name + " (cleaned)")
        if cl is not None and cl.outliers.any():
            raw = traj.axis[cl.outliers]
            ax.plot(np.repeat(t[cl.outliers], 3), raw.T.ravel(order="F"), "x", color="k", ms=4,
                    label="rejected frames (raw)")
        if cl is not None and cl.flipped.any():
            ax.plot(t[cl.flipped], np.full(cl.flipped.sum(), 1.08), "|", color="C3", ms=4,
                    label="sign flipped")
        ax.set_ylabel("axis u")
        ax.set_ylim(-1.15, 1.15)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    return _save(fig, Path(path))


def write_plots(result: AnalysisResult, out_dir: str | Path, prefix: str = "") -> list[Path]:
    """``msd.png``, ``orientation.png`` (not for spheres) and ``trajectory.png``, each name
    after ``prefix`` (one track of several: ``particle_<id>_``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [plot_msd(result, out / f"{prefix}msd.png")]
    p = plot_orientation(result, out / f"{prefix}orientation.png")
    if p is not None:
        paths.append(p)
    paths.append(plot_trajectory(result, out / f"{prefix}trajectory.png"))
    return paths
