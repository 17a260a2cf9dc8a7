"""Measured holograms fitted with and without the objective lens (not part of `make bench`).

    python bench/validate_lens_realdata.py --out /tmp/lens_realdata [--only NAME ...]
                                           [--skip-dimer] [--dimer-only]

Spheres (HoloPy ``image0001`` and ``image01``; pylorenzmie ``PS_silica`` silica and PS,
``image0400`` and ``image0010`` both spheres, ``sample`` lower-left): each frame goes through
``holofit crop`` (``run_crop``: ``--normalized`` where the data are stored background-divided,
else the background frames and dark level) and ``holofit prefit`` (``run_prefit``, no manual
guess) with

- the ideal model (``--numerical-aperture none``),
- the lens at NA 1.2, 1.3 and 1.45 (fixed; 1.45 collects every propagating wave in water),
- the NA fitted (``--fit-na`` from 1.2),
- the instrument's own NA where it has one (pylorenzmie's 0.86, measured from these data),

and an NA profile (the prefit at fixed NAs from 0.3 up: does the misfit fall at low NA, i.e.
do the data's fringes fade faster than the model's?). For every fit: R^2, reduced chi^2,
z, radius, index, alpha (and NA), against the published or independent reference fits of the
data READMEs. The fringe envelope: the gain ``g`` of the data's fringes over the model's,
``data - 1 ~ g (model - 1)`` by least squares in rings about the fitted centre, against the NA
whose aperture angle the ring's geometric angle reaches (``n_medium sin(atan(rho / z))``): a
gain that falls with the ring says the data's fringes fade faster than the model's.

The dimer (HoloPy ``dimer2011``): crop, prefit, ``holofit library``, and ``holofit fit --pass
initial --initial-frames 1`` with ``--fix gap_um`` and without, ideal and through the lens (NA
1.2 fixed, NA fitted), against the 2011 T-matrix fit. Each DDA fit takes minutes.

Writes ``report.md`` (tables), ``report.json`` (every row), per case ``<case>_compare.png``
(data; residuals of the ideal model, NA 1.2 and the fitted NA; radial profiles; fringe envelope)
and ``<case>_na_profile.png``, and the stages' own outputs (tables, ``frames/*.png`` data /
model / residual pictures) under ``<case>/``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from holofit.batch import BatchSettings
from holofit.batch.aperture import FROM_INSTRUMENT
from holofit.batch.errors import BatchError
from holofit.config import load_instrument, load_particle, resolve_config
from holofit.crop import CropConfig, run_crop
from holofit.fit.config import FitConfig
from holofit.fit.stage import run_fit
from holofit.holomodel.pictures import model_image
from holofit.library.stage import run_library
from holofit.particles import Sphere
from holofit.prefit.profile import radial_profile
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.prefit.stage import run_prefit
from holofit.scattering.mie import LorenzMie
from holofit.tables.cropset import CropSet

ROOT = Path(__file__).resolve().parents[1]
HOLOPY = ROOT / "tests" / "data" / "holopy"
PYLM = ROOT / "tests" / "data" / "pylorenzmie"
SERIAL = BatchSettings(workers=0, progress=False)

#: the fixed apertures compared with the ideal model
FIXED_NA = (1.2, 1.3, 1.45)
#: the NA profile
PROFILE_NA = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.45)


@dataclass(frozen=True)
class Case:
    """One measured sphere."""

    name: str
    movie: Path
    instrument: str
    size: int
    normalized: bool = True
    background: tuple[Path, ...] = ()
    dark: Any = None
    start: tuple[float, float] | None = None
    fix_alpha: float | None = None
    reference: dict[str, float] = field(default_factory=dict)
    source: str = ""


def _um(px: float) -> float:
    return px * 0.048


CASES = [
    Case("image0001", HOLOPY / "image0001.tif", "holopy_image0001", 100,
         reference=dict(x_um=5.792, y_um=5.534, z_um=14.15, radius_um=0.6484, n=1.582,
                        alpha=0.6497),
         source="HoloPy test_nmpfit gold_sphere (x = HoloPy's y)"),
    Case("image01", HOLOPY / "image01.tif", "holopy_image01", 200, normalized=False,
         background=tuple(HOLOPY / f"bg0{k}.tif" for k in (1, 2, 3)),
         dark=(HOLOPY / "df01.tif",),
         reference=dict(x_um=21.843, y_um=24.170, z_um=16.63, radius_um=0.557, n=1.58,
                        alpha=0.706),
         source="independent re-fit in the data README (n held at 1.58)"),
    Case("PS_silica_silica", PYLM / "PS_silica.tif", "pylorenzmie", 301, start=(908.5, 484.0),
         fix_alpha=1.0,
         reference=dict(z_um=_um(179.284), radius_um=0.4976, n=1.4255),
         source="pylorenzmie TestFrame notebook (2021)"),
    Case("PS_silica_PS", PYLM / "PS_silica.tif", "pylorenzmie", 301, start=(376.9, 481.3),
         fix_alpha=1.0,
         reference=dict(z_um=_um(181.399), radius_um=0.7707, n=1.5602),
         source="pylorenzmie TestFrame notebook (2021)"),
    Case("image0400_left", PYLM / "image0400.tif", "pylorenzmie", 301, start=(583.1, 685.3),
         fix_alpha=1.0,
         reference=dict(z_um=_um(217.7), radius_um=1.1816, n=1.3923),
         source="pylorenzmie TestFrame notebook (2021)"),
    Case("image0400_right", PYLM / "image0400.tif", "pylorenzmie", 301, start=(884.4, 747.0),
         fix_alpha=1.0,
         reference=dict(z_um=_um(112.8), radius_um=1.2226, n=1.3936),
         source="pylorenzmie TestFrame notebook (2021)"),
    Case("image0010_left", PYLM / "image0010.tif", "pylorenzmie", 301, start=(562.3, 720.2),
         fix_alpha=1.0,
         reference=dict(z_um=_um(543.2), radius_um=1.213, n=1.402),
         source="independent lm re-fit in the data README"),
    Case("image0010_right", PYLM / "image0010.tif", "pylorenzmie", 301, start=(920.5, 732.1),
         fix_alpha=1.0,
         reference=dict(z_um=_um(540.5), radius_um=1.207, n=1.405),
         source="independent lm re-fit in the data README"),
    Case("sample_lower_left", PYLM / "sample.tif", "pylorenzmie", 301, normalized=False,
         background=(PYLM / "background.tif",), dark=13.0, start=(322.3, 733.0), fix_alpha=1.0,
         reference=dict(z_um=_um(225.2), radius_um=0.847, n=1.441),
         source="independent lm re-fit in the data README"),
]

CONFIGS: list[tuple[str, Any, bool]] = [("ideal", None, False)] + [
    (f"NA {na:g}", na, False) for na in FIXED_NA] + [("NA fitted", 1.2, True)]
#: for instruments with an NA of their own (pylorenzmie's measured 0.86)
INSTRUMENT_CONFIG: tuple[str, Any, bool] = ("instrument NA", FROM_INSTRUMENT, False)
#: for data whose published model has alpha = 1 (pylorenzmie): the same with alpha free too
ALPHA_CONFIGS: list[tuple[str, Any, bool]] = [("ideal, alpha free", None, False),
                                              ("NA fitted, alpha free", 1.2, True)]


def _crop(case: Case, out: Path) -> Path:
    crops = out / "crops"
    if not (crops / "crops.csv").exists():
        run_crop(case.movie, None if case.normalized else list(case.background), case.instrument,
                 crops, CropConfig(normalized=case.normalized, dark=case.dark, size=case.size,
                                   follow="nearest" if case.start else "strongest",
                                   start=case.start, plot=False))
    return crops


def _prefit(case: Case, crops: Path, out: Path, label: str, na: Any, fit_na: bool
            ) -> dict[str, Any]:
    folder = out / ("prefit_" + label.replace(" ", "_").replace(",", "").replace(".", "p"))
    t0 = time.perf_counter()
    fix_alpha = None if "alpha free" in label else case.fix_alpha
    fit = SphereFitSettings(fix_alpha=fix_alpha, fit_na=fit_na)
    try:  # the same settings as a finished earlier run: its table is kept
        result = run_prefit(crops, folder, fit=fit, batch=SERIAL, numerical_aperture=na,
                            plot=True, plot_frames=[0])
    except BatchError:  # other settings: start again
        result = run_prefit(crops, folder, fit=fit, numerical_aperture=na, plot=True,
                            plot_frames=[0],
                            batch=BatchSettings(workers=0, progress=False, overwrite=True))
    row = pd.read_csv(result.table).iloc[0].to_dict()
    row.update(config=label, na=na, wall_s=time.perf_counter() - t0, folder=str(folder))
    return row


def _envelope(data: np.ndarray, model: np.ndarray, centre_rc: tuple[float, float],
              z_um: float, px: float, n_medium: float, n_rings: int = 8
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fringe gain of the data over the model in rings about the centre.

    In each ring the data's fringes are fitted as a multiple of the model's,
    ``data - 1 ~ g (model - 1)``: ``g < 1`` where the data's fringes are weaker. Returns the
    rings' mean radius (um), the NA their geometric angle reaches, and ``g``.
    """
    rows, cols = np.indices(data.shape)
    r = np.hypot(rows - centre_rc[0], cols - centre_rc[1])
    ok = np.isfinite(data)
    edges = np.linspace(2.0, min(data.shape) / 2, n_rings + 1)
    reach, gain, rho = [], [], []
    for lo, hi in itertools.pairwise(edges):
        ring = ok & (r >= lo) & (r < hi)
        if ring.sum() < 20:
            continue
        d = data[ring] - 1.0
        m = model[ring] - 1.0
        rr = 0.5 * (lo + hi) * px
        rho.append(rr)
        reach.append(n_medium * rr / math.hypot(rr, z_um))
        gain.append(float(d @ m / (m @ m)) if m @ m > 0 else math.nan)
    return np.array(rho), np.array(reach), np.array(gain)


def _model(crops: CropSet, row: dict[str, Any], optics) -> np.ndarray:
    crow = crops.row(0)
    data = crops.crop(0)
    px = crops.instrument.pixel_size_um  # type: ignore[union-attr]
    return model_image(row, Sphere(1.0, 1.5), LorenzMie(), optics, data.shape,
                       (int(crow["corner_row"]), int(crow["corner_col"])), px)


def _profile(case: Case, crops: Path) -> list[dict[str, float]]:
    """Prefit at fixed NAs (the ideal model last): R^2 and reduced chi^2 against NA."""
    out = []
    with CropSet(crops) as cs:
        inst = cs.instrument
        crow = cs.row(0)
        data = cs.crop(0).astype(float)
        corner = (int(crow["corner_row"]), int(crow["corner_col"]))
        centre = (float(crow["x_um"]), float(crow["y_um"]))
    for na in (*PROFILE_NA, None):
        optics = inst.with_numerical_aperture(na).optics  # type: ignore[union-attr]
        fit = fit_sphere_crop(data, corner, centre, optics, inst.pixel_size_um,  # type: ignore
                              SphereFitSettings(fix_alpha=case.fix_alpha), seed=0)
        out.append(dict(na=math.nan if na is None else na, r2=fit.r2, chi2_red=fit.chi2_red,
                        z_um=fit.values["z_um"], radius_um=fit.values["radius_um"],
                        n=fit.values["n"], status=fit.status))
    return out


def run_sphere(case: Case, out_root: Path) -> dict[str, Any]:
    out = out_root / case.name
    out.mkdir(parents=True, exist_ok=True)
    crops = _crop(case, out)
    configs = list(CONFIGS)
    if load_instrument(resolve_config(case.instrument, "instruments")).optics.numerical_aperture:
        configs.append(INSTRUMENT_CONFIG)
    configs += ALPHA_CONFIGS if case.fix_alpha is not None else []
    rows = [_prefit(case, crops, out, label, na, fit_na) for label, na, fit_na in configs]
    profile = _profile(case, crops)
    envelope = _figures(case, crops, rows, profile, out_root)
    return {"case": case.name, "source": case.source, "reference": case.reference,
            "rows": rows, "profile": profile, "envelope": envelope}


def _figures(case: Case, crops_dir: Path, rows: list[dict[str, Any]],
             profile: list[dict[str, float]], out_root: Path) -> dict[str, Any]:
    """Draw ``<case>_compare.png``; returns the fringe envelopes (reach, gain) by model."""
    by = {r["config"]: r for r in rows}
    with CropSet(crops_dir) as crops:
        inst = crops.instrument
        assert inst is not None
        px = inst.pixel_size_um
        crow = crops.row(0)
        data = crops.crop(0).astype(float)
        shown = [("ideal", None), ("NA 1.2", 1.2), ("NA fitted", 1.2)]
        models = {}
        for label, na in shown:
            row = by[label]
            models[label] = _model(crops, row, inst.with_numerical_aperture(na).optics)
    fig, ax = plt.subplots(2, 4, figsize=(18, 9))
    vmax = np.nanpercentile(np.abs(data - 1), 99)
    ax[0, 0].imshow(data, cmap="gray", vmin=1 - vmax, vmax=1 + vmax)
    ax[0, 0].set_title(f"{case.name}: data")
    res_max = np.nanpercentile(np.abs(data - models["ideal"]), 99)
    for k, (label, _) in enumerate(shown):
        row = by[label]
        res = np.where(np.isfinite(data), data - models[label], np.nan)
        ax[0, k + 1].imshow(res, cmap="RdBu_r", vmin=-res_max, vmax=res_max)
        na_text = (f", NA {row['numerical_aperture']:.3f}" if label == "NA fitted" else "")
        ax[0, k + 1].set_title(f"residual, {label}{na_text}\nR^2 {row['r2']:.4f}, "
                               f"chi2_red {row['chi2_red']:.3g}")
    row = by["ideal"]
    centre_rc = (row["y_um"] / px - crow["corner_row"], row["x_um"] / px - crow["corner_col"])
    valid = np.isfinite(data)
    n_bins = min(data.shape) // 2 - 1
    rho_px = np.arange(n_bins) + 0.5
    ax[1, 0].plot(rho_px * px, radial_profile(data, valid, centre_rc, n_bins).mean, "k-",
                  lw=1.5, label="data")
    for label, _ in shown:
        ax[1, 0].plot(rho_px * px, radial_profile(np.where(valid, models[label], np.nan), valid,
                                                  centre_rc, n_bins).mean, lw=1, label=label)
    ax[1, 0].set_xlabel("rho (um)")
    ax[1, 0].set_ylabel("azimuthal mean")
    ax[1, 0].legend(fontsize=8)
    for label, _ in shown:
        res = np.where(valid, (data - models[label]) ** 2, np.nan)
        prof = radial_profile(res, valid, centre_rc, n_bins).mean
        ax[1, 1].plot(rho_px * px, np.sqrt(prof), lw=1, label=label)
    ax[1, 1].set_xlabel("rho (um)")
    ax[1, 1].set_ylabel("rms residual in the ring")
    ax[1, 1].legend(fontsize=8)
    envelope = {}
    for label, _ in shown:
        rho, reach, gain = _envelope(data, models[label], centre_rc, by[label]["z_um"], px,
                                     inst.medium_index)
        envelope[label] = {"rho_um": rho.tolist(), "reach_na": reach.tolist(),
                           "gain": gain.tolist()}
        ax[1, 2].plot(reach, gain, "o-", ms=3, label=label)
    ax[1, 2].axhline(1.0, color="k", lw=0.5)
    ax[1, 2].set_xlabel("n_medium sin(theta) reached by the ring")
    ax[1, 2].set_ylabel("fringe gain g: data - 1 ~ g (model - 1)")
    ax[1, 2].set_title("fringe envelope, data over model, by ring")
    ax[1, 2].legend(fontsize=8)
    nas = [p["na"] for p in profile if math.isfinite(p["na"])]
    r2 = [p["r2"] for p in profile if math.isfinite(p["na"])]
    ideal_r2 = next(p["r2"] for p in profile if not math.isfinite(p["na"]))
    ax[1, 3].plot(nas, r2, "o-", label="lens, NA fixed")
    ax[1, 3].axhline(ideal_r2, color="k", ls="--", label="ideal model")
    fitted = by["NA fitted"]
    ax[1, 3].errorbar([fitted["numerical_aperture"]], [fitted["r2"]],
                      xerr=[fitted["d_numerical_aperture"]], fmt="rs", label="NA fitted")
    ax[1, 3].set_xlabel("numerical aperture")
    ax[1, 3].set_ylabel("R^2")
    ax[1, 3].set_title("R^2 against the objective's NA")
    ax[1, 3].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_root / f"{case.name}_compare.png", dpi=80)
    plt.close(fig)
    return envelope


# -- the dimer --------------------------------------------------------------------------

DIMER_REFERENCE = dict(x_um=17.39, y_um=17.00, z_um=20.93, radius1_um=0.6857, radius2_um=0.6964,
                       n1=1.6026, n2=1.6026)
DIMER_CONFIGS: list[tuple[str, Any, bool, tuple[str, ...]]] = [
    ("ideal, gap fixed", None, False, ("gap_um",)),
    ("ideal, gap free", None, False, ()),
    ("NA 1.2, gap fixed", 1.2, False, ("gap_um",)),
    ("NA 1.45, gap fixed", 1.45, False, ("gap_um",)),
    ("NA fitted, gap fixed", 1.2, True, ("gap_um",)),
]


def run_dimer(out_root: Path, configs: list[str] | None = None) -> dict[str, Any]:
    out = out_root / "dimer2011"
    out.mkdir(parents=True, exist_ok=True)
    inst = load_instrument(resolve_config("holopy_dimer2011", "instruments"))
    particle = load_particle(resolve_config("dimer_holopy2011", "particles"))
    crops = out / "crops"
    if not (crops / "crops.csv").exists():
        run_crop(HOLOPY / "dimer2011.tif", None, inst, crops,
                 CropConfig(normalized=True, size=100, plot=False))
    prefit = out / "prefit"
    if not (prefit / "prefit.csv").exists():
        run_prefit(crops, prefit, batch=SERIAL, plot=False)
    library = out / "library"
    if not (library / "library.csv").exists():
        run_library(crops, prefit, particle, library, batch=SERIAL, plot=False)
    rows = []
    for label, na, fit_na, fixed in DIMER_CONFIGS:
        if configs and label not in configs:
            continue
        folder = out / ("fit_" + label.replace(" ", "_").replace(",", "").replace(".", "p"))
        table = folder / "initial.csv"
        t0 = time.perf_counter()
        if not table.exists():
            config = FitConfig(particle, passes="initial", initial_frames=1, fixed=fixed,
                               plot=True, numerical_aperture=na, fit_na=fit_na)
            run_fit(crops, prefit, library, folder, config, batch=SERIAL)
        row = pd.read_csv(table).iloc[0].to_dict()
        row.update(config=label, wall_s=time.perf_counter() - t0, folder=str(folder))
        rows.append(row)
        print(
            f"dimer {label}: R^2 {row['r2']:.4f}, {row['status']} ({row['wall_s']:.0f} s)",
            flush=True,
        )
    return {
        "case": "dimer2011",
        "reference": DIMER_REFERENCE,
        "source": "HoloPy 2011 test_fit gold_dimerslow (T-matrix; x = HoloPy's y)",
        "rows": rows,
    }


# -- the report -------------------------------------------------------------------------


def _f(v: Any, spec: str) -> str:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return ""
    return "" if not math.isfinite(x) else format(x, spec)


def _sphere_table(result: dict[str, Any]) -> list[str]:
    ref = result["reference"]
    lines = [
        f"### {result['case']}",
        "",
        "| model | R^2 | chi2_red | z (um) | radius (um) | n | alpha | NA | status |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    lines.append(
        f"| reference ({result['source']}) | | | {_f(ref.get('z_um'), '.3f')} | "
        f"{_f(ref.get('radius_um'), '.4f')} | {_f(ref.get('n'), '.4f')} | "
        f"{_f(ref.get('alpha'), '.3f')} | | |"
    )
    for r in result["rows"]:
        na = (
            f"{r['numerical_aperture']:.3f} ± {r['d_numerical_aperture']:.3f}"
            if r["config"].startswith("NA fitted")
            else ""
        )
        lines.append(
            f"| {r['config']} | {_f(r['r2'], '.5f')} | {_f(r['chi2_red'], '.3f')} | "
            f"{_f(r['z_um'], '.3f')} | {_f(r['radius_um'], '.4f')} | "
            f"{_f(r['n'], '.4f')} | {_f(r['alpha'], '.3f')} | {na} | {r['status']} |"
        )
    prof = result["profile"]
    lines += [
        "",
        "NA profile (prefit at fixed NA; R^2): "
        + ", ".join(
            f"{'ideal' if not math.isfinite(p['na']) else format(p['na'], 'g')}: {p['r2']:.4f}"
            for p in prof
        ),
        "",
    ]
    for label, env in result.get("envelope", {}).items():
        lines.append(
            f"Fringe gain g by ring ({label}; ring reaches NA -> g): "
            + ", ".join(
                f"{a:.2f} -> {g:.3f}" for a, g in zip(env["reach_na"], env["gain"], strict=True)
            )
        )
    return [*lines, ""]


def _dimer_table(result: dict[str, Any]) -> list[str]:
    ref = result["reference"]
    cols = ("x_um", "y_um", "z_um", "radius1_um", "radius2_um", "gap_um", "n1", "n2", "alpha")
    lines = [
        "### dimer2011 (DDA fit, initial pass, one frame)",
        "",
        "| model | R^2 | chi2_red | " + " | ".join(cols) + " | NA | status | time (s) |",
        "| --- " * (len(cols) + 6) + "|",
    ]
    lines.append(
        f"| reference ({result['source']}) | | | "
        + " | ".join(_f(ref.get(c), ".4f") for c in cols)
        + " | | | |"
    )
    for r in result["rows"]:
        na = (
            f"{r['numerical_aperture']:.3f} ± {r['d_numerical_aperture']:.3f}"
            if "numerical_aperture" in r
            else ""
        )
        lines.append(
            f"| {r['config']} | {_f(r['r2'], '.4f')} | {_f(r['chi2_red'], '.3f')} | "
            + " | ".join(_f(r.get(c), ".4f") for c in cols)
            + f" | {na} | {r['status']} | {_f(r['fit_time_s'], '.0f')} |"
        )
    return [*lines, ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--only", nargs="*", default=None, help="sphere cases to run")
    ap.add_argument("--skip-dimer", action="store_true")
    ap.add_argument("--dimer-only", action="store_true")
    ap.add_argument("--dimer-configs", nargs="*", default=None)
    args = ap.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    report_json = out / "report.json"

    def record(name: str, result: dict[str, Any]) -> dict[str, Any]:
        # re-read first: another run (the dimer) may have written meanwhile
        results = json.loads(report_json.read_text()) if report_json.exists() else {}
        results[name] = result
        report_json.write_text(json.dumps(results, indent=1, default=str))
        return results

    if not args.dimer_only:
        for case in CASES:
            if args.only and case.name not in args.only:
                continue
            t0 = time.perf_counter()
            result = run_sphere(case, out)
            best = max(result["rows"], key=lambda r: r["r2"])
            print(
                f"{case.name}: done in {time.perf_counter() - t0:.0f} s; best R^2 "
                f"{best['r2']:.4f} ({best['config']})",
                flush=True,
            )
            record(case.name, result)
    if not args.skip_dimer:
        record("dimer2011", run_dimer(out, args.dimer_configs))
    results = json.loads(report_json.read_text()) if report_json.exists() else {}
    order = [c.name for c in CASES] + ["dimer2011"]
    results = {k: results[k] for k in order if k in results}
    lines = ["# Measured holograms with and without the objective lens", ""]
    for name, result in results.items():
        lines += _dimer_table(result) if name == "dimer2011" else _sphere_table(result)
    (out / "report.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
