"""What ``holofit calibrate`` is told (:class:`CalibrateConfig`) and what it did
(:class:`CalibrationRun`), for :func:`holofit.calibrate.stage.run_calibrate`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from holofit.aberration import MAX_SPHERICAL_TERMS, SPHERICAL_NAMES
from holofit.calibrate.settings import InstrumentFit, JointFitSettings, SphereFrame
from holofit.config import ConfigError, Instrument

__all__ = [
    "DEFAULT_MAX_FRAMES",
    "DEFAULT_MAX_PIXELS",
    "CalibrateConfig",
    "CalibrateError",
    "CalibrationRun",
    "FrameRecord",
]

#: the default number of frames fitted jointly: the NA's and the coefficients' errors fall as
#: 1/sqrt(frames) while the cost grows as the frames; 20 heights sample a 5-25 um range at 1 um
DEFAULT_MAX_FRAMES = 20
#: the default pixels fitted per frame (a seeded random subset of larger crops): the paper's
#: 140-pixel crops whole
DEFAULT_MAX_PIXELS = 20000


class CalibrateError(ConfigError):
    """Input the calibrate stage cannot use (no instrument NA, no usable sphere, a bad
    setting); a :class:`~holofit.config_schema.ConfigError`, so that the command line reports
    it in one line (:mod:`holofit.cli.errors`)."""


@dataclass(frozen=True)
class CalibrateConfig:
    """What ``holofit calibrate`` fits, on which frames.

    Attributes
    ----------
    max_frames : int
        Most frames fitted jointly, chosen spread over the heights
        (:func:`holofit.calibrate.stage.choose_frames`).
    frames : tuple of int, optional
        Choose among these frame numbers only (``--frames``); default all.
    fit_na : bool
        Fit the numerical aperture (the start: :attr:`numerical_aperture` or the prefit's).
    aberration_terms : int
        Spherical-aberration coefficients fitted (``sa4_rad``, ``sa6_rad``, ...; 0: none, the
        instrument's held).
    fit_polarization : bool
        Fit the polarisation angle too.
    numerical_aperture : float, optional
        Start NA (default: the instrument's the prefit used).
    instrument : Instrument, optional
        Start instrument (default: the one the prefit used, else the crops').
    index, radius_um : float, optional
        The stated material's real index and radius (um): held at these values, or with
        :attr:`index_sd` / :attr:`radius_sd_um` a Gaussian prior on every frame's; default
        free.
    index_sd, radius_sd_um : float, optional
        The priors' standard deviations (um for the radius).
    fix_alpha : float, optional
        Hold every frame's alpha (default fitted).
    max_pixels : int
        Pixels fitted per frame (a seeded random subset of a larger crop).
    aberration_starts : tuple of tuple of float, optional
        Coefficient starts of the joint fit's screening step (default: its grid).
    max_nfev : int
        Most evaluations of each least-squares run.
    seed : int
        Seed of the pixel subsets.
    plot : bool
        Write ``calibration.png``.
    """

    max_frames: int = DEFAULT_MAX_FRAMES
    frames: tuple[int, ...] | None = None
    fit_na: bool = True
    aberration_terms: int = 2
    fit_polarization: bool = False
    numerical_aperture: float | None = None
    instrument: Instrument | None = None
    index: float | None = None
    index_sd: float | None = None
    radius_um: float | None = None
    radius_sd_um: float | None = None
    fix_alpha: float | None = None
    max_pixels: int = DEFAULT_MAX_PIXELS
    aberration_starts: tuple[tuple[float, ...], ...] | None = None
    max_nfev: int = 100
    seed: int = 0
    plot: bool = True

    def __post_init__(self) -> None:
        if self.max_frames < 1:
            raise CalibrateError(f"max_frames (--max-frames) must be >= 1, got "
                                 f"{self.max_frames}")
        if not 0 <= self.aberration_terms <= MAX_SPHERICAL_TERMS:
            raise CalibrateError(f"aberration_terms (--aberration-terms) must be 0 to "
                                 f"{MAX_SPHERICAL_TERMS}, got {self.aberration_terms}")
        if self.max_pixels < 100:
            raise CalibrateError(f"max_pixels (--max-pixels) must be >= 100, got "
                                 f"{self.max_pixels}")
        for name, value, sd in (("index", self.index, self.index_sd),
                                ("radius", self.radius_um, self.radius_sd_um)):
            if sd is not None and value is None:
                raise CalibrateError(f"--{name}-sd needs --{name} (the prior's value)")

    def joint_settings(self, pixel_fraction: float, index_imag: float = 0.0
                       ) -> JointFitSettings:
        """The joint fit's settings for crops of which ``pixel_fraction`` is fitted.

        Raises
        ------
        CalibrateError
            Nothing to fit, or a bad stated value.
        """
        priors = []
        fixed: dict[str, float] = {}
        for name, value, sd in (("n", self.index, self.index_sd),
                                ("radius_um", self.radius_um, self.radius_sd_um)):
            if value is None:
                continue
            if sd is None:
                fixed[name] = value
            else:
                priors.append((name, (value, sd)))
        try:
            return JointFitSettings(
                fit_na=self.fit_na, aberration=SPHERICAL_NAMES[:self.aberration_terms],
                fit_polarization=self.fit_polarization, aberration_starts=self.aberration_starts,
                pixel_fraction=pixel_fraction, fix_alpha=self.fix_alpha, index_imag=index_imag,
                max_nfev=self.max_nfev, seed=self.seed, fix_index=fixed.get("n"),
                fix_radius_um=fixed.get("radius_um"), priors=tuple(priors))
        except ValueError as exc:
            raise CalibrateError(f"calibrate settings (--no-fit-na / --aberration-terms / "
                                 f"--fit-polarization / --index / --radius): {exc}") from None

    def as_dict(self) -> dict[str, Any]:
        """Plain form for the sidecar."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "instrument"}
        out["instrument"] = None if self.instrument is None else self.instrument.as_dict()
        return out


@dataclass
class FrameRecord:
    """One chosen frame: its key, crop, prefit row and chi^2 per pixel before and after.

    ``message`` is empty for a frame of the joint fit; a frame that could not be used (too few
    valid pixels, no noise estimate, no hologram for its prefit's values) keeps the reason
    there, is left out of the fit and is written to ``calibration.csv`` as ``failed``."""

    key: tuple[int, int]
    frame: SphereFrame
    before: dict[str, float]
    chi2_before: float
    n_pixels: int
    chi2_after: float = math.nan
    message: str = ""

    @property
    def ok(self) -> bool:
        """The frame is in the joint fit."""
        return not self.message


@dataclass
class CalibrationRun:
    """What :func:`run_calibrate` did and wrote.

    Attributes
    ----------
    instrument_toml, table : Path
        ``OUT/instrument.toml`` and ``OUT/calibration.csv``.
    plot : Path or None
        ``OUT/calibration.png``.
    instrument : Instrument
        The calibrated instrument (as the TOML reads back).
    start : Instrument
        The instrument the fit started from (and the "before" fits used).
    fit : InstrumentFit
        The joint fit.
    keys : list of tuple
        The ``(particle, frame)`` of the frames fitted, by height (the chosen frames that
        failed are in ``failed``).
    chi2_before, chi2_after : float
        Mean chi^2 per pixel (mean squared residual, normalised intensity^2) of those frames,
        each on all its unmasked pixels.
    notes : list of str
        What the user should know (frames left out, too few heights).
    time_s : float
        Wall time.
    failed : dict
        ``(particle, frame) -> reason`` of the chosen frames that could not be used (rows
        ``failed`` in ``calibration.csv``); the others were fitted.
    """

    instrument_toml: Path
    table: Path
    plot: Path | None
    instrument: Instrument
    start: Instrument
    fit: InstrumentFit
    keys: list[tuple[int, int]]
    chi2_before: float
    chi2_after: float
    notes: list[str] = field(default_factory=list)
    time_s: float = 0.0
    failed: dict[tuple[int, int], str] = field(default_factory=dict)
