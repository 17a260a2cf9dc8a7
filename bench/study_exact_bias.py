"""The DDA fit measured against exact holograms: the bias of every fitted parameter against its
error (issue 25, item 3).

Usage: ``python bench/study_exact_bias.py [--cases coated dimer] [--dpl 10 20] [--seeds 0]
[--out FILE.json]``; ``--linear`` for the first-order estimate (below).

* ``coated``: a polystyrene sphere (radius 0.443 um, n 1.581) with a uniform 47 nm TiO2 shell
  (n 2.74), the paper's Janus materials, on the paper's 100x oil instrument (its lens, NA 1.4),
  12 um from focus, 140 x 140 crop. The hologram is exact (``coated_sphere``: coated-sphere
  Lorenz-Mie); the fit is the built-in DDA of the ``coated_sphere`` model with position, alpha,
  core radius, shell thickness and both (real) indices free.
* ``dimer``: two touching polystyrene spheres (0.53 um, n 1.59) at three orientations on the
  paper's 60x water instrument (lens NA 1.2), exact by the cluster engine; the DDA dimer fit has
  position, orientation, alpha, both radii and both indices free (gap held at 0).

Every crop has 8-bit camera noise (background 120 counts; ``--seeds``; seed -1: no noise, so
that the fit's offset from the truth is the DDA's own bias, to be set against the errors of a
noisy fit); the fits start from the
truth moved by (30, -20, 250) nm, the sizes by +2 % and the indices by +0.01, alpha 0.8, the
orientation at the truth's. For each case, dipole rule (``--dpl``; the engine's default is 10)
and seed the table gives every fitted parameter's ``fitted - truth`` and ``(fitted - truth) /
error``; ``|bias| <= error`` is the issue's "within 1 sigma". Prints a table and one JSON line.

``--linear``: the first-order (Gauss-Newton) estimate of the same numbers from one DDA solve
at the truth per rule, for rules too costly to fit: the bias ``b = (J^T J)^-1 J^T (H_exact -
H_DDA(truth))`` and the error ``sigma = s sqrt(diag (J^T J)^-1)``, with ``J`` the exact model's
Jacobian at the truth (central differences) and ``s`` the camera's pixel noise (the standard
deviation of exposed-minus-ideal crops). ``--ramp`` and ``--mixing`` choose the boundary
treatment (:mod:`holofit.dda.voxelize`) for such comparisons.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from holofit.camera import Camera
from holofit.config import load_instrument, resolve_config
from holofit.conventions import DetectorGrid
from holofit.dda.engine import BuiltinDDA
from holofit.engines.select import select_engine
from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem
from holofit.fit.settings import FrameFitSettings
from holofit.hologram import calc_hologram
from holofit.holomodel.parameters import static_parameters
from holofit.library.search import Candidate
from holofit.particles import CoatedSphere, Dimer, ParticleModel
from holofit.scattering.theory import Orientation

CROP = 140
Z_UM = 12.0
ALPHA = 0.9
START_OFFSET_UM = (0.03, -0.02, 0.25)

CASES: dict[str, tuple[str, ParticleModel, list[Orientation]]] = {
    "coated": ("paper_100x_oil", CoatedSphere(0.443, 0.047, 1.581, 2.74), [Orientation()]),
    "dimer": ("paper_60x_water", Dimer(0.53, 0.53, 0.0, 1.59, 1.59),
              [Orientation(0.6, 1.0), Orientation(1.9, 0.4), Orientation(-0.8, 1.45)]),
}


def _start_model(model: ParticleModel) -> ParticleModel:
    changes: dict[str, float | complex] = {}
    for f in model.size_fields:
        changes[f] = getattr(model, f) * 1.02
    for f in model.index_fields:
        n = complex(getattr(model, f))
        changes[f] = complex(n.real + 0.01, n.imag) if n.imag else n.real + 0.01
    return model.replace(**changes)


def run_case(case: str, dpl: float, seed: int, o_index: int) -> dict[str, object]:
    inst_name, truth, orientations = CASES[case]
    o = orientations[o_index]
    inst = load_instrument(resolve_config(inst_name, "instruments"))
    px = inst.pixel_size_um
    grid = DetectorGrid((CROP, CROP), px, (100, 200))
    pos = ((200 + 70.3) * px, (100 + 69.6) * px, Z_UM)
    exact = select_engine(truth).solve(truth, inst.optics, o)
    holo = calc_hologram(exact, pos, grid, ALPHA)
    if seed < 0:  # noise-free: the fit's offset from the truth is the model's own bias
        crop = holo
    else:
        crop = Camera(background_counts=120.0).expose(holo, np.random.default_rng(seed)) / 120.0
    start_model = _start_model(truth)
    dda = BuiltinDDA(dipoles_per_wavelength=dpl)
    d = dda.settings.dipole_size_for(truth, inst.optics)
    dda = BuiltinDDA(dda.settings.replace(dipole_size_um=d))  # one lattice for the whole fit
    free = ["x_um", "y_um", "z_um", "alpha"]
    if truth.anisotropic:
        free.append("orientation")
    free += [p.name for p in static_parameters(truth) if p.name != "gap_um"]
    start = tuple(p + s for p, s in zip(pos, START_OFFSET_UM, strict=True))
    cands = [Candidate(o.psi, o.theta, o.phi, 0.0)]
    t0 = time.perf_counter()
    res = fit_frame(
        FrameProblem(
            crop,
            grid.corner,
            px,
            dda,
            start_model,
            inst.optics,
            tuple(free),
            settings=FrameFitSettings(),
            seed=0,
        ),
        start,
        0.8,
        cands,
    )
    wall = time.perf_counter() - t0
    truth_values = {"x_um": pos[0], "y_um": pos[1], "z_um": pos[2], "alpha": ALPHA}
    for p in static_parameters(truth):
        truth_values[p.name] = float(complex(getattr(truth, p.field)).real)
    rows = {}
    for name, value in truth_values.items():
        if name not in res.values:
            continue
        bias = res.values[name] - value
        err = res.errors.get(name, float("nan"))
        rows[name] = {
            "truth": value,
            "fitted": res.values[name],
            "bias": bias,
            "error": err,
            "bias_over_error": bias / err if err else float("nan"),
        }
    if truth.anisotropic:
        ut = np.array(
            [np.sin(o.theta) * np.cos(o.psi), np.sin(o.theta) * np.sin(o.psi), np.cos(o.theta)]
        )
        u = np.array([res.values[k] for k in ("ux", "uy", "uz")])
        rows["axis_deg"] = {
            "bias": float(np.degrees(np.arccos(min(1.0, abs(u @ ut) / np.linalg.norm(u))))),
            "error": float("nan"),
            "bias_over_error": float("nan"),
            "truth": 0.0,
            "fitted": float("nan"),
        }
    return {
        "case": case,
        "orientation": dataclasses.astuple(o),
        "dpl": dpl,
        "d_um": d,
        "seed": seed,
        "status": res.status,
        "r2": res.r2,
        "wall_s": wall,
        "params": rows,
    }


#: central-difference steps of the exact model's Jacobian (um for sizes and positions)
LINEAR_STEPS = {
    "x_um": 1e-3,
    "y_um": 1e-3,
    "z_um": 2e-3,
    "alpha": 1e-3,
    "size": 5e-4,
    "index": 5e-4,
}


def _setup(case: str, o_index: int):
    inst_name, truth, orientations = CASES[case]
    o = orientations[o_index]
    inst = load_instrument(resolve_config(inst_name, "instruments"))
    px = inst.pixel_size_um
    grid = DetectorGrid((CROP, CROP), px, (100, 200))
    pos = ((200 + 70.3) * px, (100 + 69.6) * px, Z_UM)
    return inst, truth, o, grid, pos


def linear_case(
    case: str, dpls: list[float], o_index: int = 0, **settings: str
) -> list[dict[str, object]]:
    """First-order bias and error of every parameter (see the module docstring); position,
    alpha, sizes and indices (orientation held); ``settings``: the DDA's (e.g. ``filling``,
    ``polarizability``)."""
    inst, truth, o, grid, pos = _setup(case, o_index)
    exact = select_engine(truth)

    def holo(model: ParticleModel, p: tuple, alpha: float) -> np.ndarray:
        return calc_hologram(exact.solve(model, inst.optics, o), p, grid, alpha).ravel()

    h0 = holo(truth, pos, ALPHA)
    names, cols = [], []
    for i, name in enumerate(("x_um", "y_um", "z_um")):
        step = LINEAR_STEPS[name]
        up, dn = list(pos), list(pos)
        up[i] += step
        dn[i] -= step
        cols.append((holo(truth, tuple(up), ALPHA) - holo(truth, tuple(dn), ALPHA)) / (2 * step))
        names.append(name)
    step = LINEAR_STEPS["alpha"]
    cols.append((holo(truth, pos, ALPHA + step) - holo(truth, pos, ALPHA - step)) / (2 * step))
    names.append("alpha")
    for field in (*truth.size_fields, *truth.index_fields):
        kind = "size" if field in truth.size_fields else "index"
        step = LINEAR_STEPS[kind]
        v = complex(getattr(truth, field)).real if kind == "index" else getattr(truth, field)
        cols.append(
            (
                holo(truth.replace(**{field: v + step}), pos, ALPHA)
                - holo(truth.replace(**{field: v - step}), pos, ALPHA)
            )
            / (2 * step)
        )
        names.append(field)
    jac = np.column_stack(cols)
    cov = np.linalg.inv(jac.T @ jac)
    cam = Camera(background_counts=120.0)
    img = h0.reshape(grid.shape)
    noise = np.std(
        np.concatenate(
            [(cam.expose(img, np.random.default_rng(s)) / 120.0 - img).ravel() for s in range(4)]
        )
    )
    sigma = noise * np.sqrt(np.diag(cov))
    out = []
    for dpl in dpls:
        dda = BuiltinDDA(dipoles_per_wavelength=dpl, **settings)
        d = dda.settings.dipole_size_for(truth, inst.optics)
        t0 = time.perf_counter()
        wave = BuiltinDDA(dda.settings.replace(dipole_size_um=d)).solve(truth, inst.optics, o)
        hd = calc_hologram(wave, pos, grid, ALPHA).ravel()
        wall = time.perf_counter() - t0
        bias = cov @ (jac.T @ (h0 - hd))
        rows = {
            n: {"bias": float(b), "error": float(e), "bias_over_error": float(b / e)}
            for n, b, e in zip(names, bias, sigma, strict=True)
        }
        n_dip = int(wave.solution.P.shape[0]) if hasattr(wave, "solution") else -1
        out.append(
            {
                "case": case,
                "dpl": dpl,
                "d_um": d,
                "settings": settings,
                "dipoles": n_dip,
                "solve_s": wall,
                "one_minus_r2": float(np.sum((h0 - hd) ** 2) / np.sum((h0 - h0.mean()) ** 2)),
                "pixel_noise": float(noise),
                "params": rows,
            }
        )
        print(
            f"## linear {case} {settings} dpl {dpl:g} (d {1e3 * d:.1f} nm), solve {wall:.0f} s, "
            f"1-R^2 {out[-1]['one_minus_r2']:.2e}",
            flush=True,
        )
        for n, r in rows.items():
            print(
                f"| {n} | {r['bias']:.2e} | {r['error']:.2e} | {r['bias_over_error']:.2f} |",
                flush=True,
            )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--dpl", type=float, nargs="*", default=[10, 20])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0])
    ap.add_argument("--orientations", type=int, nargs="*", default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--linear", action="store_true")
    ap.add_argument("--polarizability", default=None)
    ap.add_argument("--filling", default=None)
    args = ap.parse_args()
    if args.linear:
        results_lin = []
        for case in args.cases:
            settings = {
                k: v for k in ("polarizability", "filling") if (v := getattr(args, k)) is not None
            }
            results_lin += linear_case(case, args.dpl, **settings)
            if args.out:
                args.out.write_text(json.dumps(results_lin) + "\n")
        print(json.dumps(results_lin))
        return
    results = []
    for case in args.cases:
        n_o = len(CASES[case][2])
        for dpl in args.dpl:
            for oi in args.orientations if args.orientations is not None else range(n_o):
                if oi >= n_o:
                    continue
                for seed in args.seeds:
                    r = run_case(case, dpl, seed, oi)
                    results.append(r)
                    print(
                        f"## {case} o{oi} dpl {dpl:g} (d {1e3 * r['d_um']:.1f} nm) seed "
                        f"{seed}: {r['status']}, R^2 {r['r2']:.5f}, {r['wall_s']:.0f} s",
                        flush=True,
                    )
                    print("| parameter | truth | fitted | bias | error | bias/error |")
                    print("| --- | --- | --- | --- | --- | --- |")
                    for name, p in r["params"].items():
                        print(
                            f"| {name} | {p['truth']:.4f} | {p['fitted']:.4f} | "
                            f"{p['bias']:.2e} | {p['error']:.2e} | "
                            f"{p['bias_over_error']:.2f} |",
                            flush=True,
                        )
                    if args.out:
                        args.out.write_text(json.dumps(results) + "\n")
    print(json.dumps(results))


if __name__ == "__main__":
    main()
