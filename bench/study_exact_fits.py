"""Fits of holograms made by independent codes, by the exact engine and by the DDA at its default
rule: the bias of every fitted parameter in units of its error (issue 37, item 5).

Usage: ``python bench/study_exact_fits.py [--cases rod spheroid janus] [--seeds 0 1]
[--engines exact builtin] [--out bench/results/exact/study_exact_fits.json]``; prints a table
per fit and writes one JSON line (the fits, and per case and engine the largest
``|bias| / error`` of every parameter, its mean over the fits, the axis error).

The truths and their references (none is holofit's own exact engine):

* ``rod``: the paper's rod (``rod_paper``: spherocylinder a 0.5, b 1.0 um, n 1.495) on the
  60x water instrument (``paper_60x_water``, NA 1.2), from the extended-precision (long
  double) EBCM of ``tests/ebcm_reference.py`` at order :data:`ROD_ORDER`;
* ``spheroid``: a silica spheroid (aspect 2, equal-volume radius 0.5 um, n 1.45), same
  instrument, from pytmatrixc (Mishchenko's EBCM Fortran) amplitude matrices;
* ``janus``: the paper's Janus particle (``janus_paper``) on the 100x oil instrument
  (``paper_100x_oil``, NA 1.4), from holofit's built-in DDA at :data:`JANUS_RULES` dipoles per
  wavelength, extrapolated linearly in the dipole size to d = 0.

Engines (``--engines``): ``exact``, ``builtin`` (the DDA at its default rule) and
``builtin-ramp`` (the same with the older ramp filling, for comparison).

Each reference is a far-field-only wave (``tests/exact_references.py``) imaged by holofit's own
camera and lens code: the imaging is shared with the fitted models, the scattering is not. The
references' own accuracy is measured here too (``reference_accuracy``): the rod's far-field
change between orders ``ROD_ORDER - 4`` and ``ROD_ORDER``; pytmatrixc against holofit's exact
spheroid; the Janus extrapolation from rules (20, 28) against a quadratic one from (14, 20, 28).

With ``--precision-order N`` the holograms are made by holofit's exact engine itself at order
``N`` instead: not an independent reference, but a measure of what the fit's own
(lower) order costs; each row says so (``reference``).

Crops: 140 x 140 pixels, alpha 0.9, the frames of :data:`FRAMES` (orientation, height), each
without noise (seed -1: the fit's offset from the truth is the model's own bias) and with 8-bit
camera noise (background 120 counts; seeds 0, 1: the errors, and the pulls). A parameter's bias
in units of its error is the noise-free fit's offset over the mean error of the frame's noisy
fits. The fits start from the truth moved by
(30, -20, 250) nm, the sizes by +2 %, the indices by +0.01, alpha 0.8, the axis turned by
3 deg in theta and 5 deg in psi, with the fit's default settings (its mirrored start
included). Position, alpha, orientation, sizes and indices are free. A Janus fit whose axis is
more than 30 deg off the truth is on the wrong branch; it is flagged if its status is not ``ok``
or the fit marks it ambiguous.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from holofit.camera import Camera  # noqa: E402
from holofit.config import load_instrument, load_particle, resolve_config  # noqa: E402
from holofit.conventions import DetectorGrid  # noqa: E402
from holofit.dda.engine import BuiltinDDA  # noqa: E402
from holofit.dda.settings import DDASettings  # noqa: E402
from holofit.engines.registry import get_engine  # noqa: E402
from holofit.fit.frame import fit_frame  # noqa: E402
from holofit.fit.problem import FrameProblem  # noqa: E402
from holofit.fit.settings import FrameFitSettings  # noqa: E402
from holofit.hologram import calc_hologram  # noqa: E402
from holofit.holomodel.parameters import static_parameters  # noqa: E402
from holofit.library.search import Candidate  # noqa: E402
from holofit.particles import ParticleModel, Spheroid  # noqa: E402
from holofit.scattering.axisym import build_exact_tmatrix, discretisation  # noqa: E402
from holofit.scattering.theory import Orientation  # noqa: E402
from holofit.scattering.tmatrix_wave import TMatrixWave  # noqa: E402
from tests.exact_references import (  # noqa: E402
    ExtrapolatedWave,
    FarFieldWave,
    ld_ebcm_amplitude,
    pytmatrix_amplitude,
)

CACHE = HERE / ".cache"
CROP = 140
ALPHA = 0.9
START_OFFSET_UM = (0.03, -0.02, 0.25)
START_TURN_RAD = (math.radians(5.0), math.radians(3.0))  # psi, theta
#: the rod reference's order (its change from order - 4 is its stated accuracy)
ROD_ORDER = 54
#: dipoles per wavelength of the Janus reference (extrapolated to d = 0) and of its check
JANUS_RULES = (20.0, 28.0)
JANUS_CHECK_RULE = 14.0
#: a Janus axis this far off the truth is on the wrong branch, deg
WRONG_BRANCH_DEG = 30.0
SPHEROID = Spheroid(0.5 / 2 ** (1 / 3), 2 * 0.5 / 2 ** (1 / 3), 1.45)

#: case -> (instrument, (psi, theta, z_um) per frame)
FRAMES: dict[str, tuple[str, list[tuple[float, float, float]]]] = {
    "rod": ("paper_60x_water", [(0.6, 1.0, 12.0), (1.9, 0.45, 10.0), (-0.8, 1.45, 14.0)]),
    "spheroid": ("paper_60x_water", [(0.6, 1.0, 12.0), (1.9, 0.45, 10.0), (-0.8, 1.45, 14.0)]),
    "janus": ("paper_100x_oil", [(0.6, 1.0, 12.0), (1.9, 0.4, 10.0), (-0.8, 2.2, 14.0),
                                 (2.8, 1.6, 12.0)]),
}


def truth_of(case: str) -> ParticleModel:
    """The case's particle (module docstring)."""
    if case == "spheroid":
        return SPHEROID
    name = {"rod": "rod_paper", "janus": "janus_paper"}[case]
    return load_particle(resolve_config(name, "particles")).model


class References:
    """The independent reference waves of each case, built once (module docstring)."""

    def __init__(self, case: str, truth: ParticleModel, optics,
                 precision_order: int | None = None) -> None:
        self.case, self.truth, self.optics = case, truth, optics
        self.precision_order = precision_order
        self._exact = None
        self.seconds = 0.0
        self._solves: dict[tuple, object] = {}
        t0 = time.perf_counter()
        if case == "rod":
            self._amp = ld_ebcm_amplitude(truth, optics, ROD_ORDER, cache=CACHE)
        elif case == "spheroid":
            self._amp = pytmatrix_amplitude(truth, optics)
        self.seconds += time.perf_counter() - t0

    def janus_wave(self, o: Orientation, rules: tuple[float, ...]) -> ExtrapolatedWave:
        """The DDA at ``rules`` extrapolated to d = 0 (linearly, or quadratically for three)."""
        waves, sizes = [], []
        for dpl in rules:
            settings = DDASettings(dipoles_per_wavelength=dpl, tolerance=1e-7)
            key = (dpl, o.as_tuple())
            if key not in self._solves:
                self._solves[key] = BuiltinDDA(settings).solve_direct(self.truth, self.optics, o)
            waves.append(self._solves[key])
            sizes.append(settings.dipole_size_for(self.truth, self.optics))
        return ExtrapolatedWave(waves, sizes)

    def wave(self, o: Orientation):
        t0 = time.perf_counter()
        if self.precision_order is not None:
            if self._exact is None:
                self._exact = build_exact_tmatrix(self.truth, self.optics,
                                                  order=self.precision_order, estimate=False)
            out = TMatrixWave(self.truth, self.optics, o, self._exact)
        elif self.case == "janus":
            out = self.janus_wave(o, JANUS_RULES)
        else:
            out = FarFieldWave(self.truth, self.optics, o, self._amp)
        self.seconds += time.perf_counter() - t0
        return out


def _far_error(a, b, dirs) -> float:
    fa, fb = a.far_field_amplitude(dirs), b.far_field_amplitude(dirs)
    return float(np.abs(fa - fb).max() / np.abs(fb).max())


def reference_accuracy(case: str, refs: References, o: Orientation) -> dict[str, float]:
    """The reference's own accuracy (module docstring), far field relative to its maximum."""
    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(150, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    truth, optics = refs.truth, refs.optics
    ref = refs.wave(o)
    tm = build_exact_tmatrix(truth, optics, max_seconds=60.0)
    exact = TMatrixWave(truth, optics, o, tm)
    out = {f"{case}_reference_vs_exact_engine_far_field": _far_error(exact, ref, dirs),
           f"{case}_exact_engine_order": float(tm.order),
           f"{case}_exact_engine_truncation_estimate": float(tm.provenance["truncation_estimate"])}
    if case == "rod":
        lower = FarFieldWave(truth, optics, o,
                             ld_ebcm_amplitude(truth, optics, ROD_ORDER - 4, cache=CACHE))
        out["rod_reference_order_change_far_field"] = _far_error(lower, ref, dirs)
    elif case == "spheroid":
        tm = build_exact_tmatrix(truth, optics, order=28)
        out["spheroid_reference_vs_exact_order28_far_field"] = _far_error(
            TMatrixWave(truth, optics, o, tm), ref, dirs)
    else:
        quad = refs.janus_wave(o, (JANUS_CHECK_RULE, *JANUS_RULES))
        out["janus_reference_linear_vs_quadratic_far_field"] = _far_error(quad, ref, dirs)
    return out


def _geometry(inst, frame: tuple[float, float, float]):
    px = inst.pixel_size_um
    grid = DetectorGrid((CROP, CROP), px, (100, 200))
    pos = ((200 + 70.3) * px, (100 + 69.6) * px, frame[2])
    return grid, pos


def _start_model(model: ParticleModel) -> ParticleModel:
    changes: dict[str, float | complex] = {}
    for f in model.size_fields:
        changes[f] = getattr(model, f) * 1.02
    for f in model.index_fields:
        changes[f] = complex(getattr(model, f)).real + 0.01
    return model.replace(**changes)


def _axis(theta: float, psi: float) -> np.ndarray:
    return np.array([np.sin(theta) * np.cos(psi), np.sin(theta) * np.sin(psi), np.cos(theta)])


def fit_one(engine, truth: ParticleModel, inst, crop, frame, grid, pos) -> dict:
    """One fit of ``crop`` (module docstring) and the bias of every parameter."""
    o = Orientation(frame[0], frame[1])
    free = ["x_um", "y_um", "z_um", "alpha", "orientation",
            *[p.name for p in static_parameters(truth)]]
    start = tuple(p + s for p, s in zip(pos, START_OFFSET_UM, strict=True))
    cand = Candidate(o.psi + START_TURN_RAD[0], o.theta + START_TURN_RAD[1], 0.0, 0.0)
    problem = FrameProblem(crop, grid.corner, inst.pixel_size_um, engine, _start_model(truth),
                           inst.optics, tuple(free), settings=FrameFitSettings(), seed=0)
    t0 = time.perf_counter()
    res = fit_frame(problem, start, 0.8, [cand])
    wall = time.perf_counter() - t0
    truth_values = {"x_um": pos[0], "y_um": pos[1], "z_um": pos[2], "alpha": ALPHA,
                    "theta_rad": o.theta, "psi_rad": o.psi}
    for p in static_parameters(truth):
        truth_values[p.name] = float(complex(getattr(truth, p.field)).real)
    rows = {}
    for name, value in truth_values.items():
        bias = res.values[name] - value
        if name == "psi_rad":
            bias = (bias + math.pi) % (2 * math.pi) - math.pi
        err = res.errors.get(name, math.nan)
        rows[name] = {"truth": value, "fitted": res.values[name], "bias": bias, "error": err,
                      "bias_over_error": bias / err if err else math.nan}
    u = _axis(res.values["theta_rad"], res.values["psi_rad"])
    cos = float(u @ _axis(o.theta, o.psi))
    if truth.head_tail_symmetric:
        cos = abs(cos)
    axis_deg = math.degrees(math.acos(min(1.0, cos)))
    flagged = res.status != "ok" or bool(res.extra.get("ambiguous", 0))
    return {"status": res.status, "ambiguous": int(res.extra.get("ambiguous", 0)),
            "flagged": flagged, "r2": res.r2, "wall_s": wall, "axis_deg": axis_deg,
            "wrong_branch": axis_deg > WRONG_BRANCH_DEG, "params": rows}


def summarise(fits: list[dict]) -> dict[str, dict]:
    """Per case and engine: every parameter's bias in units of its error, ``z = (noise-free
    fit - truth) / sigma`` with ``sigma`` the mean error of the frame's noisy fits, as its
    largest ``|z|`` and its mean over the frames; the noisy fits' pulls ``(fit - truth) /
    error`` (mean and s.d.); the axis error (noise-free fits: largest; noisy: rms); the
    wrong-branch counts."""
    out: dict[str, dict] = {}
    for key in sorted({(f["case"], f["engine"]) for f in fits}):
        group = [f for f in fits if (f["case"], f["engine"]) == key and not f["wrong_branch"]]
        names = list(group[0]["params"]) if group else []
        s: dict[str, float] = {"fits": float(len(group))}
        z: dict[str, list[float]] = {n: [] for n in names}
        for frame in sorted({f["frame"] for f in group}):
            clean = [f for f in group if f["frame"] == frame and f["seed"] < 0]
            noisy = [f for f in group if f["frame"] == frame and f["seed"] >= 0]
            if not clean or not noisy:
                continue
            for n in names:
                sigma = float(np.mean([f["params"][n]["error"] for f in noisy]))
                z[n].append(clean[0]["params"][n]["bias"] / sigma)
        for n in names:
            zz = np.array(z[n])
            s[f"{n}_max_abs_bias_over_error"] = float(np.max(np.abs(zz))) if zz.size else math.nan
            s[f"{n}_mean_bias_over_error"] = float(np.mean(zz)) if zz.size else math.nan
            pulls = np.array([f["params"][n]["bias_over_error"] for f in group if f["seed"] >= 0])
            s[f"{n}_pull_mean"] = float(np.mean(pulls)) if pulls.size else math.nan
            s[f"{n}_pull_sd"] = float(np.std(pulls)) if pulls.size > 1 else math.nan
        clean_axis = [f["axis_deg"] for f in group if f["seed"] < 0]
        noisy_axis = np.array([f["axis_deg"] for f in group if f["seed"] >= 0])
        s["axis_noise_free_max_deg"] = float(max(clean_axis)) if clean_axis else math.nan
        s["axis_noisy_rms_deg"] = (float(np.sqrt(np.mean(noisy_axis**2))) if noisy_axis.size
                                   else math.nan)
        every = [f for f in fits if (f["case"], f["engine"]) == key]
        s["wrong_branch"] = float(sum(f["wrong_branch"] for f in every))
        s["wrong_branch_unflagged"] = float(sum(f["wrong_branch"] and not f["flagged"]
                                                for f in every))
        s["wall_s_mean"] = float(np.mean([f["wall_s"] for f in every]))
        out[f"{key[0]}_{key[1]}"] = s
    return out


def _engine(name: str, truth: ParticleModel, optics):
    """The fitting engine by its public name (:func:`holofit.engines.registry.get_engine`):
    ``exact``; ``builtin``: the DDA at its default rule (one lattice for the whole fit);
    ``builtin-ramp``: the same with the filling before issue 37 (to compare)."""
    if name == "exact":
        engine = get_engine("exact")
        # one discretisation for the fit, fixed at its start model, as the pipeline's fit does
        engine.fix_discretisation(_start_model(truth), optics)
        return engine
    d = DDASettings().dipole_size_for(truth, optics)
    filling = "ramp" if name == "builtin-ramp" else "fractional"
    return get_engine("builtin", settings=DDASettings(dipole_size_um=d, filling=filling))


def _print_fit(r: dict) -> None:
    print(f"## {r['case']} {r['engine']} frame {r['frame']} seed {r['seed']}: {r['status']}, "
          f"R^2 {r['r2']:.5f}, axis {r['axis_deg']:.3f} deg, {r['wall_s']:.0f} s", flush=True)
    print("| parameter | truth | fitted | bias | error | bias/error |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, p in r["params"].items():
        print(f"| {name} | {p['truth']:.5f} | {p['fitted']:.5f} | {p['bias']:.2e} | "
              f"{p['error']:.2e} | {p['bias_over_error']:.2f} |", flush=True)


def run(cases: list[str], seeds: list[int], engines: list[str], partial: Path | None,
        frames_wanted: list[int] | None = None, precision_order: int | None = None) -> dict:
    fits: list[dict] = []
    accuracy: dict[str, float] = {}
    done = set()
    if partial is not None and partial.exists():
        for line in partial.read_text().splitlines():
            row = json.loads(line)
            if "reference_accuracy" in row:
                accuracy.update(row["reference_accuracy"])
            else:
                fits.append(row)
                done.add((row["case"], row["engine"], row["frame"], row["seed"]))
    for case in cases:
        inst_name, frames = FRAMES[case]
        inst = load_instrument(resolve_config(inst_name, "instruments"))
        truth = truth_of(case)
        refs = References(case, truth, inst.optics, precision_order)
        if precision_order is None and not any(k.startswith(f"{case}_reference")
                                               for k in accuracy):
            acc = reference_accuracy(case, refs, Orientation(frames[0][0], frames[0][1]))
            accuracy.update(acc)
            print(f"## {case} reference accuracy: {acc}", flush=True)
            if partial is not None:
                with partial.open("a") as fh:
                    fh.write(json.dumps({"reference_accuracy": acc}) + "\n")
        engine_of = {name: _engine(name, truth, inst.optics) for name in engines}
        for fi, frame in enumerate(frames):
            if frames_wanted is not None and fi not in frames_wanted:
                continue
            todo = [(e, s) for e in engines for s in seeds if (case, e, fi, s) not in done]
            if not todo:
                continue
            grid, pos = _geometry(inst, frame)
            wave = refs.wave(Orientation(frame[0], frame[1]))
            holo = calc_hologram(wave, pos, grid, ALPHA)
            for name, seed in todo:
                crop = holo if seed < 0 else Camera(background_counts=120.0).expose(
                    holo, np.random.default_rng(1000 * fi + seed)) / 120.0
                r = fit_one(engine_of[name], truth, inst, crop, frame, grid, pos)
                r.update(case=case, engine=name, frame=fi, seed=seed,
                         frame_geometry=list(frame), model=truth.kind)
                if precision_order is not None:
                    r["reference"] = f"exact engine at order {precision_order} (precision)"
                _print_fit(r)
                fits.append(r)
                if partial is not None:
                    with partial.open("a") as fh:
                        fh.write(json.dumps(r) + "\n")
    return {"fits": fits, "summary": summarise(fits), "reference_accuracy": accuracy,
            "settings": {"crop": CROP, "alpha": ALPHA, "rod_order": ROD_ORDER,
                         "janus_rules": list(JANUS_RULES), "seeds": seeds}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(FRAMES))
    ap.add_argument("--seeds", type=int, nargs="*", default=[-1, 0, 1],
                    help="camera-noise seeds; -1: no noise (the model's own bias)")
    ap.add_argument("--frames", type=int, nargs="*", default=None)
    ap.add_argument("--engines", nargs="*", default=["exact", "builtin"])
    ap.add_argument("--out", type=Path, default=HERE / "results" / "exact" /
                    "study_exact_fits.json")
    ap.add_argument("--partial", type=Path, default=None,
                    help="JSON-lines file of finished fits, read to resume and appended to")
    ap.add_argument("--precision-order", type=int, default=None,
                    help="make the holograms by holofit's exact engine at this order instead "
                         "(not independent: a precision check of the fit's own order)")
    ap.add_argument("--iitm-extra-orders", type=int, default=None,
                    help="orders past the start the fit's imbedding may rise (default: "
                         "holofit.scattering.axisym.discretisation.IITM_EXTRA_ORDERS)")
    args = ap.parse_args()
    if args.iitm_extra_orders is not None:
        discretisation.IITM_EXTRA_ORDERS = args.iitm_extra_orders
    out = run(args.cases, args.seeds, args.engines, args.partial, args.frames,
              args.precision_order)
    for key, s in out["summary"].items():
        print(f"## summary {key}: " + ", ".join(f"{k} {v:.3g}" for k, v in s.items()))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
