"""The summary table (the paper's "quantity, experiment, expected, source"), files, report."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.analysis.consistency import Consistency
from holofit.analysis.recipes import Compared, recipe_for
from holofit.analysis.results import AnalysisResult
from holofit.io.tables import write_json, write_table
from holofit.provenance import sidecar

__all__ = ["SUMMARY_COLUMNS", "consistency_rows", "format_report", "summary_rows",
           "write_summary"]

SUMMARY_COLUMNS = (
    "quantity",
    "unit",
    "measured",
    "measured_err",
    "expected",
    "expected_err",
    "source",
    "measured_d_est_low",
    "measured_d_est_high",
    "measured_err_below",
    "measured_err_above",
)

SUMMARY_UNITS = {
    "quantity": "text",
    "unit": "text (unit of measured, expected and their errors)",
    "measured": "see unit",
    "measured_err": "1-sigma statistical error (correlations between lags included; empty "
                    "for an upper limit), see unit",
    "expected": "see unit",
    "expected_err": "1-sigma, from temperature and size uncertainties, see unit",
    "source": "text",
    "measured_d_est_low": "measured value with the rejection's D_est x 2/3, see unit",
    "measured_d_est_high": "measured value with the rejection's D_est x 4/3, see unit",
    "measured_err_below": "1-sigma error below the measured value (score interval: a "
                          "diffusion coefficient's error grows with it), see unit",
    "measured_err_above": "1-sigma error above the measured value, see unit",
}

NAN = float("nan")


def _row(quantity: str, unit: str, measured=NAN, err=NAN, expected=NAN, expected_err=NAN,
         source: str = "", low=NAN, high=NAN, below=NAN, above=NAN) -> dict[str, Any]:
    if not math.isfinite(below):
        below = err
    if not math.isfinite(above):
        above = err
    return dict(zip(SUMMARY_COLUMNS,
                    (quantity, unit, measured, err, expected, expected_err, source, low, high,
                     below, above), strict=True))


def _static_source(col: str, st: dict[str, float]) -> str:
    """Where a static parameter's value and spread come from (FitTable.static_summary)."""
    if st.get("held"):
        return (f"fit table '{col}' (held fixed in the final pass): the initial pass's robust "
                f"average +- robust spread (1.4826 MAD) over {int(st['count'])} frames")
    return f"fit table '{col}': median +- s.d. over {int(st['count'])} frames"


def summary_rows(result: AnalysisResult) -> list[dict[str, Any]]:
    """Rows of the summary table for the analysed model."""
    s = result.settings
    meas = result.measured
    pred = result.predictions
    rows: list[dict[str, Any]] = []
    static = result.trajectory.static
    factors = list(s.sensitivity_factors)

    def sens(key: str) -> tuple[float, float]:
        m = meas.get(key)
        if m is None or len(factors) < 2:
            return NAN, NAN
        lo = m.sensitivity.get(f"D_est x {factors[0]:.3g}", NAN)
        hi = m.sensitivity.get(f"D_est x {factors[-1]:.3g}", NAN)
        return lo, hi

    for key, label in (("a_um", "a"), ("b_um", "b")):
        if key in result.sizes:
            v, e, src = result.sizes[key]
            if src == "given":
                rows.append(_row(label, "nm", 1e3 * v, 1e3 * e, source="given"))
            else:
                col = src.split("'")[1]
                st = static[col]
                rows.append(_row(label, "nm", 1e3 * st["median"], 1e3 * st["std"],
                                 source=_static_source(col, st)))
    for col in ("n", "index", "n_core", "n_cap"):
        if col in static:
            st = static[col]
            rows.append(_row(col, "1", st["median"], st["std"], source=_static_source(col, st)))

    def with_pred(key: str, label: str, pkey: str | None, unit: str) -> None:
        m = meas.get(key)
        if m is None:
            return
        lo, hi = sens(key)
        below, above = m.sides()
        if pkey is not None and pkey in pred:
            p, _, src = pred[pkey]
            rows.append(_row(label, unit, m.value, m.error, p.value, p.error, src, lo, hi,
                             below, above))
        else:
            rows.append(_row(label, unit, m.value, m.error, source="", low=lo, high=hi,
                             below=below, above=above))

    recipe = recipe_for(s.model)
    for line in recipe.summary:
        if isinstance(line, Compared):
            with_pred(line.measured, line.label, line.prediction, line.unit)
        elif line.measured in meas:
            m = meas[line.measured]
            src = line.source
            if m.upper_limit:
                src += ": not resolved from zero, 95 % upper limit"
            rows.append(_row(line.label, m.unit, m.value, m.error, line.expected, source=src))
            rows[-1]["upper_limit"] = m.upper_limit
    radius = result.sizes.get("a_um")
    for key, label, src in (
        ("a_eff_t", "a_eff from D_t", "Stokes-Einstein radius of the measured D_t"),
        ("a_eff_r", "a_eff from D_r", "Stokes-Einstein-Debye radius of the measured D_r"),
    ):
        a_eff = meas.get(key)
        if a_eff is None:
            continue
        if recipe.radius_is_hydrodynamic and radius is not None:
            rows.append(_row(label, "nm", a_eff.value, a_eff.error, 1e3 * radius[0],
                             1e3 * radius[1], src + " vs fitted radius"))
        else:
            rows.append(_row(label, "nm", a_eff.value, a_eff.error, source=src))
    if result.consistency is not None:
        rows += consistency_rows(result.consistency)
    return rows


def consistency_rows(c: Consistency) -> list[dict[str, Any]]:
    """Rows of the physical-consistency check: each size test's size ratio, each test's
    p-value (``expected``: the p-value below which it fails) and the verdict."""
    rows: list[dict[str, Any]] = []
    thr = c.threshold
    for t in c.tests:
        failed = " -- FAILED" if t.name in c.failed else ""
        if t.name.startswith("size ") and "size_ratio" in t.values:
            rows.append(_row(f"check: hydrodynamic/optical size from {t.name[5:]}", "1",
                             t.values["size_ratio"], t.values["size_ratio_err"], 1.0,
                             source=f"(D_predicted / D_measured)^(1/e); z = "
                                    f"{t.statistic:+.2f}{failed}"))
        rows.append(_row(f"check: {t.name}", "p", t.p_value, expected=thr,
                         source=t.detail + failed))
    verdict = c.message if c.flagged else (
        f"consistent with the free Brownian motion of the fitted particle (every test "
        f"p >= {thr:.2g}, the rule that flags {100 * c.alpha:g} % of such tracks at most)")
    rows.append(_row("check: flagged", "1", float(c.flagged), source=verdict))
    return rows


#: sided errors are printed apart when they differ by more than this fraction
SIDED_SHOWN = 0.1


def _fmt(value: float, err: float, upper_limit: bool = False, below: float = NAN,
         above: float = NAN) -> str:
    if not math.isfinite(value):
        return "--"
    if upper_limit:
        return f"< {value:.2g}"
    if not math.isfinite(err) or err <= 1e-9 * abs(value):
        return f"{value:.4g}"
    digits = min(max(0, 1 - math.floor(math.log10(err))), 6)
    if (math.isfinite(below) and math.isfinite(above)
            and abs(above - below) > SIDED_SHOWN * err):
        return f"{value:.{digits}f} -{below:.{digits}f} +{above:.{digits}f}"
    return f"{value:.{digits}f} +- {err:.{digits}f}"


def format_report(result: AnalysisResult) -> str:
    """A short text report for the terminal."""
    s = result.settings
    traj = result.trajectory
    lines = [
        f"holofit analyze: {traj.source} ({s.model}, {s.temperature_c:g} +- "
        f"{s.temperature_err_c:g} C)",
        f"  frames {traj.first_frame}-{traj.first_frame + traj.n_frames - 1}: "
        f"{int(traj.valid.sum())} with a fit, {int((~traj.valid).sum())} gaps, "
        f"{int(result.valid.sum())} used; frame interval {traj.frame_interval_s:g} s",
    ]
    if s.subtract_drift:
        v, dv = result.drift_um_s, result.drift_err_um_s
        parts = ", ".join(_fmt(a, b) for a, b in zip(v, dv, strict=True))
        lines.append(f"  drift removed: ({parts}) um/s (end to end; the MSD fits allow for "
                     "its removal)")
    cl = result.cleaning
    if cl is not None:
        done: list[str] = []
        if s.head_tail:
            done.append(f"{int(cl.flipped.sum())} head-tail flips corrected")
        if s.reject and cl.estimate is not None:
            rej = next(iter(result.stats.values()))
            done.append(
                f"{int(cl.outliers.sum())} frames rejected, {int(rej.rejected[0])} pairs at lag 1"
                f" (P < {s.reject_probability:g}, D_est = {cl.estimate.d_est:.3g} 1/s "
                f"{cl.estimate.source}, eps_r = {cl.estimate.eps_r:.3g} rad)"
            )
        if done:
            lines.append("  cleaning: " + "; ".join(done))
    for key, f in result.fits.items():
        lines.append(
            f"  fit {key}: lags {f.lags[0]}-{f.lags[-1]} frames ({f.tau_s[0]:.3g}-"
            f"{f.tau_s[-1]:.3g} s), reduced chi2 {f.chi2_reduced:.2f}"
        )
    lines.append("")
    header = f"  {'quantity':<30} {'unit':<7} {'measured':>22} {'expected':>22}  source"
    lines.append(header)
    lines.append("  " + "-" * (len(header) + 10))
    for r in result.rows:
        measured = _fmt(r["measured"], r["measured_err"], r.get("upper_limit", False),
                        r["measured_err_below"], r["measured_err_above"])
        lines.append(
            f"  {r['quantity']:<30} {r['unit']:<7} {measured:>22}"
            f" {_fmt(r['expected'], r['expected_err']):>22}  {r['source']}"
        )
    sens = {k: m for k, m in result.measured.items() if m.sensitivity}
    if sens:
        labels = list(next(iter(sens.values())).sensitivity)
        lines.append("")
        lines.append(f"  sensitivity to the rejection's D_est ({' / '.join(labels)}):")
        for key, m in sens.items():
            alt = " / ".join(f"{m.sensitivity[k]:.4g}" for k in labels)
            lines.append(f"    {key:<14} {alt}  (nominal {m.value:.4g} +- {m.error:.2g})")
    for note in result.notes:
        lines.append(f"  note: {note}")
    return "\n".join(lines)


def write_summary(
    result: AnalysisResult, out_dir: str | Path, inputs: list[str | Path] | None = None,
    prefix: str = "",
) -> dict[str, Path]:
    """Write ``summary.csv`` (+ sidecar), ``summary.json`` and ``msd.csv`` (every lag
    statistic), each name after ``prefix`` (one track of several: ``particle_<id>_``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = result.summary()
    meta = sidecar(kind="diffusion analysis summary", units=SUMMARY_UNITS,
                   config=doc["settings"], inputs=inputs)
    write_json(out / f"{prefix}summary.json", {**meta, "analysis": doc})
    frames = []
    for name, st in result.stats.items():
        frames.append(pd.DataFrame({
            "observable": name, "lag_frames": st.lags, "tau_s": st.tau_s, "mean": st.mean,
            "sem": st.sem, "pairs": st.count, "rejected_pairs": st.rejected,
            "error_plateau": st.converged,
        }))
    msd_units = {"observable": "text", "lag_frames": "frames", "tau_s": "s",
                 "mean": "um^2 (MSDs), 1 (orient, proj)", "sem": "same as mean",
                 "pairs": "count", "rejected_pairs": "count", "error_plateau": "bool"}
    msd = write_table(out / f"{prefix}msd.csv", pd.concat(frames, ignore_index=True),
                      sidecar(kind="lag statistics", units=msd_units, inputs=inputs))
    # the last file written: make waits for it
    csv = write_table(out / f"{prefix}summary.csv",
                      pd.DataFrame(result.rows, columns=SUMMARY_COLUMNS), meta)
    return {"summary_csv": csv, "summary_json": out / f"{prefix}summary.json", "msd_csv": msd}
