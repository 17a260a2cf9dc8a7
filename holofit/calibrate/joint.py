"""Joint fit of several sphere holograms that share one instrument: the objective's numerical
aperture, its spherical-aberration coefficients (:mod:`holofit.aberration`) and optionally the
polarisation angle are common to every frame; each frame's sphere (position, radius, index,
alpha) is its own.

Why jointly: in one hologram the aberration's phase over the pupil trades off against the
particle's height and, less, its index and size (the defocus phase ``k z (cos th - 1)`` and the
4th-order term ``-c_0 (cos th - 1)^2`` differ only in their power of the pupil coordinate), so
a single frame fixes the coefficients poorly and can hold several minima. Spheres at several
heights see the same pupil through different defocus, which separates the two; that is how an
instrument is calibrated (Martin, Leahy & Manoharan, Opt. Express 2022).

The fit is holofit's one least-squares fit (:func:`holofit.holomodel.leastsq.solve_least_squares`)
of a model that stacks the frames' forward models (:class:`holofit.holomodel.forward.HologramModel`,
exact Lorenz-Mie through the lens), each frame's residuals divided by its pixel noise so that
every frame weighs by its information; its Jacobian is the frames' own columns, the shared ones
(exact for the aberration, one re-imaging of the solved wave for the NA, a re-solve for the
polarisation) stacked in one column each. It goes in the steps a rugged misfit needs:

1. every frame's sphere from ``holofit prefit``'s automatic start
   (:func:`holofit.prefit.sphere.fit_sphere_crop`, with the start instrument), unless given;
2. the aberration coefficients from each of a few starts (the instrument's own and a grid),
   everything but the NA free, on a random subset of each frame's pixels; the best kept;
3. with a fitted NA: the NA of least misfit on a grid (every other parameter held), as the
   single-frame NA fit does (:mod:`holofit.holomodel.aperture`), and everything fitted from
   each of the scan's deepest minima on all pixels, the best kept; otherwise everything fitted
   once on all pixels.

Errors are ``(J^T J)^-1`` of the weighted residuals times their reduced chi^2 (the convention of
:func:`holofit.holomodel.statistics.covariance_from_jacobian`), so a frame's parameters carry the
instrument's uncertainty; a fitted NA's error is at least the half-width of the scan's NAs whose
misfit is within :data:`holofit.holomodel.result.APERTURE_CHI2` of the best, as for one frame.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import SPHERICAL_NAMES, Aberration, spherical_basis
from holofit.calibrate.model import Frame, JointModel
from holofit.calibrate.settings import (
    DEFAULT_ABERRATION_STARTS,
    INSTRUMENT_PREFIX,
    POLARIZATION,
    InstrumentFit,
    JointFitSettings,
    SphereFrame,
)
from holofit.calibrate.solver import NormalSolution, covariance_from_normal, solve_normal_lm
from holofit.holomodel.aperture import SCAN_LOWEST, SCAN_STEP, aperture_minima, aperture_start
from holofit.holomodel.forward import InvalidParameters
from holofit.holomodel.parameters import APERTURE
from holofit.holomodel.pixels import select_pixels
from holofit.holomodel.result import APERTURE_CHI2, FitResult, aperture_spread
from holofit.holomodel.statistics import estimate_noise_sd
from holofit.optics import Optics
from holofit.prefit.sphere import SPHERE_COLUMNS, fit_sphere_crop
from holofit.status import NOT_CONVERGED, OK

__all__ = [
    "DEFAULT_ABERRATION_STARTS",
    "INSTRUMENT_PREFIX",
    "POLARIZATION",
    "InstrumentFit",
    "JointFitSettings",
    "SphereFrame",
    "calibrate_instrument",
]


def _prefit_start(frame: SphereFrame, optics: Optics, pixel_size_um: float,
                  settings: JointFitSettings, seed: int) -> dict[str, float]:
    """Step 1: the frame's sphere from the automatic prefit with the start instrument."""
    if frame.start is not None:
        missing = [c for c in SPHERE_COLUMNS if c not in frame.start]
        if missing:
            raise ValueError(f"a frame's start lacks {', '.join(missing)}")
        return {c: float(frame.start[c]) for c in SPHERE_COLUMNS}
    opts = replace(settings.prefit, fit_na=False, fit_aberration=(), seed_only=False)
    if settings.fix_alpha is not None:
        opts = replace(opts, fix_alpha=settings.fix_alpha)
    fit = fit_sphere_crop(frame.crop, frame.corner_rc, frame.centre_xy_um, optics,
                          pixel_size_um, opts, seed=seed)
    return {c: float(fit.values[c]) for c in SPHERE_COLUMNS}


#: what a joint fit tells its ``progress`` callable: the step begun, the steps begun so far,
#: the steps planned (the NA scan's minima set how many full fits follow it)
Progress = Callable[[str, int, int], None]


def calibrate_instrument(frames: Sequence[SphereFrame], optics: Optics, pixel_size_um: float,
                         settings: JointFitSettings | None = None, *,
                         progress: Progress | None = None) -> InstrumentFit:
    """Fit the instrument shared by several sphere holograms (the module docstring).

    Parameters
    ----------
    frames : sequence of SphereFrame
        The holograms (one or more; spheres at several heights fix the aberration best).
    optics : Optics
        The start instrument: wavelength and medium (held), and the start values of the NA
        (required), the aberration and the polarisation.
    pixel_size_um : float
        Pixel pitch in the sample plane, um.
    settings : JointFitSettings, optional
        What is fitted (default: the NA and the 4th- and 6th-order spherical aberration).
    progress : callable, optional
        Called as ``progress(step, begun, planned)`` at the start of each step: a frame's
        prefit, an aberration start, the NA scan, a full fit.

    Returns
    -------
    InstrumentFit

    Raises
    ------
    ValueError
        No frames, no NA in the optics (the lens model is needed), or a frame with too few
        pixels or no automatic start.
    """
    t0 = time.perf_counter()
    st = settings or JointFitSettings()
    if not frames:
        raise ValueError("a joint instrument fit needs at least one frame")
    if optics.numerical_aperture is None:
        raise ValueError("calibrating the objective needs the optics' numerical_aperture "
                         "(the start value)")
    n_terms = max([SPHERICAL_NAMES.index(n) + 1 for n in st.aberration], default=0)
    start_ab = optics.aberration.padded(n_terms)
    base = replace(optics, aberration=start_ab)
    fixed = st.fixed_values()
    frame_names = tuple(n for n in SPHERE_COLUMNS
                        if not (n == "alpha" and st.fix_alpha is not None) and n not in fixed)
    rng = np.random.default_rng(st.seed)
    n_starts = (1 + len(st.aberration_starts if st.aberration_starts is not None
                        else DEFAULT_ABERRATION_STARTS)) if st.aberration else 0
    held_first = int(st.fit_na and bool(st.aberration or st.fit_polarization))
    plan = [sum(f.start is None for f in frames) + n_starts
            + ((held_first + 1 + 3) if st.fit_na else 1), 0]

    def begin(step: str) -> None:
        plan[1] += 1
        plan[0] = max(plan[0], plan[1])
        if progress is not None:
            progress(step, plan[1], plan[0])

    prepared: list[Frame] = []
    for j, fr in enumerate(frames):
        pix = select_pixels(np.asarray(fr.crop, dtype=float), fr.corner_rc, pixel_size_um,
                            fraction=st.pixel_fraction, rng=rng, min_pixels=100)
        noise = fr.noise_sd if fr.noise_sd is not None else estimate_noise_sd(
            np.asarray(fr.crop, dtype=float), pix.valid)
        if not noise > 0:
            raise ValueError(f"frame {j}: no pixel noise estimate (give noise_sd)")
        m = min(st.screen_pixels, pix.size)
        subset = np.sort(rng.choice(pix.size, size=m, replace=False))
        if fr.start is None:
            begin(f"frame {j}: prefit")
        sphere = {**_prefit_start(fr, base, pixel_size_um, st, j), **fixed}
        prepared.append(Frame(pix, float(noise), sphere, subset))
    shared: dict[str, float] = {APERTURE.name: (aperture_start(optics) if st.fit_na
                                                else float(optics.numerical_aperture)),
                                POLARIZATION: float(optics.polarization_rad),
                                **start_ab.values()}
    free_all = ([APERTURE.name] if st.fit_na else []) + list(st.aberration) + (
        [POLARIZATION] if st.fit_polarization else [])
    trials: list[dict] = []
    n_eval = 0

    def run(free: Sequence[str], subset: bool, values: Mapping[str, float],
            max_nfev: int | None = None) -> tuple[JointModel, NormalSolution]:
        nonlocal n_eval
        jm = JointModel(prepared, base, values, free, frame_names, st, subset)
        sol = solve_normal_lm(jm, jm.data(), jm.vector(), max_nfev=max_nfev or st.max_nfev,
                              ftol=1e-6 if subset else st.ftol,
                              xtol=1e-6 if subset else st.xtol)
        n_eval += jm.n_holograms
        return jm, sol

    def adopt(jm: JointModel, sol: NormalSolution) -> dict[str, float]:
        values, spheres = jm.values(sol.vector)
        for f, s in zip(prepared, spheres, strict=True):
            f.sphere = s
        return values

    # step 2: the aberration from several starts, the NA held, on pixel subsets
    if st.aberration:
        starts = [tuple(shared[n] for n in st.aberration)]
        for c in (st.aberration_starts if st.aberration_starts is not None
                  else DEFAULT_ABERRATION_STARTS):
            c = tuple(float(x) for x in c)[: len(st.aberration)]
            c = c + starts[0][len(c):]
            if c not in starts:
                starts.append(c)
        plan[0] += len(starts) - n_starts
        spheres0 = [dict(f.sphere) for f in prepared]
        best: tuple[float, dict, list] | None = None
        free = [n for n in free_all if n != APERTURE.name]
        for k, c in enumerate(starts):
            begin(f"aberration start {k + 1}/{len(starts)}")
            for f, s in zip(prepared, spheres0, strict=True):
                f.sphere = dict(s)
            values = {**shared, **dict(zip(st.aberration, c, strict=True))}
            jm, sol = run(free, True, values, max_nfev=40)
            trials.append({"step": "aberration_start", **dict(zip(st.aberration, c,
                                                                   strict=True)),
                           "chi2_red": sol.rss / max(sol.residuals.size - sol.vector.size, 1)})
            if np.isfinite(sol.rss) and (best is None or sol.rss < best[0]):
                values, spheres = jm.values(sol.vector)
                best = (sol.rss, values, spheres)
        assert best is not None
        shared = best[1]
        for f, s in zip(prepared, best[2], strict=True):
            f.sphere = s
    # step 3: everything on all pixels (from the NA scan's deepest minima if it is fitted)
    scan: tuple[NDArray, NDArray] | None = None
    if st.fit_na:
        held = [n for n in free_all if n != APERTURE.name]
        if held:
            begin("all frames, the NA held")
            jm, sol = run(held, False, shared)
            shared = adopt(jm, sol)
        begin("NA scan")
        grid, rss = _scan_aperture(prepared, base, shared, frame_names, st)
        scan = (grid, rss)
        na_starts = aperture_minima(grid, rss) or [shared[APERTURE.name]]
        plan[0] = plan[1] + len(na_starts)
        spheres0 = [dict(f.sphere) for f in prepared]
        best_run: tuple[JointModel, NormalSolution] | None = None
        for k, na in enumerate(na_starts):
            begin(f"full fit {k + 1}/{len(na_starts)} from NA {na:.3f}")
            for f, s in zip(prepared, spheres0, strict=True):
                f.sphere = dict(s)
            jm, sol = run(free_all, False, {**shared, APERTURE.name: na})
            trials.append({"step": "aperture_start", APERTURE.name: na,
                           "chi2_red": sol.rss / max(sol.residuals.size - sol.vector.size, 1)})
            if best_run is None or (np.isfinite(sol.rss) and sol.rss < best_run[1].rss):
                best_run = (jm, sol)
        assert best_run is not None
        jm, sol = best_run
    else:
        begin("full fit")
        jm, sol = run(free_all, False, shared)
    shared = adopt(jm, sol)
    return _result(jm, sol, prepared, base, shared, scan, trials, n_eval,
                   time.perf_counter() - t0)


def _scan_aperture(frames: list[Frame], optics: Optics, shared: Mapping[str, float],
                   frame_names: Sequence[str], settings: JointFitSettings
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The weighted misfit of all frames on a grid of NAs (every other parameter held; the
    grid of :func:`holofit.holomodel.aperture.scan_aperture`), on the step-2 subsets."""
    top = optics.n_medium
    na0 = float(shared[APERTURE.name])
    grid = np.unique(np.concatenate([np.arange(SCAN_LOWEST, top, SCAN_STEP),
                                     [top, min(na0, top)]]))
    rss = np.full(grid.size, np.inf)
    for i, na in enumerate(grid):
        jm = JointModel(frames, optics, {**shared, APERTURE.name: float(na)}, (), frame_names,
                         settings, subset=True)
        try:
            r = jm.hologram(jm.vector()) - jm.data()
        except InvalidParameters:
            continue
        rss[i] = float(r @ r)
    return grid, rss


def _result(jm: JointModel, sol: NormalSolution, frames: list[Frame], optics: Optics,
            shared: Mapping[str, float], scan: tuple[NDArray, NDArray] | None,
            trials: list[dict], n_eval: int, time_s: float) -> InstrumentFit:
    n = int(sol.residuals.size)
    p = int(sol.vector.size)
    cov = covariance_from_normal(sol.normal, sol.rss, n)
    dof = max(n - p, 1)
    chi2_red = sol.rss / dof
    values = {name: float(shared[name]) for name in jm.free_shared}
    errors = {}
    for i, name in enumerate(jm.free_shared):
        errors[name] = float(np.sqrt(cov[i, i])) if cov[i, i] >= 0 else math.nan
    if scan is not None and APERTURE.name in errors:
        spread = aperture_spread(*scan, APERTURE_CHI2 * chi2_red * _scan_fraction(frames))
        local = errors[APERTURE.name]
        errors[APERTURE.name] = spread if not local >= spread else local
    fitted_optics = replace(
        optics, numerical_aperture=float(shared[APERTURE.name]),
        polarization_rad=float(shared.get(POLARIZATION, optics.polarization_rad)),
        aberration=Aberration.from_values(dict(shared), optics.aberration))
    edge, edge_error = _edge_phase(fitted_optics, jm.free_shared, cov)
    status = OK if sol.converged else NOT_CONVERGED
    results = []
    models = jm._models_for(jm._beta(sol.vector))
    for j, (f, idx, m) in enumerate(zip(frames, jm._index, models, strict=True)):
        space = m.space
        vj = sol.vector[idx]
        vals, errs = space.report(vj, cov[np.ix_(idx, idx)])
        for name in (APERTURE.name, *SPHERICAL_NAMES):
            vals.pop(name, None)
            errs.pop(name, None)
        res = sol.residuals[jm._rows[j]:jm._rows[j + 1]] / jm.weights[j]
        rss_j = float(res @ res)
        n_j = int(res.size)
        data = f.pix.data
        r2 = 1.0 - rss_j / float(np.sum((data - data.mean()) ** 2))
        p_j = len(jm.frame_names)
        results.append(FitResult(
            values=vals, errors=errs, free=space.names, rss=rss_j, chi2=rss_j / n_j,
            chi2_red=rss_j / (f.noise_sd**2 * max(n_j - p_j, 1)), noise_sd=f.noise_sd, r2=r2,
            n_pixels=n_j, n_eval=0, n_solves=m.n_solves, status=status, message=sol.message,
            model=data + res))
    return InstrumentFit(values=values, errors=errors, optics=fitted_optics, frames=results,
                         names=jm.space.names, covariance=cov, chi2_red=float(chi2_red),
                         n_pixels=n, n_eval=n_eval, status=status, message=sol.message,
                         time_s=time_s, trials=trials, edge_phase_rad=edge,
                         edge_phase_error_rad=edge_error)


def _edge_phase(optics: Optics, free_shared: Sequence[str], cov: NDArray[np.float64]
                ) -> tuple[float, float]:
    """``Phi(th_max)`` of the fitted pupil and its error from the shared covariance."""
    if optics.numerical_aperture is None:
        return math.nan, math.nan
    na = float(optics.numerical_aperture)
    n_medium = optics.n_medium

    def edge(na_: float, ab: Aberration) -> float:
        theta = float(np.arcsin(min(na_ / n_medium, 1.0)))
        return float(ab.phase(np.array([theta]))[0])

    ab = optics.aberration
    value = edge(na, ab)
    grad = np.zeros(len(free_shared))
    theta = float(np.arcsin(min(na / n_medium, 1.0)))
    basis = spherical_basis(np.array([theta]), max(len(ab.spherical), 1))[:, 0]
    for i, name in enumerate(free_shared):
        if name in SPHERICAL_NAMES:
            grad[i] = basis[SPHERICAL_NAMES.index(name)]
        elif name == APERTURE.name and na < n_medium:
            h = 1e-6
            grad[i] = (edge(na + h, ab) - edge(na - h, ab)) / (2 * h)
    k = len(free_shared)
    var = float(grad @ cov[:k, :k] @ grad) if np.all(np.isfinite(cov[:k, :k])) else math.nan
    return value, (math.sqrt(var) if var >= 0 else math.nan)


def _scan_fraction(frames: list[Frame]) -> float:
    """Pixels of the step-2 subsets over all pixels: the scan's misfit is on the subsets."""
    sub = sum(f.subset.size for f in frames)
    return sub / max(sum(f.pix.size for f in frames), 1)
