"""``holofit calibrate`` on a simulated 100-frame sphere movie and on the measured pylorenzmie
and HoloPy spheres (issue #38 item 2's must-shows; not part of ``make bench``).

    python bench/calibrate_study.py [--json PATH] [--work DIR]
                                    [--only sim pulls pylorenzmie holopy]
                                    [--pulls K] [--max-frames N]

``sim``: 100 frames of a 1 um polystyrene sphere at heights 5-25 um (evenly spread, shuffled,
x and y jittered by 0.3 um) through the paper's 60x water objective with an effective NA of
1.15 and the spherical aberration of a coverslip 5 um thicker than designed
(``layer_aberration`` over the NA 1.15 pupil: (-4.50, 10.64) rad; docs/validation/aberration.md
section 1), 8-bit camera noise, 50 background frames;
``holofit crop`` (140-pixel crops, the paper's), ``holofit prefit`` with the paper's instrument
file (NA 1.2, no aberration) and ``holofit calibrate`` (its defaults: 20 frames chosen over
the heights; with ``--max-frames 100`` all). Reported: each fitted quantity, its error and its
pull ``(fitted - truth) / error``; chi^2 per pixel before and after.

``pulls``: the configuration of tests/test_calibrate_stage.py (NA 0.9, 10 um glass, 64-pixel
crops, 14 frames of which 10 are fitted) over ``--pulls`` camera-noise seeds: the pulls' mean
and standard deviation (honest errors: 0 and 1, each within about ``1/sqrt(K)``).

``pylorenzmie``: the seven measured spheres (4 images, one microscope) cropped one by one by
``holofit crop`` (301 pixels, ``--normalized`` or background-divided, saturated pixels masked;
the centres of bench/aberration_realdata.py), gathered into one crop folder (frame k = sphere
k), ``holofit prefit`` with the instrument file (NA 0.86) and ``holofit calibrate`` (about a
third of each crop's pixels): chi^2 per pixel before and after, and each sphere's z, radius and
index before and after next to the published or re-fitted values of the data README.

``holopy``: HoloPy's two sphere images (two set-ups, one height each) through the same
commands, each alone: ``holofit crop`` (image0001 ``--normalized``, 100 pixels; image01 divided
by its three backgrounds, 200 pixels), ``holofit prefit`` and ``holofit calibrate
--no-fit-na`` (the coefficients only, the NA held at the instrument files' assumed 1.4). A
single height cannot tell the pupil phase from the height (docs/validation/aberration.md
section 6): these are the stage's numbers on real single frames, not calibrations of those
microscopes.

Writes a flat JSON ``name -> number``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from holofit.aberration import layer_aberration
from holofit.batch import BatchSettings
from holofit.calibrate.stage import CalibrateConfig, run_calibrate
from holofit.config import Instrument, load_instrument
from holofit.crop import CropConfig, run_crop
from holofit.io.tables import write_table
from holofit.io.tiffstack import TiffStackWriter
from holofit.particles import Sphere
from holofit.prefit import run_prefit
from holofit.provenance import sidecar
from holofit.simulate.holograms import Exposure, simulate_movie
from holofit.tables.cropset import CropSet

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from aberration_realdata import HOLOPY, PYLM, PYLM_SPHERES  # noqa: E402

SERIAL = BatchSettings(workers=0, progress=False)
#: background frames of a simulated movie (their median divides every frame, as the crop
#: stage does): 50 make its noise, common to every frame, small beside a frame's own
N_BACKGROUND = 50


def _pulls(values: dict, errors: dict, truth: dict) -> dict[str, float]:
    return {k: (values[k] - v) / errors[k] for k, v in truth.items()}


def _edge(aberration, na: float, n_medium: float) -> float:
    return float(aberration.phase(np.array([np.arcsin(min(na / n_medium, 1.0))]))[0])


def _movie(root: Path, truth: Instrument, start: Instrument, n: int, size: int,
           frame: int, seed: int, n_background: int = N_BACKGROUND) -> None:
    """A sphere movie over 5-25 um through ``truth``, cropped and prefitted with ``start``."""
    rng = np.random.default_rng(seed)
    z = np.linspace(5.0, 25.0, n)
    rng.shuffle(z)
    c = frame / 2 * truth.pixel_size_um
    pos = np.c_[c + rng.normal(0, 0.3, n), c + rng.normal(0, 0.3, n), z]
    sim = simulate_movie(Sphere(0.5, 1.59), truth, pos, (frame, frame), out_dir=root / "sim",
                         exposure=Exposure(n_background=n_background), seed=seed)
    run_crop(sim.movie, sim.background, start, root / "crop", CropConfig(size=size, plot=False))
    run_prefit(root / "crop", root / "prefit", batch=SERIAL, plot=False)


def simulated(work: Path, max_frames: int) -> dict[str, float]:
    """The 100-frame movie through the paper's 60x water objective (module docstring)."""
    paper = load_instrument("paper_60x_water")
    na_true = 1.15
    ab, _ = layer_aberration(0.66, 1.33, na_true, 1.523, 5.0)
    truth = paper.with_numerical_aperture(na_true).with_aberration(ab)
    root = work / "sim100"
    t_prefit = math.nan  # reused from an earlier run
    if not (root / "prefit" / "prefit.csv").exists():
        t0 = time.perf_counter()
        _movie(root, truth, paper, 100, 140, 256, seed=11)
        t_prefit = time.perf_counter() - t0
    run = run_calibrate(root / "crop", root / "prefit", root / f"cal{max_frames}",
                        CalibrateConfig(max_frames=max_frames), batch=SERIAL)
    fit = run.fit
    key = "calibrate_sim100" if max_frames == 20 else f"calibrate_sim100_{max_frames}frames"
    want = {"numerical_aperture": na_true, **ab.values()}
    out = {f"{key}_frames_fitted": float(len(run.keys)),
           **({f"{key}_simulate_crop_prefit_s": t_prefit} if t_prefit == t_prefit else {}),
           f"{key}_calibrate_s": run.time_s,
           f"{key}_chi2_red": fit.chi2_red,
           f"{key}_chi2_per_px_before": run.chi2_before,
           f"{key}_chi2_per_px_after": run.chi2_after,
           f"{key}_ok": float(fit.status == "ok")}
    for name, pull in _pulls(fit.values, fit.errors, want).items():
        out[f"{key}_{name}"] = fit.values[name]
        out[f"{key}_{name}_error"] = fit.errors[name]
        out[f"{key}_{name}_true"] = want[name]
        out[f"{key}_{name}_pull"] = pull
    edge = _edge(ab, na_true, 1.33)
    out.update({f"{key}_edge_phase_rad": fit.edge_phase_rad,
                f"{key}_edge_phase_error_rad": fit.edge_phase_error_rad,
                f"{key}_edge_phase_true_rad": edge,
                f"{key}_edge_phase_pull": (fit.edge_phase_rad - edge) / fit.edge_phase_error_rad})
    table = pd.read_csv(run.table)
    for when in ("before", "after"):
        for col, true in (("radius_um", 0.5), ("n", 1.59)):
            dev = table[f"{col}_{when}"] - true
            out[f"{key}_{col}_{when}_mean_dev"] = float(dev.mean())
            out[f"{key}_{col}_{when}_rms_dev"] = float(np.sqrt((dev**2).mean()))
    return out


def pulls(work: Path, seeds: int, n_background: int = N_BACKGROUND) -> dict[str, float]:
    """The test's configuration over ``seeds`` noise draws (module docstring); with
    ``n_background`` background frames (their median divides every frame: its noise is common
    to all the frames, which the joint fit's errors do not model)."""
    na_true = 0.9
    ab, _ = layer_aberration(0.66, 1.33, na_true, 1.523, 10.0)

    def inst(na: float, aberration=None) -> Instrument:
        extra = {"numerical_aperture": na}
        if aberration is not None:
            extra["spherical_aberration_rad"] = list(aberration.spherical)
        return Instrument("dipping-0.9", 0.66, 1.33, 0.1767, extra=extra)

    want = {"numerical_aperture": na_true, **ab.values()}
    edge = _edge(ab, na_true, 1.33)
    rows = []
    for seed in range(seeds):
        root = work / (f"pulls{seed}" if n_background == N_BACKGROUND
                       else f"pulls{seed}_bg{n_background}")
        if not (root / "prefit" / "prefit.csv").exists():
            _movie(root, inst(na_true, ab), inst(0.95), 14, 64, 128, seed=100 + seed,
                   n_background=n_background)
        run = run_calibrate(root / "crop", root / "prefit", root / "cal",
                            CalibrateConfig(max_frames=10, plot=False), batch=SERIAL)
        p = _pulls(run.fit.values, run.fit.errors, want)
        p["edge_phase"] = (run.fit.edge_phase_rad - edge) / run.fit.edge_phase_error_rad
        print(f"  pulls seed {seed}: " + ", ".join(f"{k} {v:+.2f}" for k, v in p.items())
              + f" ({run.time_s:.0f} s)", flush=True)
        rows.append(p)
    table = pd.DataFrame(rows)
    key = "calibrate_pulls" + ("" if n_background == N_BACKGROUND else f"_bg{n_background}")
    out = {f"{key}_seeds": float(seeds)}
    for col in table.columns:
        out[f"{key}_{col}_mean"] = float(table[col].mean())
        out[f"{key}_{col}_sd"] = float(table[col].std(ddof=1))
        out[f"{key}_{col}_within_2sigma_fraction"] = float((table[col].abs() < 2).mean())
    return out


def _gather(folders: list[Path], out: Path, instrument: Instrument) -> Path:
    """One crop folder of the single-crop folders ``folders`` (frame k = folder k)."""
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with TiffStackWriter(out / "crops.tif", {"holofit": "crops (gathered)"}) as writer:
        for k, folder in enumerate(folders):
            with CropSet(folder) as crops:
                key = crops.keys[0]
                writer.write(crops.crop(key))
                row = crops.row(key)
            row.update(frame=k, particle=0, source=str(folder))
            rows.append(row)
    write_table(out / "crops.csv", pd.DataFrame(rows),
                sidecar(kind="crop table (the crop stage's crops of several images, gathered)",
                        config={"instrument": instrument.as_dict()},
                        inputs=[f / "crops.csv" for f in folders]))
    return out


def pylorenzmie(work: Path) -> dict[str, float]:
    """The seven measured spheres (module docstring)."""
    inst = load_instrument("pylorenzmie")
    root = work / "pylorenzmie"
    folders = []
    for s in PYLM_SPHERES:
        folder = root / "single" / s.name
        if not (folder / "crops.csv").exists():
            raw = s.image == "sample"
            run_crop(PYLM / f"{s.image}.tif", [PYLM / "background.tif"] if raw else None, inst,
                     folder, CropConfig(normalized=not raw, dark=13.0 if raw else None,
                                        size=s.size, follow="nearest", start=s.centre_px,
                                        plot=False))
        folders.append(folder)
    crops = _gather(folders, root / "crop", inst)
    run_prefit(crops, root / "prefit", plot=False,
               batch=BatchSettings(workers=0, progress=False, overwrite=True))
    n_px = 301 * 301
    run = run_calibrate(crops, root / "prefit", root / "cal",
                        CalibrateConfig(max_pixels=int(0.35 * n_px)), batch=SERIAL)
    fit = run.fit
    out = {"calibrate_pylm_frames": float(len(run.keys)),
           "calibrate_pylm_chi2_per_px_before": run.chi2_before,
           "calibrate_pylm_chi2_per_px_after": run.chi2_after,
           "calibrate_pylm_chi2_red": fit.chi2_red,
           "calibrate_pylm_edge_phase_rad": fit.edge_phase_rad,
           "calibrate_pylm_edge_phase_error_rad": fit.edge_phase_error_rad,
           "calibrate_pylm_calibrate_s": run.time_s, "calibrate_pylm_ok": float(fit.status == "ok")}
    for name, value in fit.values.items():
        out[f"calibrate_pylm_{name}"] = value
        out[f"calibrate_pylm_{name}_error"] = fit.errors[name]
    table = pd.read_csv(run.table).set_index("frame")
    for k, s in enumerate(PYLM_SPHERES):
        row = table.loc[k]
        for col in ("z_um", "radius_um", "n"):
            out[f"calibrate_pylm_{s.name}_{col}_published"] = s.reference[col]
            out[f"calibrate_pylm_{s.name}_{col}_before"] = float(row[f"{col}_before"])
            out[f"calibrate_pylm_{s.name}_{col}_after"] = float(row[f"{col}_after"])
            out[f"calibrate_pylm_{s.name}_{col}_after_error"] = float(row[f"d_{col}_after"])
        out[f"calibrate_pylm_{s.name}_chi2_per_px_before"] = float(row["chi2_per_px_before"])
        out[f"calibrate_pylm_{s.name}_chi2_per_px_after"] = float(row["chi2_per_px_after"])
    for when in ("before", "after"):
        for col in ("radius_um", "n"):
            dev = [float(table.loc[k, f"{col}_{when}"]) - s.reference[col]
                   for k, s in enumerate(PYLM_SPHERES)]
            out[f"calibrate_pylm_{col}_{when}_mean_abs_dev_from_published"] = float(
                np.mean(np.abs(dev)))
    return out


#: HoloPy's sphere images: instrument, image, backgrounds, crop size, centre (column, row; px),
#: reference values (the data README's)
HOLOPY_IMAGES = (
    ("image0001", "holopy_image0001", [], 100, (50.232, 48.573),
     dict(z_um=14.15, radius_um=0.6484, n=1.582), "HoloPy test_nmpfit values"),
    ("image01", "holopy_image01", ["bg01", "bg02", "bg03"], 200, (257.0, 284.0),
     dict(z_um=16.63, radius_um=0.557, n=1.58), "README independent re-fit (n held 1.58)"),
)


def holopy(work: Path) -> dict[str, float]:
    """HoloPy's two sphere images, each alone through crop, prefit, calibrate (docstring)."""
    out: dict[str, float] = {}
    for name, inst_name, bgs, size, centre, ref, _source in HOLOPY_IMAGES:
        inst = load_instrument(inst_name)
        root = work / "holopy" / name
        run_crop(HOLOPY / f"{name}.tif", [HOLOPY / f"{b}.tif" for b in bgs] or None, inst,
                 root / "crop", CropConfig(normalized=not bgs, size=size, follow="nearest",
                                           start=centre, plot=False))
        run_prefit(root / "crop", root / "prefit", plot=False,
                   batch=BatchSettings(workers=0, progress=False, overwrite=True))
        run = run_calibrate(root / "crop", root / "prefit", root / "cal",
                            CalibrateConfig(fit_na=False), batch=SERIAL)
        key = f"calibrate_holopy_{name}"
        out[f"{key}_chi2_per_px_before"] = run.chi2_before
        out[f"{key}_chi2_per_px_after"] = run.chi2_after
        out[f"{key}_chi2_red"] = run.fit.chi2_red
        out[f"{key}_edge_phase_rad"] = run.fit.edge_phase_rad
        out[f"{key}_ok"] = float(run.fit.status == "ok")
        for k, v in run.fit.values.items():
            out[f"{key}_{k}"] = v
            out[f"{key}_{k}_error"] = run.fit.errors[k]
        row = pd.read_csv(run.table).iloc[0]
        for col in ("z_um", "radius_um", "n"):
            out[f"{key}_{col}_published"] = ref[col]
            out[f"{key}_{col}_before"] = float(row[f"{col}_before"])
            out[f"{key}_{col}_after"] = float(row[f"{col}_after"])
            out[f"{key}_{col}_after_error"] = float(row[f"d_{col}_after"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument("--work", type=Path, default=Path("/tmp/holofit_calibrate_study"),
                        help="scratch folder (movies, crops, prefits; reused when present)")
    parser.add_argument("--only", nargs="*", default=["sim", "pulls", "pylorenzmie", "holopy"],
                        choices=["sim", "pulls", "pylorenzmie", "holopy"])
    parser.add_argument("--pulls", type=int, default=12, help="seeds of the pull study")
    parser.add_argument("--pulls-background", type=int, default=N_BACKGROUND,
                        help="background frames of the pull study's movies")
    parser.add_argument("--max-frames", type=int, default=20,
                        help="frames the 100-frame movie's calibration fits")
    args = parser.parse_args()
    results: dict[str, float] = {}
    for part in args.only:
        t0 = time.perf_counter()
        print(f"[calibrate_study] {part} ...", flush=True)
        got = (simulated(args.work, args.max_frames) if part == "sim"
               else pulls(args.work, args.pulls, args.pulls_background) if part == "pulls"
               else holopy(args.work) if part == "holopy"
               else pylorenzmie(args.work))
        for key, value in got.items():
            print(f"    {key} = {value:.6g}", flush=True)
        results.update(got)
        print(f"    ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.json:
        old = json.loads(args.json.read_text()) if args.json.exists() else {}
        old.update({k: (None if isinstance(v, float) and math.isnan(v) else v)
                    for k, v in results.items()})
        args.json.write_text(json.dumps(dict(sorted(old.items())), indent=1) + "\n")


if __name__ == "__main__":
    main()
