"""The fit stage's configuration (:class:`FitConfig`) and what a run wrote (:class:`FitRun`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from holofit.batch import BatchSummary
from holofit.batch.aperture import FROM_INSTRUMENT, ApertureChoice
from holofit.config import Instrument, ParticleConfig
from holofit.fit.continuity import ContinuityReport, ContinuitySettings
from holofit.fit.model_error import ModelErrorSettings
from holofit.fit.settings import FollowSettings, FrameFitSettings
from holofit.fit.static import STATIC_MODES
from holofit.fit.tmatrix_policy import TMATRIX_CHOICES

__all__ = ["PASSES", "FitConfig", "FitRun"]

#: which passes a run does
PASSES = ("initial", "final", "both")


@dataclass(frozen=True)
class FitConfig:
    """Everything the fit stage is told (what ``holofit fit`` sets).

    Attributes
    ----------
    particle : ParticleConfig
        The particle model and its ``[dda]`` settings: the run's primary model (the one the
        library ranks orientations of).
    alternatives : tuple of ParticleConfig
        The run's other models (spheres, coated spheres: no orientation); each track is
        given the model that fits its initial frames best (:mod:`holofit.fit.models`).
    model_test : bool
        A non-spherical primary model is also tested against a sphere of the prefit's size
        where no alternative is given (a sphere in a rod run is never reported as a rod).
    particles : tuple of int, optional
        Only these tracks (``--particle``).
    exclude_particles : tuple of int
        Not these tracks (``--exclude-particle``).
    passes : {"both", "initial", "final"}
        Which passes to run.
    initial_frames : int, optional
        Frames of each track's initial pass (spread over the movie where the particle has a
        T-matrix, else the first ones that can be fitted); default
        :func:`holofit.fit.defaults.default_initial_frames` of the track's fittable frames.
    static : Path, optional
        ``static.json`` for the final pass (default: ``OUT/static.json`` of the initial pass).
    static_mode : {"per-track", "pooled"}
        Static parameters per track, or pooled over the tracks (:mod:`holofit.fit.static`).
    frame : FrameFitSettings
        How frames are fitted.
    engine : str, optional
        The scattering engine (default: the particle config's).
    fixed : tuple of str
        Parameters held at their start values (the particle config's for static ones).
    tmatrix : {"auto", "always", "never"}
        Serve the final pass from the particle's T-matrix (:mod:`holofit.fit.tmatrix_policy`).
    follow : FollowSettings
        How a pass follows each track (:mod:`holofit.fit.follow`); ``warm=False``:
        independent frames (``--independent-frames``).
    continuity : ContinuitySettings
        The continuity sweeps after the final pass (default: on).
    model_error : ModelErrorSettings
        The final table's model-error estimate (:mod:`holofit.fit.model_error`; default: on
        for the discrete-dipole engines, the stated accuracy for the exact ones).
    frames : tuple of int, optional
        Only these frames (both passes, every track).
    instrument : Instrument, optional
        Instead of the crops' own (:func:`holofit.tables.cropset.resolve_instrument`).
    override_instrument : bool
        Accept an instrument that contradicts the crops'.
    numerical_aperture : ApertureChoice
        The objective's NA (:mod:`holofit.batch.aperture`).
    fit_na : bool
        Fit the NA in every frame of both passes, starting from the one chosen.
    outlier_factor : float
        ``ok`` rows above this many times their track's median reduced chi^2 become
        ``poor_fit`` (:func:`holofit.quality.flag_outliers`).
    plot : bool
        Draw the passes' plots and a few frames' pictures.
    plot_frames : tuple of int, optional
        The frames to draw (default: :func:`holofit.holomodel.pictures.choose_frames`).
    """

    particle: ParticleConfig
    alternatives: tuple[ParticleConfig, ...] = ()
    model_test: bool = True
    particles: tuple[int, ...] | None = None
    exclude_particles: tuple[int, ...] = ()
    passes: str = "both"
    initial_frames: int | None = None
    static: Path | None = None
    static_mode: str = "per-track"
    frame: FrameFitSettings = field(default_factory=FrameFitSettings)
    engine: str | None = None
    fixed: tuple[str, ...] = ()
    tmatrix: str = "auto"
    follow: FollowSettings = field(default_factory=FollowSettings)
    continuity: ContinuitySettings = field(default_factory=ContinuitySettings)
    model_error: ModelErrorSettings = field(default_factory=ModelErrorSettings)
    frames: tuple[int, ...] | None = None
    instrument: Instrument | None = None
    override_instrument: bool = False
    numerical_aperture: ApertureChoice = FROM_INSTRUMENT
    fit_na: bool = False
    outlier_factor: float = 4.0
    plot: bool = True
    plot_frames: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        if self.passes not in PASSES:
            raise ValueError(f"pass must be one of {', '.join(PASSES)}, got {self.passes!r}")
        if self.tmatrix not in TMATRIX_CHOICES:
            raise ValueError(f"tmatrix must be one of {', '.join(TMATRIX_CHOICES)}, got "
                             f"{self.tmatrix!r}")
        if self.initial_frames is not None and self.initial_frames < 1:
            raise ValueError(f"initial_frames must be >= 1, got {self.initial_frames}")
        if any(a.model.anisotropic for a in self.alternatives):
            odd = ", ".join(a.model.kind for a in self.alternatives if a.model.anisotropic)
            raise ValueError(f"alternative model(s) {odd}: a run's population holds one "
                             "non-spherical model, its first (the library ranks its "
                             "orientations); fit the others in a run of their own")
        if self.static_mode not in STATIC_MODES:
            raise ValueError(f"static mode {self.static_mode!r}: expected one of "
                             f"{', '.join(STATIC_MODES)}")


@dataclass
class FitRun:
    """What :func:`holofit.fit.stage.run_fit` wrote."""

    initial: Path | None = None
    static: Path | None = None
    final: Path | None = None
    summaries: dict[str, BatchSummary] = field(default_factory=dict)
    tmatrix: Path | None = None
    tmatrix_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    continuity: ContinuityReport | None = None
    continuity_by_track: dict[int, ContinuityReport] = field(default_factory=dict)
    tracks: Path | None = None
    left_out: dict[int, str] = field(default_factory=dict)
    model_error: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"initial": self.initial, "static": self.static, "final": self.final,
                "notes": self.notes, "model_error": self.model_error}
