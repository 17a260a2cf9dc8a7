"""How close a Janus movie's fits can come to the truth (``python bench/janus_floor.py RUN``;
prints JSON; not a test).

``RUN`` is the run folder of a simulated Janus movie (``make replicate``'s ``janus/`` or
``bench/short_movie.py``'s ``run/``), with the simulation's ``truth.csv`` in ``RUN/sim/`` or
given by ``--truth``. Every ``--step``-th ``ok`` frame of the final fit is refitted from its true
pose (position, axis, the final fit's alpha) until converged (no mirror, no early stop), with:

- ``fitted``: the movie's static parameters (``fit/static.json``) and T-matrix
  (``fit/tmatrix.npz``), the model the final pass fits;
- ``truth``: the true static parameters (the paper's Janus particle, the simulation's), its
  T-matrix built once and kept in ``bench/.cache/``;
- ``truth_spin``: the same, the model's lattice turned by the true spin phi about the axis
  (as the simulation renders each frame);
- ``truth_phi_average``: the same T-matrix averaged over phi (its m != m' couplings dropped).

Reported for each, and for the final fit's own rows (``run``): the axis rms off the truth (deg)
over all the frames, those within 30 deg of the optical axis (``_pole``) and the others
(``_away``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from truth_compare import axis_from_angles

from holofit.batch.stage import FrameLoader
from holofit.config import ParticleConfig, load_instrument, load_particle, resolve_config
from holofit.fit.problem import FrameProblem, state_of
from holofit.fit.settings import FrameFitSettings
from holofit.fit.static import read_static
from holofit.fit.task import free_parameters
from holofit.fit.warm import fit_frame_warm
from holofit.holomodel.parameters import particle_with
from holofit.particles import JanusSphere
from holofit.scattering.tmatrix import TMatrix
from holofit.scattering.vsw import term_indices
from holofit.tables.cropset import CropSet
from holofit.tables.inputs import read_stage_table

#: the simulation's particle (``bench/replicate.py``, ``bench/short_movie.py``)
TRUE_JANUS = JanusSphere(0.443, 0.047, 1.581, 2.74)
CACHE = Path(__file__).resolve().parent / ".cache"


def phi_average(tm: TMatrix) -> TMatrix:
    """``tm`` averaged over rotations about the particle's axis: only its m = m' couplings."""
    _, _, m = term_indices(tm.order)
    dense = tm.dense()
    dense[m[:, None] != m[None, :]] = 0.0
    return TMatrix.from_dense(dense, tm.order, tm.k, tm.radius_um, 2 * tm.order + 1,
                              tm.provenance)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("run", type=Path)
    parser.add_argument("--truth", type=Path, default=None)
    parser.add_argument("--step", type=int, default=15)
    parser.add_argument("--instrument", default="paper_100x_oil")
    parser.add_argument("--particle", default="janus_paper")
    args = parser.parse_args()
    run = args.run
    truth = pd.read_csv(args.truth or run / "sim" / "truth.csv").set_index("frame")
    inst = load_instrument(resolve_config(args.instrument, "instruments"))
    base = load_particle(resolve_config(args.particle, "particles"))

    def theory_of(model, path):
        part = ParticleConfig(model, base.settings, base.path).with_fixed_lattice(inst.optics)
        theory = part.theory(None, fixed_lattice_for=inst.optics)
        return theory, theory.tmatrix(model, inst.optics, path=str(path))

    fitted = particle_with(base.model, read_static(run / "fit" / "static.json", base.model))
    CACHE.mkdir(exist_ok=True)
    th_fit, _ = theory_of(fitted, run / "fit" / "tmatrix.npz")
    th_true, tm_true = theory_of(TRUE_JANUS, CACHE / "janus_floor_truth_tmatrix.npz")
    th_avg, _ = theory_of(TRUE_JANUS, CACHE / "janus_floor_truth_tmatrix.npz")
    th_avg.use_tmatrix(TRUE_JANUS, inst.optics, phi_average(tm_true), source="phi average")
    cases = {"fitted": (fitted, th_fit, False), "truth": (TRUE_JANUS, th_true, False),
             "truth_spin": (TRUE_JANUS, th_true, True),
             "truth_phi_average": (TRUE_JANUS, th_avg, False)}

    fit = pd.read_csv(run / "fit" / "fit.csv").set_index("frame")
    crops = CropSet(run / "crop")
    prefit, _ = read_stage_table(run / "prefit" / "prefit.csv", crops, "prefit")
    loader = FrameLoader(crops, prefit)
    frames = [f for f in fit.index[::args.step] if fit.loc[f, "status"] == "ok"]
    settings = FrameFitSettings(mirror=False, warm_stop_chi2=0.0)

    def off(values, t) -> float:
        u = axis_from_angles(values["theta_rad"], values["psi_rad"])
        return math.degrees(math.acos(min(1.0, float(np.sum(
            u * axis_from_angles(t.theta_rad, t.psi_rad))))))

    errors: dict[str, list[float]] = {"run": [], **{k: [] for k in cases}}
    near = []
    for frame in frames:
        start, t = loader(frame), truth.loc[frame]
        errors["run"].append(off(fit.loc[frame], t))
        near.append(min(t.theta_rad, math.pi - t.theta_rad) < math.radians(30.0))
        pose = {"x_um": t.x_um, "y_um": t.y_um, "z_um": t.z_um, "theta_rad": t.theta_rad,
                "psi_rad": t.psi_rad, "alpha": fit.loc[frame, "alpha"]}
        for name, (model, theory, spin) in cases.items():
            state = state_of({**pose, **({"phi_rad": t.phi_rad} if spin else {})}, model)
            res = fit_frame_warm(
                FrameProblem(
                    start.crop,
                    start.corner,
                    inst.pixel_size_um,
                    theory,
                    model,
                    inst.optics,
                    free_parameters(model, "final"),
                    settings=settings,
                    seed=frame,
                ),
                state,
            ).result
            errors[name].append(off(res.values, t))
    near_mask = np.array(near)
    out: dict[str, float] = {"frames": float(len(frames)), "frames_pole": float(near_mask.sum())}
    for name, values in errors.items():
        v = np.asarray(values)
        out[f"{name}_axis_rms_deg"] = float(np.sqrt(np.mean(v**2)))
        for label, mask in (("pole", near_mask), ("away", ~near_mask)):
            out[f"{name}_axis_rms_{label}_deg"] = (
                float(np.sqrt(np.mean(v[mask] ** 2))) if mask.any() else math.nan
            )
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
