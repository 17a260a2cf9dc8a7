"""When does the objective lens matter? Fit lens holograms with the ideal model.

``python bench/lens_bias.py [--quick]`` prints a table (and ``--json PATH`` writes it): for
spheres like the paper's 0.95 um polystyrene in its two set-ups (60x water NA 1.2, 100x oil
NA 1.4 imaging into water) and like the pylorenzmie spheres (NA 1.45), a noise-free hologram
through an aplanatic objective (:mod:`holofit.scattering.lens`) is fitted with holofit's ideal
model (exact Lorenz-Mie near field on the focal plane, the paper's and HoloPy's ``Mie``) by
least squares in ``x, y, z, radius, index, alpha``, started from the truth. The fitted minus
true values are the bias the lens model removes; ``sigma`` columns are the noise-limited
standard errors of the same fit for pixel noise 0.02 (a typical background-divided 8-bit
frame), so ``|bias| / sigma > 1`` says the lens matters at that precision. A control row fits
the lens hologram with the lens model (bias must vanish).

It also prints what each model gives near and below the focal plane.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from holofit.conventions import DetectorGrid, hologram_intensity, r_squared
from holofit.models import Sphere
from holofit.optics import Optics
from holofit.scattering.lens import lens_field_on_pixels
from holofit.scattering.mie import MieWave

NOISE = 0.02
NAMES = ("x_um", "y_um", "z_um", "radius_um", "index", "alpha")


@dataclass(frozen=True)
class Case:
    label: str
    wavelength_um: float
    n_medium: float
    pixel_um: float
    crop_px: int
    na: float
    radius_um: float
    index: float
    z_um: float
    alpha: float = 0.9


def cases(quick: bool) -> list[Case]:
    zs = (5.0, 10.0, 20.0) if quick else (5.0, 10.0, 15.0, 20.0)
    out = []
    for z in (2.0, 3.0, *zs):
        out.append(Case("paper 60x water NA1.2, PS 0.95", 0.66, 1.33, 0.1767, 100, 1.2,
                        0.475, 1.59, z))
    for z in zs:
        # a crop twice as wide (35 um) reaches past the aperture angle up to z ~ 11 um
        out.append(Case("paper 60x water NA1.2, PS 0.95, 200 px", 0.66, 1.33, 0.1767, 200,
                        1.2, 0.475, 1.59, z))
    for z in zs:
        # a dry objective (NA 0.95) imaging into water: cut at 45.6 deg
        out.append(Case("dry NA0.95 into water, PS 0.95", 0.66, 1.33, 0.1767, 100, 0.95,
                        0.475, 1.59, z))
    for z in zs:
        out.append(Case("paper 100x oil NA1.4, PS 0.95", 0.66, 1.33, 0.106, 128, 1.4,
                        0.475, 1.59, z))
    out += [
        Case("pylorenzmie silica a1.18 NA1.45", 0.447, 1.34, 0.048, 301, 1.45, 1.18, 1.39,
             5.3),
        Case("pylorenzmie silica a1.18 NA1.45", 0.447, 1.34, 0.048, 301, 1.45, 1.18, 1.39,
             10.2),
        Case("pylorenzmie PS a0.77 NA1.45", 0.447, 1.34, 0.048, 301, 1.45, 0.77, 1.56, 8.7),
        Case("pylorenzmie silica a0.50 NA1.45", 0.447, 1.34, 0.048, 301, 1.45, 0.50, 1.4255,
             8.6),
        Case("pylorenzmie silica a1.18 NA1.2", 0.447, 1.34, 0.048, 301, 1.2, 1.18, 1.39, 10.2),
    ]
    if quick:
        out = [c for c in out if c.crop_px < 301 or c.z_um == 8.7]
    return out


def _pixels(case: Case) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    grid = DetectorGrid((case.crop_px, case.crop_px), case.pixel_um)
    x, y = grid.coordinates()
    centre = ((case.crop_px - 1) / 2 * case.pixel_um + 0.31 * case.pixel_um,
              (case.crop_px - 1) / 2 * case.pixel_um - 0.22 * case.pixel_um)
    return x.ravel(), y.ravel(), centre


def _model(p: np.ndarray, case: Case, xs: np.ndarray, ys: np.ndarray, lens: bool) -> np.ndarray:
    optics = Optics(case.wavelength_um, case.n_medium, 0.0)
    wave = MieWave(Sphere(p[3], p[4]), optics)
    if lens:
        ex, ey = lens_field_on_pixels(wave, p[:3], xs, ys, case.na)
    else:
        ex, ey = wave.field_on_pixels(p[:3], xs, ys)
    return hologram_intensity(ex, ey, 0.0, p[5])


def fit_case(case: Case, lens_model: bool = False) -> dict[str, float]:
    xs, ys, (xc, yc) = _pixels(case)
    truth = np.array([xc, yc, case.z_um, case.radius_um, case.index, case.alpha])
    data = _model(truth, case, xs, ys, lens=True)
    res = least_squares(lambda p: _model(p, case, xs, ys, lens_model) - data, truth,
                        x_scale=np.array([0.01, 0.01, 0.01, 0.001, 0.001, 0.001]),
                        diff_step=1e-7, xtol=1e-12, ftol=1e-12, gtol=1e-12, method="lm")
    j = res.jac
    cov = np.linalg.inv(j.T @ j) * NOISE**2
    out = {"case": case.label, "z_true_um": case.z_um, "model": "lens" if lens_model else "ideal",
           "r2": r_squared(data, data + res.fun)}
    for i, name in enumerate(NAMES):
        out[f"bias_{name}"] = float(res.x[i] - truth[i])
        out[f"sigma_{name}"] = float(np.sqrt(cov[i, i]))
    return out


def focus_demo() -> list[dict[str, float | str]]:
    """Contrast of each model's hologram of a 0.95 um PS sphere near and below focus."""
    case = Case("focus", 0.66, 1.33, 0.1767, 100, 1.2, 0.475, 1.59, 0.0)
    xs, ys, (xc, yc) = _pixels(case)
    rows = []
    for z in (10.0, 2.0, 0.0, -2.0, -10.0):
        p = np.array([xc, yc, z, case.radius_um, case.index, 1.0])
        lens = _model(p, case, xs, ys, lens=True)
        try:
            ideal = _model(p, case, xs, ys, lens=False)
            ideal_text = f"{ideal.min():.3f}..{ideal.max():.3f}"
        except ValueError as exc:
            ideal_text = f"error: {exc}"
        rows.append({"z_um": z, "lens": f"{lens.min():.3f}..{lens.max():.3f}",
                     "ideal": ideal_text})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer cases")
    parser.add_argument("--json", default=None, help="write the rows to this file")
    args = parser.parse_args()
    rows = []
    all_cases = cases(args.quick)
    rows.append(fit_case(all_cases[3], lens_model=True))  # control: must give zero bias
    for case in all_cases:
        rows.append(fit_case(case))
    head = ("case", "model", "z_um", "dz_um", "sz", "dr_nm", "sr", "dn_1e-4", "sn", "dalpha",
            "R2")
    print(" | ".join(head))
    for r in rows:
        print(" | ".join([
            r["case"], r["model"], f"{r['z_true_um']:.1f}",
            f"{r['bias_z_um']:+.4f}", f"{r['sigma_z_um']:.4f}",
            f"{1e3 * r['bias_radius_um']:+.1f}", f"{1e3 * r['sigma_radius_um']:.1f}",
            f"{1e4 * r['bias_index']:+.1f}", f"{1e4 * r['sigma_index']:.1f}",
            f"{r['bias_alpha']:+.4f}", f"{r['r2']:.6f}",
        ]))
    print("\nhologram range (min..max) near and below focus, 0.95 um PS, NA 1.2 water:")
    demo = focus_demo()
    for r in demo:
        print(f"  z = {r['z_um']:+.1f} um: lens {r['lens']}, ideal {r['ideal']}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"fits": rows, "focus": demo}, fh, indent=1)


if __name__ == "__main__":
    main()
