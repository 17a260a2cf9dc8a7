"""How to analyse a trajectory: :class:`AnalysisConfig`, checked like a configuration file.

Numeric settings are held to the rules of :mod:`holofit.config_schema` (the configuration files'
validation library), so a temperature given in kelvin or a radius given in nanometres is
refused with the same advice wherever it comes from: a keyword argument, or a ``holofit
analyze`` option (the command line names the option, see :class:`SettingError`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from holofit.analysis.recipes import RECIPES, recipe_for
from holofit.config_schema import SIZE_RANGE_UM, Spec, celsius_hint, nm_hint, number_problem

__all__ = ["SETTING_SPECS", "AnalysisConfig", "SettingError"]

#: the rule of every numeric setting (checked when it is not None)
SETTING_SPECS: dict[str, Spec] = {
    # the water viscosity formula (holofit.analysis.hydrodynamics) holds for liquid water
    "temperature_c": Spec("float", "the sample temperature in C", 0.0, 100.0,
                          hint=celsius_hint),
    "temperature_err_c": Spec("float", "the temperature uncertainty in C", 0.0, 50.0),
    "a_um": Spec("float", "a (radius or cap radius) in um", *SIZE_RANGE_UM, hint=nm_hint),
    "b_um": Spec("float", "b (half tip-to-tip length) in um", *SIZE_RANGE_UM, hint=nm_hint),
    "a_err_um": Spec("float", "the uncertainty of a in um", 0.0, SIZE_RANGE_UM[1],
                     hint=nm_hint),
    "b_err_um": Spec("float", "the uncertainty of b in um", 0.0, SIZE_RANGE_UM[1],
                     hint=nm_hint),
    "eps_r_est": Spec("float", "the angular noise per frame in rad", 0.0, math.pi),
    "max_lag": Spec("int", "the longest lag in frames", 1, None),
}


class SettingError(ValueError):
    """An analysis setting is out of range or inconsistent.

    Attributes
    ----------
    setting : str
        The field of :class:`AnalysisConfig`.
    problem : str
        What is wrong with it (without the field's name, so that a caller can name the
        setting its own way, e.g. as a command-line option).
    """

    def __init__(self, setting: str, problem: str) -> None:
        super().__init__(f"analysis setting '{setting}': {problem}")
        self.setting = setting
        self.problem = problem


@dataclass
class AnalysisConfig:
    """How to analyse a trajectory.

    Parameters
    ----------
    model : {"rod", "janus", "sphere"}
        ``rod`` for any head-tail symmetric particle (rods, dimers); ``janus`` for particles with
        a distinguishable cap (only x, y and the azimuth psi are used, as in the paper); ``sphere``
        for translation only (:mod:`holofit.analysis.recipes`).
    temperature_c, temperature_err_c : float
        Sample temperature and its uncertainty, C.
    a_um, b_um : float, optional
        Sizes for the predictions (cap/sphere radius, half length), um; default: medians of the
        table's static parameters.
    a_err_um, b_err_um : float, optional
        Their uncertainties; default: the standard error of the table's per-frame values (zero
        when the fit held the sizes fixed).
    head_tail : bool, optional
        Correct head-tail flips (default: the model's, True for rods).
    reject : bool, optional
        Reject improbable angular jumps (default: the model's, True for rods, False for Janus
        particles, whose analysis uses psi only, which a mirrored polar angle does not change).
    reject_probability : float
        Tail-probability threshold of the rejection.
    d_est : float, optional
        Rotational diffusion coefficient for the rejection, 1/s (default: estimated).
    eps_r_est : float, optional
        Angular noise per frame for the rejection, rad (default: estimated; 0 reproduces the
        paper's rule exactly).
    sensitivity_factors : tuple of float
        Factors applied to ``D_est`` for the sensitivity report.
    subtract_drift : bool
        Remove a constant drift velocity (the end-to-end one; the translational MSD models then
        carry the Brownian bridge's factor ``1 - tau / T``, so this costs no bias).
    fit_lags_translation, fit_lags_rotation : tuple of int, optional
        Inclusive fit ranges in frames. Defaults: lags 1..p with ``p = 2 + 2.5 sqrt(x)``
        (3 <= p <= 20; a rod's translation 2 <= p, with ``eps^2`` less twice its error, the
        noise where resolved) for translation and for the rod's orientation MSD, ``x`` being
        the reduced localisation error ``eps^2 / (D dt)`` from a preliminary fit of lags 1-10
        (the orientation MSD also stops before ``<|du|^2>`` reaches 0.5); for the Janus
        projection correlation, up to the lag where ``<p . p'>`` falls to 0.5.
    max_lag : int, optional
        Longest lag computed for the plots (default: a quarter of the trajectory).
    drop_ambiguous : bool, optional
        Treat frames the DDA fit flagged ``ambiguous`` (the runner-up orientation fits as well,
        within the noise) as gaps (default: True for rods, False otherwise).
    projection_amplitude : bool
        Fit an amplitude ``A`` in front of the projection series (absorbs angular noise).
    body_frame : bool
        Fit a rod's MSDs along and across its axis together with their exact means for the
        measured axis path and the drift removal (:mod:`holofit.analysis.body_frame`); False:
        two separate lines ``2 D_par tau (1 - tau/T)`` and ``4 D_perp tau (1 - tau/T)``, which
        are biased when an anisotropic rod turns within the fit range (kept for comparison).
    check_consistency : bool
        Test the track's hydrodynamic size against its optical size and its motion against
        Brownian motion (:mod:`holofit.analysis.consistency`); a track that fails is flagged
        and left out of pooled results.
    consistency_alpha : float
        Probability that a Brownian track of the fitted size is flagged (split over the
        tests), default 0.01.
    theory_tolerance : float, optional
        Relative uncertainty of the hydrodynamic theory in the size test (default: the
        model's, 5 % for spheres and Janus particles, 10 % for rods).

    Raises
    ------
    SettingError
        A value out of range (:data:`SETTING_SPECS`, with advice for a unit slip), an unknown
        model, or an empty fit range.
    """

    model: str
    temperature_c: float = 21.0
    temperature_err_c: float = 2.0
    a_um: float | None = None
    b_um: float | None = None
    a_err_um: float | None = None
    b_err_um: float | None = None
    head_tail: bool | None = None
    reject: bool | None = None
    reject_probability: float = 1e-4
    d_est: float | None = None
    eps_r_est: float | None = None
    sensitivity_factors: tuple[float, ...] = (2 / 3, 4 / 3)
    subtract_drift: bool = True
    fit_lags_translation: tuple[int, int] | None = None
    fit_lags_rotation: tuple[int, int] | None = None
    max_lag: int | None = None
    projection_amplitude: bool = True
    drop_ambiguous: bool | None = None
    body_frame: bool = True
    check_consistency: bool = True
    consistency_alpha: float = 0.01
    theory_tolerance: float | None = None

    def __post_init__(self) -> None:
        if self.model not in RECIPES:
            raise SettingError("model", f"expected one of {', '.join(RECIPES)}, got {self.model!r}")
        recipe = recipe_for(self.model)
        if self.head_tail is None:
            self.head_tail = recipe.head_tail
        if self.reject is None:
            self.reject = recipe.reject
        if self.drop_ambiguous is None:
            self.drop_ambiguous = recipe.drop_ambiguous
        if not recipe.orientation:
            self.head_tail, self.reject = False, False
        for name, spec in SETTING_SPECS.items():
            value = getattr(self, name)
            if value is not None and (problem := number_problem(value, spec)):
                raise SettingError(name, problem)
        if not 0 < self.consistency_alpha < 1:
            raise SettingError(
                "consistency_alpha", f"expected a value in (0, 1), got {self.consistency_alpha}")
        if self.theory_tolerance is not None and not 0 <= self.theory_tolerance < 1:
            raise SettingError(
                "theory_tolerance", f"expected a fraction in [0, 1), got {self.theory_tolerance}")
        if not 0 < self.reject_probability < 1:
            raise SettingError(
                "reject_probability", f"expected a value in (0, 1), got {self.reject_probability}"
            )
        if self.d_est is not None and not self.d_est > 0:
            raise SettingError("d_est", f"expected a value > 0 (1/s), got {self.d_est}")
        for name in ("fit_lags_translation", "fit_lags_rotation"):
            rng = getattr(self, name)
            if rng is not None:
                lo, hi = int(rng[0]), int(rng[1])
                if lo < 1 or hi < lo:
                    raise SettingError(name, f"expected 1 <= first <= last frames, got {rng}")
                setattr(self, name, (lo, hi))
