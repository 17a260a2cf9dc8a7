"""When does the objective lens matter? Fit lens holograms with the ideal model, as users do.

``python bench/lens_bias.py [--quick] [--json PATH]`` prints a table: for spheres like the
paper's 0.95 um polystyrene in its two set-ups (60x water NA 1.2, 100x oil NA 1.4 imaging into
water), behind a dry NA 0.95 objective, and like the pylorenzmie spheres (NA 1.45), a
noise-free hologram through an aplanatic objective (:mod:`holofit.scattering.lens`) is fitted
by the prefit exactly as ``holofit prefit`` runs it (:func:`holofit.prefit.sphere.fit_sphere_crop`:
automatic start from the radial profile, the crop stage's centre half a pixel off, x, y, z,
radius, index and alpha free) with the ideal model (no lens). The fitted minus true values are
the bias the lens model removes; ``sigma`` is the noise-limited standard error of the same fit
for pixel noise 0.02 (a typical background-divided 8-bit frame), so ``|bias| / sigma > 1``
says the lens matters at that precision. Control rows fit the same holograms with the lens
model (the bias must vanish).

It also fits particles near and below the focal plane (z = 1 um, z = -3 um) with the lens model
(a z range that reaches them) and with the ideal model (its default search).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass

import numpy as np

from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.estimate import SearchSpace
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.scattering.mie import MieWave

NOISE = 0.02
TRUE_ALPHA = 0.9


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


def cases(quick: bool) -> list[Case]:
    zs = (5.0, 10.0, 20.0) if quick else (5.0, 10.0, 15.0, 20.0)
    out = []
    for z in (3.0, *zs):
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
             10.2),
        Case("pylorenzmie PS a0.77 NA1.45", 0.447, 1.34, 0.048, 301, 1.45, 0.77, 1.56, 8.7),
        Case("pylorenzmie silica a0.50 NA1.45", 0.447, 1.34, 0.048, 301, 1.45, 0.50, 1.4255,
             8.6),
        Case("pylorenzmie silica a1.18 NA1.2", 0.447, 1.34, 0.048, 301, 1.2, 1.18, 1.39, 10.2),
    ]
    if quick:
        out = [c for c in out if c.crop_px < 301 or c.z_um == 8.7]
    return out


def lens_crop(case: Case, z_um: float | None = None
              ) -> tuple[np.ndarray, tuple[int, int], tuple[float, float], np.ndarray]:
    """The noise-free lens hologram of a case, its corner, the crop stage's centre, the truth
    ``(x, y, z, radius, index, alpha)``."""
    corner = (300, 200)
    grid = DetectorGrid((case.crop_px, case.crop_px), case.pixel_um, corner)
    px = case.pixel_um
    xc = (corner[1] + (case.crop_px - 1) / 2 + 0.31) * px
    yc = (corner[0] + (case.crop_px - 1) / 2 - 0.22) * px
    z = case.z_um if z_um is None else z_um
    optics = Optics(case.wavelength_um, case.n_medium, 0.0, case.na)
    holo = calc_hologram(MieWave(Sphere(case.radius_um, case.index), optics), (xc, yc, z), grid,
                         TRUE_ALPHA)
    centre = (xc - 0.4 * px, yc + 0.3 * px)  # a centre finder half a pixel off
    truth = np.array([xc, yc, z, case.radius_um, case.index, TRUE_ALPHA])
    return holo, corner, centre, truth


NAMES = ("x_um", "y_um", "z_um", "radius_um", "n", "alpha")


def fit_case(case: Case, lens_model: bool = False, z_um: float | None = None,
             search: SearchSpace | None = None) -> dict[str, float | str]:
    """Prefit of the case's lens hologram with the ideal (or the lens) model."""
    holo, corner, centre, truth = lens_crop(case, z_um)
    optics = Optics(case.wavelength_um, case.n_medium, 0.0, case.na if lens_model else None)
    # the status as for a frame with pixel noise NOISE (noise-free data would be poor_fit)
    opts = SphereFitSettings(noise_sd=NOISE, **({"search": search} if search is not None else {}))
    row: dict[str, float | str] = {"case": case.label, "z_true_um": float(truth[2]),
                                   "model": "lens" if lens_model else "ideal"}
    try:
        fit = fit_sphere_crop(holo, corner, centre, optics, case.pixel_um, opts)
    except ValueError as exc:
        row.update(status="error", message=str(exc))
        return row
    dof = max(fit.n_pixels - len(fit.free), 1)
    s = math.sqrt(fit.rss / dof) if fit.rss > 0 else math.nan
    row.update(r2=fit.r2, status=fit.status, message=fit.message, time_s=fit.time_s)
    for name, t in zip(NAMES, truth, strict=True):
        row[f"bias_{name}"] = fit.values[name] - float(t)
        # the fit's error for pixel noise NOISE instead of its own residual
        row[f"sigma_{name}"] = fit.errors[name] * NOISE / s if s > 0 else math.nan
    return row


def focus_rows() -> list[dict[str, float | str]]:
    """Particles near and below focus (0.95 um PS, 60x water NA 1.2, 100 px)."""
    case = Case("focus: paper 60x water NA1.2, PS 0.95", 0.66, 1.33, 0.1767, 100, 1.2, 0.475,
                1.59, 0.0)
    rows = []
    for z, reach in ((1.0, (0.5, 3.0)), (-3.0, (-6.0, -1.0))):
        rows.append(fit_case(case, True, z, SearchSpace(z_range_um=reach)))
        rows.append(fit_case(case, True, z) | {"model": "lens, default z search"})
        rows.append(fit_case(case, False, z) | {"model": "ideal, default z search"})
    return rows


def _fmt(r: dict, key: str, scale: float, spec: str) -> str:
    v = r.get(key)
    return "" if v is None or not math.isfinite(float(v)) else format(scale * float(v), spec)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer cases")
    parser.add_argument("--json", default=None, help="write the rows to this file")
    args = parser.parse_args()
    rows = []
    all_cases = cases(args.quick)
    for case in all_cases[:2]:
        rows.append(fit_case(case, lens_model=True))  # control: must give zero bias
    for case in all_cases:
        rows.append(fit_case(case))
    rows += focus_rows()
    head = ("case", "model", "z_um", "dz_um", "sz", "dr_nm", "sr", "dn_1e-4", "sn", "dalpha",
            "R2", "status")
    print(" | ".join(head))
    for r in rows:
        print(" | ".join([
            str(r["case"]), str(r["model"]), f"{r['z_true_um']:.1f}",
            _fmt(r, "bias_z_um", 1, "+.4f"), _fmt(r, "sigma_z_um", 1, ".4f"),
            _fmt(r, "bias_radius_um", 1e3, "+.1f"), _fmt(r, "sigma_radius_um", 1e3, ".1f"),
            _fmt(r, "bias_n", 1e4, "+.1f"), _fmt(r, "sigma_n", 1e4, ".1f"),
            _fmt(r, "bias_alpha", 1, "+.4f"), _fmt(r, "r2", 1, ".6f"), str(r["status"]),
        ]))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
