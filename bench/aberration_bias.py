"""Spherical aberration that a fit does not model: how far it moves a sphere's and a rod's fitted
parameters, and whether the aberration term (holofit.aberration) removes it.

``python bench/aberration_bias.py [--quick] [--seeds N] [--json PATH]`` prints a table and writes
a flat JSON map (``<case>_<model>_<parameter>_bias_sigma`` and friends; units in the names).

The instruments are the paper's two (configs/instruments/paper_60x_water.toml, NA 1.2, and
paper_100x_oil.toml, NA 1.4 imaging into water), each given a realistic aberration from the
layer model of :func:`holofit.aberration.layer_aberration` (Gibson & Lanni 1991), fitted with two
terms (4th and 6th order):

* 60x water: a coverslip 5 um thicker than the objective's design (a No. 1.5H coverslip's
  tolerance, or a correction collar set 5 um off);
* 100x oil: the objective focused 10 um into the water behind the coverslip.

The holograms (a 0.95 um polystyrene sphere; the paper's silica rod, a 0.501, b 1.079 um,
n 1.495, by the built-in DDA at the paper's 44 nm dipoles) are made by an independent
computation of the aberrated image (``--truth pupil``, the default): a direct numerical
integral over the pupil (:func:`pupil_hologram`: a tensor-product rule in ``(theta, phi)``,
the far field sampled direction by direction by the engine's own routine, the Mie kernel or
the DDA's direct dipole sums, the pupil phase ``exp(i Phi)`` written out by hand in
tests/lens_reference.py), not the lens code's fast path (radial transforms with tabulated
Bessel functions, the multipole expansion of the DDA field) that the fits use; ``--truth
lens`` makes them by the lens code instead (as the first version of this table did). They are
exposed by the 8-bit camera model (background 120 counts: shot noise, read noise,
quantisation; holofit.camera), ``--seeds`` noise draws each, and fitted three ways:

* ``ideal_pupil``: the instrument without the aberration term (what every fit did before);
* ``known``: with the instrument's aberration (a calibrated instrument);
* ``fitted`` (spheres): with both coefficients free, the NA known: the joint instrument fit of
  :mod:`holofit.calibrate.joint` on the one frame (its several starts of the coefficients; from
  zero alone a single frame's fit ends in another minimum for about one noise draw in four:
  the coefficients trade off against the height).

Spheres are fitted as ``holofit prefit`` does (:func:`holofit.prefit.sphere.fit_sphere_crop`,
automatic start); rods from the truth (the bias, not the basin, is the question) with x, y, z,
the axis, a, b, n and alpha free, with the ideal pupil and with the known aberration (the
instrument calibrated on spheres first). Per parameter the JSON has the mean of fitted minus
true over
the draws (``_bias``), the mean 1-sigma error (``_sigma``), their ratio (``_bias_sigma``: the
bias in sigma; the mean of the draws' pulls scatters by 1/sqrt(seeds) about it), and the same
bias of a noise-free fit in the draws' sigma (``_noisefree_bias_sigma``: the bias without the
noise). For a rod, ``axis`` is the angle between the fitted and the true axis (deg) and its
sigma the propagated error of the axis direction.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import Aberration, layer_aberration
from holofit.calibrate import JointFitSettings, SphereFrame, calibrate_instrument
from holofit.camera import Camera
from holofit.config import load_instrument
from holofit.conventions import DetectorGrid, axis_from_angles, euler_zyz, hologram_intensity
from holofit.dda.engine import BuiltinDDA
from holofit.hologram import calc_hologram
from holofit.holomodel import HologramModel, ParameterSpace, State, fit_result, solve_least_squares
from holofit.holomodel.parameters import static_values
from holofit.optics import Optics
from holofit.particles import Sphere, Spherocylinder
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.scattering.mie import MieWave
from holofit.scattering.theory import Orientation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.lens_reference import aberrated_factor, mie_far_field

CAMERA = Camera(background_counts=120.0)
ALPHA = 0.9
CORNER = (300, 200)
SPHERE = Sphere(0.475, 1.59)
ROD = Spherocylinder(0.501, 1.079, 1.495)
ROD_ORIENTATION = Orientation(0.6, 1.0)
DIPOLE_UM = 0.044
MODELS = ("ideal_pupil", "known", "fitted")
ROD_MODELS = ("ideal_pupil", "known")
COEFFICIENTS = ("sa4_rad", "sa6_rad")


@dataclass(frozen=True)
class Instrument:
    """A paper set-up with its aberration."""

    label: str
    config: str
    n_layer: float
    thickness_um: float
    what: str

    def optics(self) -> tuple[Optics, float]:
        """The instrument's optics with its aberration, and the pixel size (um)."""
        inst = load_instrument(self.config)
        base = inst.optics
        ab, _ = layer_aberration(base.wavelength_um, base.n_medium, base.numerical_aperture,
                                 self.n_layer, self.thickness_um)
        return replace(base, aberration=ab), inst.pixel_size_um

    def residual_rad(self) -> float:
        """What two terms leave of the layer's phase (rms over the pupil, rad)."""
        base = load_instrument(self.config).optics
        return layer_aberration(base.wavelength_um, base.n_medium, base.numerical_aperture,
                                self.n_layer, self.thickness_um)[1]


INSTRUMENTS = (
    Instrument("60x", "paper_60x_water", 1.523, 5.0, "coverslip 5 um thicker than designed"),
    Instrument("100x", "paper_100x_oil", 1.515, -10.0, "oil objective 10 um into water"),
)


#: the pupil rule of :func:`pupil_hologram`: Gauss-Legendre nodes in ``v = sqrt(cos th)`` and
#: trapezoid nodes in phi (converged to ~1e-9 of the field over these crops: ``--check``)
PUPIL_NODES = (480, 720)


def pupil_hologram(far_field: Callable[[NDArray], NDArray], optics: Optics,
                   position: tuple[float, float, float], grid: DetectorGrid, alpha: float,
                   nodes: tuple[int, int] = PUPIL_NODES, chunk: int = 24000) -> NDArray:
    """The normalised hologram of a far field imaged through the aberrated objective by a
    direct numerical pupil integral (independent of :mod:`holofit.scattering.lens`).

    The integral is tests/lens_reference.py's ``pupil_integral`` (the same rule, weights and
    pupil factor ``aberrated_factor``, the phase written out by hand), summed over the plane
    waves at every pixel of the grid; on a grid of pixels a plane wave's phase factors into
    a row and a column factor, ``exp(i (kx x + ky y)) = exp(i kx x) exp(i ky y)``, so the sum
    over the ``n_v n_phi`` waves is one matrix product per block of waves (exact, not an
    approximation). ``far_field(directions (N, 3)) -> F (N, 3)`` with ``E_s = exp(ikr)/(-ikr)
    F``.
    """
    k = optics.k
    xp, yp, zp = position
    n_v, n_phi = nodes
    theta_max = math.asin(min(1.0, optics.numerical_aperture / optics.n_medium))
    v0 = math.sqrt(math.cos(theta_max))
    s, w = np.polynomial.legendre.leggauss(n_v)
    v = v0 + (1 - v0) * (s + 1) / 2
    wv = w * (1 - v0) / 2 * 2 * v
    cos_t = v**2
    sin_t = np.sqrt(1 - cos_t**2)
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    ct, cp = np.meshgrid(cos_t, np.cos(phi), indexing="ij")
    st, sp = np.meshgrid(sin_t, np.sin(phi), indexing="ij")
    dirs = np.stack([st * cp, st * sp, -ct], axis=-1).reshape(-1, 3)
    f = np.concatenate([np.asarray(far_field(dirs[i:i + chunk]))
                        for i in range(0, dirs.shape[0], chunk)]).reshape(n_v, n_phi, 3)
    e_m = np.stack([ct * cp, ct * sp, st], axis=-1)
    e_p = np.stack([-sp, cp, np.zeros_like(cp)], axis=-1)
    f_m = np.sum(f * e_m, axis=-1)
    f_p = np.sum(f * e_p, axis=-1)
    q = np.sqrt(ct)  # the aplanatic objective's apodisation
    tx = q * (f_m * cp - f_p * sp)
    ty = q * (f_m * sp + f_p * cp)
    weight = (wv[:, None] * (2 * np.pi / n_phi)) * np.exp(1j * k * zp * ct)
    weight = weight * aberrated_factor(optics.aberration.spherical)(ct, phi[None, :] + 0 * ct)
    kx, ky = (k * st * cp).ravel(), (k * st * sp).ravel()
    tx, ty = (tx * weight).ravel(), (ty * weight).ravel()
    x, y = grid.coordinates()
    cols, rows = x[0, :] - xp, y[:, 0] - yp
    assert np.allclose(x, x[:1, :]) and np.allclose(y, y[:, :1]), "not a pixel grid"
    ex = np.zeros(grid.shape, complex)
    ey = np.zeros(grid.shape, complex)
    for i in range(0, kx.size, chunk):
        a = np.exp(1j * np.outer(cols, kx[i:i + chunk]))      # (cols, waves)
        b = np.exp(1j * np.outer(rows, ky[i:i + chunk]))      # (rows, waves)
        ex += (b * tx[i:i + chunk]) @ a.T
        ey += (b * ty[i:i + chunk]) @ a.T
    pre = -np.exp(-1j * k * zp) / (2 * np.pi)
    return hologram_intensity(pre * ex, pre * ey, optics.polarization_rad, alpha)


def _truth_hologram(wave, far: Callable[[NDArray], NDArray], position, grid: DetectorGrid,
                    truth: str) -> NDArray:
    """The case's noise-free hologram: by the pupil integral, or by the lens code."""
    if truth == "lens":
        return calc_hologram(wave, position, grid, ALPHA)
    holo = pupil_hologram(far, wave.optics, position, grid, ALPHA)
    fast = calc_hologram(wave, position, grid, ALPHA)
    TRUTH_CHECK.append(float(np.max(np.abs(holo - fast)) / np.max(np.abs(holo - 1))))
    return holo


#: per hologram made by the pupil integral: max |pupil - lens| over max |hologram - 1|
TRUTH_CHECK: list[float] = []


def _grid(pixel_um: float, n: int) -> tuple[DetectorGrid, float, float]:
    grid = DetectorGrid((n, n), pixel_um, CORNER)
    xc = (CORNER[1] + (n - 1) / 2 + 0.31) * pixel_um
    yc = (CORNER[0] + (n - 1) / 2 - 0.22) * pixel_um
    return grid, xc, yc


def _exposed(holo: NDArray, seed: int | None) -> NDArray:
    if seed is None:
        return holo
    return CAMERA.expose(holo, np.random.default_rng(seed)) / CAMERA.background_counts


def _model_optics(optics: Optics, model: str) -> Optics:
    return optics if model == "known" else replace(optics, aberration=Aberration())


def sphere_fits(inst: Instrument, z_um: float, seeds: int, truth_from: str = "pupil"
                ) -> dict[str, list[dict]]:
    """Per model, per draw (the last one noise-free): fitted minus true and the errors."""
    optics, px = inst.optics()
    n = 100 if inst.label == "60x" else 128
    grid, xc, yc = _grid(px, n)
    wave = MieWave(SPHERE, optics)
    holo = _truth_hologram(wave, mie_far_field(wave), (xc, yc, z_um), grid, truth_from)
    truth = {"x_um": xc, "y_um": yc, "z_um": z_um, "radius_um": SPHERE.radius_um,
             "n": SPHERE.index, "alpha": ALPHA, **optics.aberration.values()}
    out: dict[str, list[dict]] = {m: [] for m in MODELS}
    for seed in [*range(1, seeds + 1), None]:
        data = _exposed(holo, seed)
        centre = (xc - 0.4 * px, yc + 0.3 * px)
        noise = None if seed is not None else 0.016
        for model in MODELS:
            t0 = time.perf_counter()
            if model == "fitted":
                joint = calibrate_instrument([SphereFrame(data, CORNER, centre, noise)],
                                       _model_optics(optics, model), px,
                                       JointFitSettings(fit_na=False, aberration=COEFFICIENTS))
                res = joint.frames[0]
                values, errors = {**res.values, **joint.values}, {**res.errors, **joint.errors}
                status = joint.status
            else:
                res = fit_sphere_crop(data, CORNER, centre, _model_optics(optics, model), px,
                                      SphereFitSettings(noise_sd=noise))
                values, errors, status = res.values, res.errors, res.status
            out[model].append(_row(values, errors, truth, status, res.chi2_red,
                                   time.perf_counter() - t0))
    return out


def rod_fits(inst: Instrument, z_um: float, seeds: int, truth_from: str = "pupil",
             models: tuple[str, ...] = ROD_MODELS, first_seed: int = 1
             ) -> dict[str, list[dict]]:
    """:func:`sphere_fits` for the paper's rod (DDA), fitted from the truth (noise draws
    ``first_seed`` to ``first_seed + seeds - 1``, then the noise-free one)."""
    optics, px = inst.optics()
    grid, xc, yc = _grid(px, 140)
    engine = BuiltinDDA(dipole_size_um=DIPOLE_UM)
    wave = engine.solve(ROD, optics, ROD_ORIENTATION)
    # far_field_amplitude: the direct dipole sums, not the multipole expansion the lens uses
    holo = _truth_hologram(wave, wave.far_field_amplitude, (xc, yc, z_um), grid, truth_from)
    o = ROD_ORIENTATION
    truth = {"x_um": xc, "y_um": yc, "z_um": z_um, "a_um": ROD.a_um, "b_um": ROD.b_um,
             "n": ROD.index, "alpha": ALPHA, "theta_rad": o.theta, "psi_rad": o.psi,
             **optics.aberration.values()}
    x, y = grid.coordinates()
    xs, ys = x.ravel(), y.ravel()
    out: dict[str, list[dict]] = {m: [] for m in models}
    for seed in [*range(first_seed, first_seed + seeds), None]:
        data = _exposed(holo, seed).ravel()
        for model in models:
            t0 = time.perf_counter()
            free = ("x_um", "y_um", "z_um", "orientation", "a_um", "b_um", "n", "alpha")
            start = State((xc, yc, z_um), euler_zyz(o.psi, o.theta, 0.0), ALPHA,
                          static_values(ROD))
            space = ParameterSpace(ROD, free, start)
            fmodel = HologramModel(engine, space, _model_optics(optics, model), xs, ys)
            sol = solve_least_squares(fmodel, data, space.initial_vector(), max_nfev=60)
            noise = float(np.std(data - holo.ravel())) if seed is not None else 0.0
            res = fit_result(space, sol, data, noise, n_solves=fmodel.n_solves)
            out[model].append(_row(res.values, res.errors, truth, res.status, res.chi2_red,
                                   time.perf_counter() - t0, rod=True))
    return out


def _row(values: dict, errors: dict, truth: dict, status: str, chi2_red: float,
         time_s: float, rod: bool = False) -> dict:
    row = {"status": status, "chi2_red": chi2_red, "time_s": time_s}
    for k, t in truth.items():
        if k in values:
            row[k] = (values[k] - t, errors[k])
    if rod:
        u = axis_from_angles(values["theta_rad"], values["psi_rad"])
        ut = axis_from_angles(truth["theta_rad"], truth["psi_rad"])
        angle = math.degrees(math.acos(min(1.0, abs(float(u @ ut)))))
        sigma = math.degrees(math.hypot(errors["theta_rad"],
                                        math.sin(values["theta_rad"]) * errors["psi_rad"]))
        row["axis_deg"] = (angle, sigma)
    return row


def summarise(label: str, fits: dict[str, list[dict]]) -> dict[str, float]:
    """Flat JSON entries of one case (module docstring)."""
    out: dict[str, float] = {}
    for model, rows in fits.items():
        noisy, clean = rows[:-1], rows[-1]
        for k in [k for k in clean if isinstance(clean[k], tuple)]:
            bias = float(np.mean([r[k][0] for r in noisy]))
            sigma = float(np.mean([r[k][1] for r in noisy]))
            key = f"{label}_{model}_{k.removesuffix('_um').removesuffix('_rad')}"
            out[f"{key}_bias"] = bias
            out[f"{key}_sigma"] = sigma
            out[f"{key}_bias_sigma"] = bias / sigma
            out[f"{key}_noisefree_bias_sigma"] = clean[k][0] / sigma
            out[f"{key}_max_abs_pull"] = float(max(abs(r[k][0]) / r[k][1] for r in noisy))
        out[f"{label}_{model}_ok_fraction"] = float(np.mean([r["status"] == "ok" for r in noisy]))
        out[f"{label}_{model}_chi2_red"] = float(np.mean([r["chi2_red"] for r in noisy]))
        out[f"{label}_{model}_fit_s"] = float(np.mean([r["time_s"] for r in noisy]))
    return out


def _table(label: str, fits: dict[str, list[dict]], summary: dict[str, float]) -> None:
    clean = fits[list(fits)[-1]][-1]
    names = [k for k in clean if isinstance(clean[k], tuple)]
    print(f"\n{label}: bias in sigma (mean over the draws; noise-free in brackets)")
    print("model        | " + " | ".join(f"{n:>16s}" for n in names))
    for model in fits:
        cells = []
        for n in names:
            key = f"{label}_{model}_{n.removesuffix('_um').removesuffix('_rad')}"
            if key + "_bias_sigma" not in summary:
                cells.append(" " * 16)
                continue
            bias, clean = summary[key + "_bias_sigma"], summary[key + "_noisefree_bias_sigma"]
            cells.append(f"{bias:+7.2f} ({clean:+6.2f})")
        print(f"{model:12s} | " + " | ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="spheres only, one height")
    parser.add_argument("--seeds", type=int, default=4, help="camera-noise draws per case")
    parser.add_argument("--json", default=None, help="write the flat results to this file")
    parser.add_argument("--rod-known-seeds", type=int, default=0, metavar="N",
                        help="only the rods fitted with the known aberration, N more noise "
                             "draws (seeds from --seeds + 1): the pooled bias's scatter is "
                             "1/sqrt(seeds + N)")
    parser.add_argument("--truth", choices=("pupil", "lens"), default="pupil",
                        help="make the holograms by the direct pupil integral (default) or by "
                             "the lens code")
    args = parser.parse_args()
    results: dict[str, float] = {"truth_by_pupil_integral": float(args.truth == "pupil")}
    if args.rod_known_seeds:
        for inst in INSTRUMENTS:
            label = f"rod_{inst.label}_z12_extra"
            fits = rod_fits(inst, 12.0, args.rod_known_seeds, args.truth, models=("known",),
                            first_seed=args.seeds + 1)
            summary = summarise(label, fits)
            results.update(summary)
            _table(label, fits, summary)
            with open(f"{args.json or 'rod_known_seeds.json'}.rows.json", "a") as fh:
                fh.write(json.dumps({label: fits["known"]}) + "\n")
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(dict(sorted(results.items())), fh, indent=1)
        return
    for inst in INSTRUMENTS:
        optics, _ = inst.optics()
        for k, v in optics.aberration.values().items():
            results[f"instrument_{inst.label}_{k}"] = v
        results[f"instrument_{inst.label}_two_term_residual_rad"] = inst.residual_rad()
        print(f"{inst.label} ({inst.what}): {optics.aberration.spherical} rad, two-term "
              f"residual {inst.residual_rad():.3g} rad rms")
        for z in ((10.0,) if args.quick else (8.0, 15.0)):
            label = f"sphere_{inst.label}_z{z:g}"
            fits = sphere_fits(inst, z, args.seeds, args.truth)
            summary = summarise(label, fits)
            results.update(summary)
            _table(label, fits, summary)
        if not args.quick:
            label = f"rod_{inst.label}_z12"
            fits = rod_fits(inst, 12.0, args.seeds, args.truth)
            summary = summarise(label, fits)
            results.update(summary)
            _table(label, fits, summary)
    if TRUTH_CHECK:
        # the pupil integral against the lens code on each truth hologram (both exact; their
        # difference is the lens's stated accuracy, ~1e-7 of the field)
        results["truth_pupil_vs_lens_max_rel"] = max(TRUTH_CHECK)
        print("\npupil integral vs lens code, per hologram (max |diff| / max |holo - 1|): "
              + ", ".join(f"{c:.2g}" for c in TRUTH_CHECK))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(dict(sorted(results.items())), fh, indent=1)


if __name__ == "__main__":
    main()
