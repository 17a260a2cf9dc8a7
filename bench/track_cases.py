"""The tracking final pass along a 200-frame track (``python bench/track_cases.py CASE
[--frames N]``): prints JSON. Issue targets: ``fit_<p>_frame_final_s`` <= 0.1 s and
``fit_<p>_evals_per_frame`` <= 20 for the rod and the Janus particle.

The paper's particle and instrument of :mod:`fit_cases` (objective lens in the model, 140 x 140
crops, 8-bit camera, background 120 counts), the final pass's particle (the truth's static
parameters) with its engine's T-matrix (built once and kept in ``bench/.cache/``). The track:
from the case's truth (z 12 um, orientation (psi, theta) = (0.6, 1.0) rad) the particle takes
Gaussian steps of 50 nm per axis (~85 nm per frame, the paper's rod) and 3 deg per angle
(~4 deg of its axis per frame), sinking 9 nm per frame; each frame's crop is centred on the
pixel nearest the particle (as the crop stage does), its hologram made from the same T-matrix
and exposed with its own noise. Each frame's "prefit" start is the truth moved by
(30, -20, 250) nm with alpha 0.85, its library candidates those of the library stage at that
start (:func:`fit_cases.library_candidates`, precomputed: the library is its own stage).

Reported: the mean time (wall, and the process's CPU time: ``..._cpu_s``, less sensitive to
other jobs on a shared machine) and hologram evaluations per frame of :func:`follow_chunk` over the
whole track (one chunk: its first frame a library fit, re-acquisitions included), with the
chi^2 bar of :func:`holofit.fit.continuity.chi2_bar` over the first 12 frames fitted
independently (their mean time and evaluations are the ``independent`` baseline on the same
frames and machine); how the frames were obtained; the errors against the truth; frames on a
wrong branch (axis > 20 deg from the truth) that are ``ok`` and not flagged (``ambiguous`` or
``follow_jump``); the frames the continuity sweeps would still refit
(:func:`holofit.fit.continuity.suspects`, an upper bound of what they change).
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

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fit_cases import (
    CROP,
    START_ALPHA,
    START_OFFSET_UM,
    Case,
    library_candidates,
    make_case,
    make_library,
    use_tmatrix,
)

from holofit.camera import Camera
from holofit.conventions import DetectorGrid
from holofit.fit.continuity import ContinuitySettings, suspects
from holofit.fit.follow import chunk_fitter, follow_chunk
from holofit.fit.follower import ChunkFrame
from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem
from holofit.fit.settings import FollowSettings, FrameFitSettings
from holofit.hologram import calc_hologram
from holofit.holomodel.result import result_row
from holofit.quality import chi2_bar
from holofit.scattering.theory import Orientation

CACHE = Path(__file__).resolve().parent / ".cache"
FINAL = ("x_um", "y_um", "z_um", "orientation", "alpha")
STEP_UM, STEP_RAD, SINK_UM = 0.05, math.radians(3.0), 0.009
N_BAR = 12


def make_track(case: Case, theory, model, n: int, seed: int = 0):
    """The frames (ChunkFrame without candidates yet) and the truth, per frame."""
    rng = np.random.default_rng(seed)
    px = case.inst.pixel_size_um
    pos = np.array(case.position_um) + np.cumsum(rng.normal(0, STEP_UM, (n, 3)), axis=0)
    pos[:, 2] -= SINK_UM * np.arange(n)
    pos[0] = case.position_um
    ang = np.array([case.orientation.psi, case.orientation.theta]) + np.cumsum(
        rng.normal(0, STEP_RAD, (n, 2)), axis=0)
    ang[0] = (case.orientation.psi, case.orientation.theta)
    cam = Camera(background_counts=120.0)
    frames = []
    for k in range(n):
        corner = (round(pos[k, 1] / px) - CROP // 2, round(pos[k, 0] / px) - CROP // 2)
        grid = DetectorGrid((CROP, CROP), px, corner)
        wave = theory.solve(model, case.inst.optics, Orientation(ang[k, 0], ang[k, 1]))
        holo = calc_hologram(wave, tuple(pos[k]), grid, case.alpha)
        crop = cam.expose(holo, rng) / 120.0
        start = tuple(pos[k] + np.array(START_OFFSET_UM))
        frames.append(ChunkFrame(k, crop, corner, start, START_ALPHA, (), k * 0.01))
    return frames, pos, ang


def _axis_errors(tab: pd.DataFrame, ang: np.ndarray, head_tail: bool) -> np.ndarray:
    u = tab[["ux", "uy", "uz"]].to_numpy(dtype=float)
    ut = np.stack([np.sin(ang[:, 1]) * np.cos(ang[:, 0]), np.sin(ang[:, 1]) * np.sin(ang[:, 0]),
                   np.cos(ang[:, 1])], axis=1)
    dot = np.sum(u * ut, axis=1) / np.linalg.norm(u, axis=1)
    if head_tail:
        dot = np.abs(dot)
    return np.degrees(np.arccos(np.clip(dot, -1, 1)))


def run(name: str, n: int, track_opts: dict | None = None) -> dict[str, float]:
    case = make_case(name)
    model, theory = case.fit_model()
    CACHE.mkdir(exist_ok=True)
    out: dict[str, float] = {}
    out[f"track_{name}_tmatrix_s"] = use_tmatrix(theory, model, case.inst,
                                                 CACHE / f"{name}_final_tmatrix.npz")
    lib = make_library(theory, model, case.inst)
    frames, pos, ang = make_track(case, theory, model, n)
    px = case.inst.pixel_size_um
    for i, f in enumerate(frames):  # the library stage's candidates at each frame's start
        c = Case(case.name, case.inst, case.config, case.model, case.orientation,
                 DetectorGrid((CROP, CROP), px, f.corner), case.position_um, case.alpha,
                 case.hologram)
        frames[i] = ChunkFrame(f.frame, f.crop, f.corner, f.position_um, f.alpha,
                               tuple(library_candidates(lib, c, f.crop, f.position_um)),
                               f.time_s)
    opts = FrameFitSettings()
    # independent frames (today's final pass) on the first N_BAR: the baseline and the bar
    t0 = time.perf_counter()
    rows = []
    for f in frames[:N_BAR]:
        res = fit_frame(
            FrameProblem(
                f.crop,
                f.corner,
                px,
                theory,
                model,
                case.inst.optics,
                FINAL,
                settings=opts,
                seed=f.frame,
            ),
            f.position_um,
            f.alpha,
            f.candidates,
        )
        rows.append(result_row(f.frame, f.time_s, res))
    indep = pd.DataFrame(rows)
    out[f"fit_{name}_frame_independent_s"] = (time.perf_counter() - t0) / N_BAR
    out[f"fit_{name}_independent_evals_per_frame"] = float(indep["n_eval"].mean())
    bar = chi2_bar(indep, 4.0)
    out[f"track_{name}_chi2_bar"] = bar
    t0 = time.perf_counter()
    c0 = time.process_time()
    tab = follow_chunk(
        frames,
        chunk_fitter(
            theory,
            model,
            case.inst.optics,
            px,
            FINAL,
            FollowSettings(frame=opts, **(track_opts or {})),
        ),
        bar,
    )
    out[f"fit_{name}_frame_final_s"] = (time.perf_counter() - t0) / n
    out[f"fit_{name}_frame_final_cpu_s"] = (time.process_time() - c0) / n
    out[f"fit_{name}_evals_per_frame"] = float(tab["n_eval"].mean())
    out[f"fit_{name}_solves_per_frame"] = float(tab["n_solves"].mean())
    out[f"track_{name}_frames"] = float(n)
    for src in ("library", "warm", "reacquired"):
        out[f"track_{name}_{src}_frames"] = float((tab["follow_source"] == src).sum())
    for how, label in ((0, "carried"), (1, "screened"), (2, "refitted")):
        out[f"track_{name}_runner_up_{label}_frames"] = float((tab["runner_up_refit"] == how).sum())
    for how, label in ((0, "kept"), (1, "changed")):
        out[f"track_{name}_pole_probed_{label}_frames"] = float((tab["follow_pole"] == how).sum())
    out[f"track_{name}_ok_frames"] = float((tab["status"] == "ok").sum())
    out[f"track_{name}_jump_frames"] = float(tab["follow_jump"].sum())
    out[f"track_{name}_ambiguous_frames"] = float(tab["ambiguous"].sum())
    err = tab[["x_um", "y_um", "z_um"]].to_numpy(dtype=float) - pos
    for i, axis in enumerate("xyz"):
        out[f"track_{name}_{axis}_rms_nm"] = 1e3 * float(np.sqrt(np.mean(err[:, i] ** 2)))
    ax = _axis_errors(tab, ang, model.head_tail_symmetric)
    out[f"track_{name}_axis_rms_deg"] = float(np.sqrt(np.mean(ax**2)))
    wrong = ax > 20.0
    flagged = (tab["status"] != "ok") | (tab["ambiguous"] == 1) | (tab["follow_jump"] == 1)
    out[f"track_{name}_wrong_branch_frames"] = float(wrong.sum())
    out[f"track_{name}_wrong_branch_ok_unflagged"] = float((wrong & ~flagged).sum())
    # what the continuity sweeps would still refit (an upper bound of what they change)
    out[f"track_{name}_sweep_suspects"] = float(
        suspects(tab, ContinuitySettings(), model.head_tail_symmetric).sum()
    )
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("case", choices=("rod", "janus"))
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument(
        "--track-opts",
        type=json.loads,
        default=None,
        help="FollowSettings fields as JSON (an A/B of the tracker's settings)",
    )
    args = parser.parse_args()
    print(json.dumps(run(args.case, args.frames, args.track_opts)))
