"""What a joint instrument fit is given and what it finds (:mod:`holofit.calibrate.joint`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import SPHERICAL_NAMES
from holofit.holomodel.result import FitResult
from holofit.optics import Optics
from holofit.prefit.sphere import SphereFitSettings

__all__ = ["DEFAULT_ABERRATION_STARTS", "FIXABLE", "INSTRUMENT_PREFIX", "POLARIZATION",
           "POLARIZATION_STEP", "InstrumentFit", "JointFitSettings", "SphereFrame"]

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
#: the sphere parameters a calibration may hold at a stated material's value or give a prior
FIXABLE = ("radius_um", "n")


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
    fix_radius_um, fix_index : float, optional
        Hold every sphere's radius (um) or real index at this value (a stated material of
        known size or index); free by default.
    priors : tuple of (str, (float, float))
        Gaussian priors ``(name, (value, sd))`` on each frame's ``radius_um`` (um) or ``n``:
        one residual row ``(p - value) / sd`` per frame, for a material known to ``sd``.
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
    fix_radius_um: float | None = None
    fix_index: float | None = None
    priors: tuple[tuple[str, tuple[float, float]], ...] = ()

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
        priors = tuple((str(n), (float(v), float(sd))) for n, (v, sd) in self.priors)
        object.__setattr__(self, "priors", priors)
        fixed = self.fixed_values()
        for name, value in fixed.items():
            if not value > 0:
                raise ValueError(f"a fixed {name} must be positive, got {value}")
        for name, (value, sd) in priors:
            if name not in FIXABLE:
                raise ValueError(f"a prior on {name!r}: only on {', '.join(FIXABLE)}")
            if name in fixed:
                raise ValueError(f"{name} is both fixed and given a prior")
            if not (sd > 0 and math.isfinite(sd) and math.isfinite(value)):
                raise ValueError(f"the prior on {name} needs a finite value and sd > 0, got "
                                 f"{value} +- {sd}")

    def fixed_values(self) -> dict[str, float]:
        """The sphere parameters held at a stated value (``radius_um``, ``n``)."""
        out = {}
        if self.fix_radius_um is not None:
            out["radius_um"] = float(self.fix_radius_um)
        if self.fix_index is not None:
            out["n"] = float(self.fix_index)
        return out


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


