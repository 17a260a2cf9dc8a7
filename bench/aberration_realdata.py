"""The joint instrument fit (holofit.calibrate.joint) on measured sphere holograms: the NA and the
spherical aberration of the pylorenzmie microscope from its seven spheres at once, and the
aberration of HoloPy's two example images one by one (not part of ``make bench``).

``python bench/aberration_realdata.py [--json PATH] [--fraction F]``

Before: every sphere fitted alone as ``holofit prefit`` does (automatic start, alpha free), with
the instrument file's objective (pylorenzmie: NA 0.86, the effective aperture these data show;
HoloPy: NA 1.4, an assumption that the small crops cannot test) and no aberration. After: the
joint fit (NA and the 4th- and 6th-order coefficients shared by the pylorenzmie frames; for
HoloPy, whose crops reach NA 0.48 and 0.57 only, the coefficients alone with the NA held).
Reported per sphere: chi^2 per pixel (mean squared residual, normalised intensity^2), R^2,
z, radius and index, next to the published or independent reference fits of the data READMEs
(tests/data/*/README.md). Crops as in bench/validate_lens_realdata.py (the crop stage's sizes
and centres): pylorenzmie 301 px, saturated pixels left out; HoloPy image0001 as stored (100 px,
divided by its mean, as HoloPy's tests do), image01 background-divided, 200 px.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tifffile

from holofit.calibrate import JointFitSettings, SphereFrame, calibrate_instrument
from holofit.config import load_instrument
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop

ROOT = Path(__file__).resolve().parents[1]
HOLOPY = ROOT / "tests" / "data" / "holopy"
PYLM = ROOT / "tests" / "data" / "pylorenzmie"
PX_PYLM = 0.048
#: normalised values at or above this are saturated (255 counts over a background of 100)
SATURATED = 2.54


@dataclass(frozen=True)
class Sphere:
    """One measured sphere: its crop's centre (column, row; pixels), crop size, reference."""

    name: str
    image: str
    centre_px: tuple[float, float]
    size: int
    reference: dict[str, float]
    source: str


PYLM_SPHERES = (
    Sphere("PS_silica_silica", "PS_silica", (908.5, 484.0), 301,
           dict(z_um=179.284 * PX_PYLM, radius_um=0.4976, n=1.4255), "published (2021)"),
    Sphere("PS_silica_PS", "PS_silica", (376.9, 481.3), 301,
           dict(z_um=181.399 * PX_PYLM, radius_um=0.7707, n=1.5602), "published (2021)"),
    Sphere("image0400_left", "image0400", (583.1, 685.3), 301,
           dict(z_um=217.7 * PX_PYLM, radius_um=1.1816, n=1.3923), "published (2021)"),
    Sphere("image0400_right", "image0400", (884.4, 747.0), 301,
           dict(z_um=112.8 * PX_PYLM, radius_um=1.2226, n=1.3936), "published (2021)"),
    Sphere("image0010_left", "image0010", (562.3, 720.2), 301,
           dict(z_um=543.2 * PX_PYLM, radius_um=1.213, n=1.402), "README lm re-fit"),
    Sphere("image0010_right", "image0010", (920.5, 732.1), 301,
           dict(z_um=540.5 * PX_PYLM, radius_um=1.207, n=1.405), "README lm re-fit"),
    Sphere("sample_lower_left", "sample", (322.3, 733.0), 301,
           dict(z_um=225.2 * PX_PYLM, radius_um=0.847, n=1.441), "README lm re-fit"),
)


def _pylm_image(name: str) -> np.ndarray:
    raw = tifffile.imread(PYLM / f"{name}.tif").astype(float)
    if name == "sample":
        bg = tifffile.imread(PYLM / "background.tif").astype(float)
        return (raw - 13.0) / (bg - 13.0)
    img = raw / 100.0
    img[raw >= 255] = np.nan  # saturated
    return img


def _crop(image: np.ndarray, centre_px: tuple[float, float], size: int
          ) -> tuple[np.ndarray, tuple[int, int]]:
    col, row = centre_px
    r0 = round(row) - size // 2
    c0 = round(col) - size // 2
    return image[r0:r0 + size, c0:c0 + size].copy(), (r0, c0)


def _before(frame: SphereFrame, optics, px: float) -> dict[str, float]:
    fit = fit_sphere_crop(frame.crop, frame.corner_rc, frame.centre_xy_um, optics, px,
                          SphereFitSettings())
    return {**{k: fit.values[k] for k in ("z_um", "radius_um", "n", "alpha")},
            "chi2_per_px": fit.chi2, "r2": fit.r2, "chi2_red": fit.chi2_red,
            "status": fit.status}


def _after(fit, j: int) -> dict[str, float]:
    r = fit.frames[j]
    out = {k: r.values[k] for k in ("z_um", "radius_um", "n", "alpha")}
    out.update({f"d_{k}": r.errors[k] for k in ("z_um", "radius_um", "n")})
    out.update(chi2_per_px=r.chi2, r2=r.r2, chi2_red=r.chi2_red, status=r.status)
    return out


def pylorenzmie(fraction: float) -> dict:
    inst = load_instrument("pylorenzmie")
    optics, px = inst.optics, inst.pixel_size_um
    images: dict[str, np.ndarray] = {}
    frames = []
    for s in PYLM_SPHERES:
        img = images.setdefault(s.image, _pylm_image(s.image))
        crop, corner = _crop(img, s.centre_px, s.size)
        crop[crop >= SATURATED] = np.nan
        frames.append(SphereFrame(crop, corner, (s.centre_px[0] * px, s.centre_px[1] * px)))
    t0 = time.perf_counter()
    before = [_before(f, optics, px) for f in frames]
    t_before = time.perf_counter() - t0
    fit = calibrate_instrument(frames, optics, px, JointFitSettings(pixel_fraction=fraction))
    rows = []
    for j, s in enumerate(PYLM_SPHERES):
        rows.append({"sphere": s.name, "reference": s.reference, "source": s.source,
                     "before": before[j], "after": _after(fit, j)})
    return {"instrument": "pylorenzmie", "start": {"numerical_aperture": 0.86},
            "values": fit.values, "errors": fit.errors, "chi2_red": fit.chi2_red,
            "edge_phase_rad": fit.edge_phase_rad,
            "edge_phase_error_rad": fit.edge_phase_error_rad,
            "status": fit.status, "time_s": fit.time_s, "before_time_s": t_before,
            "trials": fit.trials, "spheres": rows}


def holopy() -> list[dict]:
    out = []
    inst = load_instrument("holopy_image0001")
    img = tifffile.imread(HOLOPY / "image0001.tif").astype(float)
    img /= img.mean()
    px = inst.pixel_size_um
    frame = SphereFrame(img, (0, 0), (50.232 * px, 48.573 * px))
    out.append(_holopy_case("image0001", frame, inst,
                            dict(z_um=14.15, radius_um=0.6484, n=1.582),
                            "HoloPy test_nmpfit gold values"))
    inst = load_instrument("holopy_image01")
    raw = tifffile.imread(HOLOPY / "image01.tif").astype(float)
    bg = np.mean([tifffile.imread(HOLOPY / f"bg0{k}.tif").astype(float) for k in (1, 2, 3)],
                 axis=0)
    dark = tifffile.imread(HOLOPY / "df01.tif").astype(float)
    norm = (raw - dark) / (bg - dark)
    crop, corner = _crop(norm, (257.0, 284.0), 200)
    px = inst.pixel_size_um
    frame = SphereFrame(crop, corner, (257.0 * px, 284.0 * px))
    out.append(_holopy_case("image01", frame, inst, dict(z_um=16.63, radius_um=0.557, n=1.58),
                            "README independent re-fit (n held at 1.58)"))
    return out


def _holopy_case(name: str, frame: SphereFrame, inst, reference: dict, source: str) -> dict:
    optics, px = inst.optics, inst.pixel_size_um
    before = _before(frame, optics, px)
    fit = calibrate_instrument([frame], optics, px, JointFitSettings(fit_na=False))
    return {"sphere": name, "reference": reference, "source": source, "before": before,
            "after": _after(fit, 0), "values": fit.values, "errors": fit.errors,
            "edge_phase_rad": fit.edge_phase_rad,
            "edge_phase_error_rad": fit.edge_phase_error_rad, "time_s": fit.time_s}


def _line(label: str, d: dict) -> str:
    return (f"  {label:7s} z {d['z_um']:7.3f}  a {d['radius_um']:.4f}  n {d['n']:.4f}  "
            f"alpha {d.get('alpha', float('nan')):.3f}  chi2/px {d.get('chi2_per_px', 0):.3e}"
            f"  R2 {d.get('r2', float('nan')):.4f}  {d.get('status', '')}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="write the results to this file")
    parser.add_argument("--fraction", type=float, default=0.35,
                        help="fraction of each pylorenzmie crop's pixels fitted jointly")
    args = parser.parse_args()
    results = {"pylorenzmie": pylorenzmie(args.fraction), "holopy": holopy()}
    p = results["pylorenzmie"]
    print("pylorenzmie joint fit:", {k: f"{v:.4g} +- {p['errors'][k]:.2g}"
                                     for k, v in p["values"].items()},
          f"edge phase {p['edge_phase_rad']:.3g} +- {p['edge_phase_error_rad']:.2g} rad, "
          f"chi2_red {p['chi2_red']:.3f}, {p['time_s']:.0f} s")
    for row in p["spheres"] + results["holopy"]:
        print(row["sphere"], f"({row['source']})")
        print(_line("ref", row["reference"]))
        print(_line("before", row["before"]))
        print(_line("after", row["after"]))
        if "values" in row:
            print("  instrument:", {k: f"{v:.4g} +- {row['errors'][k]:.2g}"
                                    for k, v in row["values"].items()},
                  f"edge phase {row['edge_phase_rad']:.3g} +- "
                  f"{row['edge_phase_error_rad']:.2g} rad")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
