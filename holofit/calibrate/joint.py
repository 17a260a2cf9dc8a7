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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import SPHERICAL_NAMES, Aberration, spherical_basis
from holofit.cache import LRUCache
from holofit.holomodel.aperture import SCAN_LOWEST, SCAN_STEP, aperture_minima, aperture_start
from holofit.holomodel.forward import HologramModel, InvalidParameters
from holofit.holomodel.leastsq import Solution, solve_least_squares
from holofit.holomodel.parameters import APERTURE, ParameterSpace, State
from holofit.holomodel.pixels import PixelSelection, select_pixels
from holofit.holomodel.result import APERTURE_CHI2, FitResult, aperture_spread
from holofit.holomodel.statistics import covariance_from_jacobian, estimate_noise_sd
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.sphere import EXACT_STEPS, SPHERE_COLUMNS, SphereFitSettings, fit_sphere_crop
from holofit.scattering.mie import LorenzMie
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

#: names of the shared parameters in the joint vector start with this (and a frame's with
#: ``frame<j>.``), so that the one least-squares entry point treats the NA as any parameter
#: (its own NA steps are this module's, over all frames)
INSTRUMENT_PREFIX = "instrument."
#: the polarisation angle from lab x, rad (a shared parameter)
POLARIZATION = "polarization_rad"
#: its finite-difference step, rad (a new solve of every frame's sphere per column)
POLARIZATION_STEP = 1e-4
#: start values of ``(sa4_rad, sa6_rad)`` tried besides the instrument's own, rad: the
#: 4th-order term up to a few waves at the pupil's edge, the 6th-order term of either sign
#: (the layer model of :func:`holofit.aberration.layer_aberration` for a coverslip 10 um off
#: or an oil objective 10 um into water lies inside)
DEFAULT_ABERRATION_STARTS: tuple[tuple[float, float], ...] = tuple(
    (a, b) for a in (-10.0, 0.0, 10.0) for b in (-30.0, 0.0, 30.0))


@dataclass(frozen=True)
class SphereFrame:
    """One normalised sphere hologram of a calibration.

    Attributes
    ----------
    crop : ndarray, shape (rows, cols)
        Background-normalised hologram; NaN marks pixels to leave out.
    corner_rc : tuple of int
        Full-frame ``(row, column)`` of the crop's pixel ``[0, 0]``.
    centre_xy_um : tuple of float
        Full-frame ``(x, y)`` of the hologram's centre from the crop stage, um (the prefit's
        start).
    noise_sd : float, optional
        Pixel noise (normalised units); estimated from the crop if not given.
    start : mapping, optional
        The sphere's start (``x_um, y_um, z_um, radius_um, n, alpha``, e.g. a prefit table
        row); None: the automatic prefit of step 1.
    """

    crop: NDArray
    corner_rc: tuple[int, int]
    centre_xy_um: tuple[float, float]
    noise_sd: float | None = None
    start: Mapping[str, float] | None = None


@dataclass(frozen=True)
class JointFitSettings:
    """What a joint instrument fit varies and how hard it looks.

    Attributes
    ----------
    fit_na : bool
        Fit the objective's numerical aperture (the instrument's is the start).
    aberration : tuple of str
        Spherical-aberration coefficients fitted (``sa4_rad``, ``sa6_rad``, ...; the others
        held at the instrument's); empty: none.
    fit_polarization : bool
        Fit the polarisation angle (the instrument's is the start).
    aberration_starts : tuple of tuple of float, optional
        Starts of the fitted coefficients tried in step 2 (each padded with the instrument's
        values); default :data:`DEFAULT_ABERRATION_STARTS`, the instrument's own always first.
    screen_pixels : int
        Pixels per frame (a seeded random subset) in step 2.
    pixel_fraction : float
        Fit a seeded random subset with this fraction of each frame's unmasked pixels (1: all;
        large crops of many frames are fitted faster, at a cost in precision only).
    fix_alpha : float, optional
        Hold every frame's alpha at this value; fitted by default.
    index_imag : float
        Imaginary part of the spheres' index, held (>= 0).
    max_nfev : int
        Most residual evaluations of each least-squares run.
    ftol, xtol : float
        Their convergence tolerances.
    prefit : SphereFitSettings
        Settings of step 1's per-frame prefits.
    seed : int
        Seed of the pixel subsets.
    """

    fit_na: bool = True
    aberration: tuple[str, ...] = ("sa4_rad", "sa6_rad")
    fit_polarization: bool = False
    aberration_starts: tuple[tuple[float, ...], ...] | None = None
    screen_pixels: int = 3000
    pixel_fraction: float = 1.0
    fix_alpha: float | None = None
    index_imag: float = 0.0
    max_nfev: int = 100
    ftol: float = 1e-8
    xtol: float = 1e-8
    prefit: SphereFitSettings = field(default_factory=SphereFitSettings)
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "aberration", tuple(self.aberration))
        unknown = [n for n in self.aberration if n not in SPHERICAL_NAMES]
        if unknown:
            raise ValueError(f"unknown aberration coefficient(s) {', '.join(unknown)}; known: "
                             f"{', '.join(SPHERICAL_NAMES)}")
        if not (self.fit_na or self.aberration or self.fit_polarization):
            raise ValueError("a joint instrument fit needs a shared parameter: fit_na, "
                             "aberration or fit_polarization")
        if self.screen_pixels < 100 or self.max_nfev < 1:
            raise ValueError("screen_pixels must be >= 100 and max_nfev >= 1")
        if not 0 < self.pixel_fraction <= 1:
            raise ValueError(f"pixel_fraction must be in (0, 1], got {self.pixel_fraction}")


@dataclass
class InstrumentFit:
    """The instrument fitted to several sphere holograms.

    Attributes
    ----------
    values, errors : dict
        The fitted instrument quantities (``numerical_aperture``, ``sa4_rad``, ...,
        ``polarization_rad``) and their 1-sigma errors.
    optics : Optics
        The start instrument's optics with the fitted values (what later fits use).
    frames : list of FitResult
        Per frame, its sphere (``x_um, y_um, z_um, radius_um, n, alpha``) with errors from the
        joint covariance (the instrument's uncertainty included), and its own goodness of fit
        (``chi2``: mean squared residual per pixel; ``chi2_red`` against its pixel noise).
    names : tuple of str
        The joint vector's components (``instrument.<name>``, ``frame<j>.<name>``).
    covariance : ndarray
        Their covariance.
    chi2_red : float
        Weighted residual sum of squares over its degrees of freedom (about 1 for a model that
        explains every frame down to its noise).
    n_pixels, n_eval : int
        Pixels of all frames; holograms computed.
    status, message : str
        ``ok`` or ``not_converged``, and the optimiser's message.
    time_s : float
        Wall time.
    trials : list of dict
        Each step-2 start and step-3 NA tried, with its weighted misfit (diagnostics).
    edge_phase_rad, edge_phase_error_rad : float
        The fitted pupil phase at the aperture's edge, ``Phi(th_max)``, and its 1-sigma error
        (the coefficients' and the NA's covariance propagated): over a small pupil the
        coefficients are strongly anticorrelated (``x^2`` and ``x^3`` look alike when ``x``
        stays small) while the phase they make is well fixed, so this is the number to
        compare between calibrations.
    """

    values: dict[str, float]
    errors: dict[str, float]
    optics: Optics
    frames: list[FitResult]
    names: tuple[str, ...]
    covariance: NDArray[np.float64]
    chi2_red: float
    n_pixels: int
    n_eval: int
    status: str
    message: str
    time_s: float = 0.0
    trials: list[dict] = field(default_factory=list)
    edge_phase_rad: float = math.nan
    edge_phase_error_rad: float = math.nan


@dataclass
class _Frame:
    """A frame's pixels, noise and current sphere."""

    pix: PixelSelection
    noise_sd: float
    sphere: dict[str, float]
    subset: NDArray[np.intp]


class _Names:
    """The ``space`` a least-squares run asks a model for: its vector's names."""

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = names


class _JointModel:
    """The frames' forward models stacked (module docstring), with the interface of
    :class:`~holofit.holomodel.forward.HologramModel` that
    :func:`~holofit.holomodel.leastsq.solve_least_squares` uses: ``space.names``,
    ``hologram``, ``jacobian`` and ``n_holograms``."""

    def __init__(self, frames: Sequence[_Frame], optics: Optics, shared: Mapping[str, float],
                 free_shared: Sequence[str], frame_names: Sequence[str],
                 settings: JointFitSettings, subset: bool = False) -> None:
        self.frames = list(frames)
        self.optics = optics
        self.shared = dict(shared)
        self.free_shared = tuple(free_shared)
        self.frame_names = tuple(frame_names)
        self.settings = settings
        self.subset = subset
        names = [INSTRUMENT_PREFIX + n for n in self.free_shared]
        for j in range(len(self.frames)):
            names += [f"frame{j}.{n}" for n in self.frame_names]
        self.space = _Names(tuple(names))
        self._models: dict[float, list[HologramModel]] = {}
        self._extra = 0
        rows = [f.subset.size if subset else f.pix.size for f in self.frames]
        self._rows = np.cumsum([0, *rows])
        self.weights = [1.0 / f.noise_sd for f in self.frames]
        model_free = [n for n in self.free_shared if n != POLARIZATION] + list(self.frame_names)
        self._frame_free = tuple(model_free)
        index = {n: i for i, n in enumerate(self.space.names)}
        self._index: list[NDArray[np.intp]] = []
        for j in range(len(self.frames)):
            space = self._space(j)
            self._index.append(np.array(
                [index[INSTRUMENT_PREFIX + n] if n in self.free_shared else index[f"frame{j}.{n}"]
                 for n in space.names], dtype=np.intp))

    # -- the frames' models ------------------------------------------------------------
    def _space(self, j: int, shared: Mapping[str, float] | None = None) -> ParameterSpace:
        s = self.shared if shared is None else shared
        sphere = self.frames[j].sphere
        st = self.settings
        alpha = sphere["alpha"] if st.fix_alpha is None else st.fix_alpha
        model = Sphere(sphere["radius_um"], complex(sphere["n"], st.index_imag))
        aberration = Aberration.from_values(s, self.optics.aberration)
        state = State((sphere["x_um"], sphere["y_um"], sphere["z_um"]), None, alpha,
                      (("radius_um", sphere["radius_um"]), ("n", sphere["n"])),
                      s.get(APERTURE.name), aberration)
        return ParameterSpace(model, self._frame_free, state, step_overrides=EXACT_STEPS)

    def _models_for(self, beta: float) -> list[HologramModel]:
        models = self._models.get(beta)
        if models is None:
            optics = replace(self.optics, polarization_rad=beta)
            models = []
            for j, f in enumerate(self.frames):
                xs, ys = ((f.pix.xs_um[f.subset], f.pix.ys_um[f.subset]) if self.subset
                          else (f.pix.xs_um, f.pix.ys_um))
                models.append(HologramModel(LorenzMie(), self._space(j), optics, xs, ys,
                                            waves=LRUCache(4)))
            while len(self._models) >= 3:
                self._extra += sum(m.n_holograms for m in self._models.pop(next(iter(
                    self._models))))
            self._models[beta] = models
        return models

    def _beta(self, v: NDArray) -> float:
        if POLARIZATION in self.free_shared:
            return float(v[self.space.names.index(INSTRUMENT_PREFIX + POLARIZATION)])
        return float(self.shared.get(POLARIZATION, self.optics.polarization_rad))

    @property
    def n_holograms(self) -> int:
        return self._extra + sum(m.n_holograms for ms in self._models.values() for m in ms)

    @n_holograms.setter
    def n_holograms(self, value: int) -> None:
        self._extra += int(value) - self.n_holograms

    # -- data, holograms, Jacobian ------------------------------------------------------
    def data(self) -> NDArray[np.float64]:
        """Every frame's data, weighted, in the model's row order."""
        return np.concatenate([
            (f.pix.data[f.subset] if self.subset else f.pix.data) * w
            for f, w in zip(self.frames, self.weights, strict=True)])

    def hologram(self, vector: NDArray) -> NDArray[np.float64]:
        v = np.asarray(vector, dtype=float)
        models = self._models_for(self._beta(v))
        return np.concatenate([m.hologram(v[idx]) * w for m, idx, w in
                               zip(models, self._index, self.weights, strict=True)])

    def jacobian(self, vector: NDArray) -> NDArray[np.float64]:
        v = np.asarray(vector, dtype=float)
        models = self._models_for(self._beta(v))
        jac = np.zeros((int(self._rows[-1]), v.size))
        for j, (m, idx, w) in enumerate(zip(models, self._index, self.weights, strict=True)):
            jac[self._rows[j]:self._rows[j + 1], idx] = m.jacobian(v[idx]) * w
        if POLARIZATION in self.free_shared:
            i = self.space.names.index(INSTRUMENT_PREFIX + POLARIZATION)
            q = v.copy()
            q[i] += POLARIZATION_STEP
            jac[:, i] = (self.hologram(q) - self.hologram(v)) / POLARIZATION_STEP
        return jac

    # -- vectors <-> values -------------------------------------------------------------
    def vector(self) -> NDArray[np.float64]:
        """The model's vector at its shared values and the frames' spheres."""
        out = [self.shared[n] for n in self.free_shared]
        for f in self.frames:
            out += [f.sphere[n] for n in self.frame_names]
        return np.array(out, dtype=float)

    def values(self, vector: NDArray) -> tuple[dict[str, float], list[dict[str, float]]]:
        """The shared values and the frames' spheres at ``vector``."""
        v = np.asarray(vector, dtype=float)
        shared = dict(self.shared)
        for i, n in enumerate(self.free_shared):
            shared[n] = float(v[i])
        spheres = []
        k = len(self.free_shared)
        for f in self.frames:
            s = dict(f.sphere)
            for n in self.frame_names:
                s[n] = float(v[k])
                k += 1
            spheres.append(s)
        return shared, spheres


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


def calibrate_instrument(frames: Sequence[SphereFrame], optics: Optics, pixel_size_um: float,
                   settings: JointFitSettings | None = None) -> InstrumentFit:
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
    frame_names = tuple(n for n in SPHERE_COLUMNS
                        if not (n == "alpha" and st.fix_alpha is not None))
    rng = np.random.default_rng(st.seed)
    prepared: list[_Frame] = []
    for j, fr in enumerate(frames):
        pix = select_pixels(np.asarray(fr.crop, dtype=float), fr.corner_rc, pixel_size_um,
                            fraction=st.pixel_fraction, rng=rng, min_pixels=100)
        noise = fr.noise_sd if fr.noise_sd is not None else estimate_noise_sd(
            np.asarray(fr.crop, dtype=float), pix.valid)
        if not noise > 0:
            raise ValueError(f"frame {j}: no pixel noise estimate (give noise_sd)")
        m = min(st.screen_pixels, pix.size)
        subset = np.sort(rng.choice(pix.size, size=m, replace=False))
        prepared.append(_Frame(pix, float(noise),
                               _prefit_start(fr, base, pixel_size_um, st, j), subset))
    shared: dict[str, float] = {APERTURE.name: (aperture_start(optics) if st.fit_na
                                                else float(optics.numerical_aperture)),
                                POLARIZATION: float(optics.polarization_rad),
                                **start_ab.values()}
    free_all = ([APERTURE.name] if st.fit_na else []) + list(st.aberration) + (
        [POLARIZATION] if st.fit_polarization else [])
    trials: list[dict] = []
    n_eval = 0

    def run(free: Sequence[str], subset: bool, values: Mapping[str, float],
            max_nfev: int | None = None) -> tuple[_JointModel, Solution]:
        nonlocal n_eval
        jm = _JointModel(prepared, base, values, free, frame_names, st, subset)
        sol = solve_least_squares(jm, jm.data(), jm.vector(),
                                  max_nfev=max_nfev or st.max_nfev,
                                  ftol=1e-6 if subset else st.ftol,
                                  xtol=1e-6 if subset else st.xtol)
        n_eval += sol.n_eval
        return jm, sol

    def adopt(jm: _JointModel, sol: Solution) -> dict[str, float]:
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
        spheres0 = [dict(f.sphere) for f in prepared]
        best: tuple[float, dict, list] | None = None
        free = [n for n in free_all if n != APERTURE.name]
        for c in starts:
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
            jm, sol = run(held, False, shared)
            shared = adopt(jm, sol)
        grid, rss = _scan_aperture(prepared, base, shared, frame_names, st)
        scan = (grid, rss)
        na_starts = aperture_minima(grid, rss) or [shared[APERTURE.name]]
        spheres0 = [dict(f.sphere) for f in prepared]
        best_run: tuple[_JointModel, Solution] | None = None
        for na in na_starts:
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
        jm, sol = run(free_all, False, shared)
    shared = adopt(jm, sol)
    return _result(jm, sol, prepared, base, shared, scan, trials, n_eval,
                   time.perf_counter() - t0)


def _scan_aperture(frames: list[_Frame], optics: Optics, shared: Mapping[str, float],
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
        jm = _JointModel(frames, optics, {**shared, APERTURE.name: float(na)}, (), frame_names,
                         settings, subset=True)
        try:
            r = jm.hologram(jm.vector()) - jm.data()
        except InvalidParameters:
            continue
        rss[i] = float(r @ r)
    return grid, rss


def _result(jm: _JointModel, sol: Solution, frames: list[_Frame], optics: Optics,
            shared: Mapping[str, float], scan: tuple[NDArray, NDArray] | None,
            trials: list[dict], n_eval: int, time_s: float) -> InstrumentFit:
    n = int(sol.residuals.size)
    p = int(sol.vector.size)
    cov = covariance_from_jacobian(sol.jacobian, sol.rss, n)
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
        aberration=Aberration.from_values(shared, optics.aberration))
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


def _scan_fraction(frames: list[_Frame]) -> float:
    """Pixels of the step-2 subsets over all pixels: the scan's misfit is on the subsets."""
    sub = sum(f.subset.size for f in frames)
    return sub / max(sum(f.pix.size for f in frames), 1)
