"""One discretisation for every build of a fit: the reference build and what it fixes.

A fit moves the sizes and indices (the initial pass's finite differences, steps of 2 nm and
1e-3); every new value is a new T-matrix. The order search of
:func:`~holofit.scattering.axisym.build.build_exact_tmatrix` picks the order, and the
imbedding its radial steps, from the model itself, in integer steps: left free they would jump
between two neighbouring sizes and the finite differences would see the jump instead of the
derivative. So a fit fixes them once, at a **reference build** of its start model
(:func:`reference_build`), and builds every other model of the fit at that order and with
those steps (:class:`Discretisation`); the quadrature of the EBCM (``2L + 10`` nodes per
surface piece) follows from the order. The reference build's truncation estimate is the
stated accuracy of them all (the models of a fit differ by a few per cent in size).

The reference build is the order search without its wall-clock budget, so that it does not
depend on the machine's load (a resumed run gets the rows of an uninterrupted one): the EBCM's
solve order stops where the tolerance is met, where the change stops falling, or
:data:`EBCM_EXTRA_ORDERS` past the start (the T-matrix is kept at the start order); the
imbedding's order (Janus spheres, layered spheres) rises at most :data:`IITM_EXTRA_ORDERS` past
its start ``L_0``: a cap's convergence in the order is algebraic (its rim), and at fewer orders
the engine's own truncation biases a side-on cap's fitted thickness and index by more than
their error bars, while each order step costs about 1.4 times a build and a fit makes tens of
builds per frame (the measurements: ``docs/validation/exact-studies.md``). The imbedding's
order being capped, its tolerance only sets its radial steps (to a tenth of it):
:data:`IITM_TOLERANCE`, far below the truncation error of a cap, where the default 1e-5 would
double the steps (and the build's time) for nothing. The fit's builds of an imbedding then drop
Richardson's extrapolation and take the fewest steps that keep plain RK4 within
:data:`STEP_SHARE` of the truncation estimate of the reference (measured against it: the radial
integration is then no longer the accuracy's limit, at a third to a sixth of the work): RK4's
error falls as the fourth power of the steps, so the change at the reference's steps predicts
the steps that give :data:`STEP_AIM` of that bar, and a build checks them (half way back where
it fails); the reference model itself is rebuilt that way too, so that every build of the fit
shares one discretisation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from holofit.cache import LRUCache
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.axisym.build import DEFAULT_TOLERANCE, build_exact_tmatrix, choose_method
from holofit.scattering.axisym.order import far_field_change, start_order
from holofit.scattering.axisym.profiles import profile_of
from holofit.scattering.tmatrix import TMatrix

__all__ = ["EBCM_EXTRA_ORDERS", "IITM_EXTRA_ORDERS", "IITM_TOLERANCE", "MIN_STEPS",
           "STEP_AIM", "STEP_SHARE", "STEP_TRIALS", "Discretisation",
           "reference_build", "remember_reference"]

#: orders past the start ``L_0`` that the reference build of an imbedding may raise (the
#: paper's Janus particle: ``L = 36``)
IITM_EXTRA_ORDERS = 20
#: orders past the start ``L_0`` that the reference build of the EBCM may solve at (it keeps
#: ``L_0``): a rebuild's cost grows about as the solve order's cube, and a fit makes tens of
#: builds per frame (the measurements: ``docs/validation/exact_tmatrix.md``)
EBCM_EXTRA_ORDERS = 12
#: the reference build's tolerance for the imbedding (whose order is capped): its radial steps
#: are refined until Richardson's change is below a tenth of it
IITM_TOLERANCE = 1e-4
#: a fit's imbedding steps: plain RK4, as few as keep its far-field change from the
#: reference below this share of the reference's truncation estimate
STEP_SHARE = 0.1
#: the fit's steps are predicted to give this fraction of the :data:`STEP_SHARE` bar (a margin
#: for the prediction), then checked against the bar itself
STEP_AIM = 0.5
#: most builds the choice of a fit's imbedding steps makes
STEP_TRIALS = 4
#: fewest Runge-Kutta steps per radial segment of a fit's build
MIN_STEPS = 8


@dataclass(frozen=True)
class Discretisation:
    """The order (and the imbedding's radial steps) every build of a fit uses.

    Attributes
    ----------
    order : int
        Truncation order ``L``.
    radial_steps : tuple of int, optional
        Runge-Kutta steps per radial segment (imbedding only; None for the EBCM and Mie).
    method : str
        ``"ebcm"``, ``"iitm"`` or ``"mie"``.
    truncation_estimate : float
        The reference build's far-field change between orders ``L - 4`` and ``L``, relative
        to the largest amplitude: the stated accuracy of every build at this discretisation.
    tolerance : float
        The tolerance the reference build's order search aimed at.
    stop : str
        Why the reference build's search stopped (``order_search_stop``).
    richardson : bool
        The imbedding's Richardson extrapolation (False: plain RK4 at ``radial_steps``).
    step_error : float
        Far-field change of these radial steps from the reference build's (0 where they are
        the reference's own).
    solve_order : int, optional
        The EBCM's solve order (``order`` is the order it keeps; None: the same).
    """

    order: int
    radial_steps: tuple[int, ...] | None = None
    method: str = ""
    truncation_estimate: float = math.nan
    tolerance: float = DEFAULT_TOLERANCE
    stop: str = ""
    richardson: bool = True
    step_error: float = 0.0
    solve_order: int | None = None

    @classmethod
    def of(cls, tm: TMatrix) -> Discretisation:
        """The discretisation of a built exact T-matrix (from its provenance: the one it was
        built at, else its own order and steps)."""
        p = tm.provenance
        if isinstance(p.get("discretisation"), dict):
            d = dict(p["discretisation"])
            steps = d.get("radial_steps")
            return cls(int(d["order"]), None if steps is None else tuple(int(s) for s in steps),
                       str(d.get("method", "")), float(d.get("truncation_estimate", math.nan)),
                       float(d.get("tolerance", DEFAULT_TOLERANCE)),
                       str(d.get("order_search_stop", "")), bool(d.get("richardson", True)),
                       float(d.get("step_error", 0.0)),
                       None if d.get("solve_order") is None else int(d["solve_order"]))
        steps = p.get("radial_steps") if p.get("method") == "iitm" else None
        solve = p.get("solve_order") if p.get("method") == "ebcm" else None
        return cls(int(tm.order), None if steps is None else tuple(int(s) for s in steps),
                   str(p.get("method", "")), float(p.get("truncation_estimate", math.nan)),
                   float(p.get("tolerance", DEFAULT_TOLERANCE)),
                   str(p.get("order_search_stop", "")),
                   solve_order=None if solve is None else int(solve))

    def as_dict(self) -> dict[str, Any]:
        """JSON-able form (sidecars)."""
        return {"order": self.order, "radial_steps": None if self.radial_steps is None
                else list(self.radial_steps), "method": self.method,
                "truncation_estimate": self.truncation_estimate, "tolerance": self.tolerance,
                "order_search_stop": self.stop, "richardson": self.richardson,
                "step_error": self.step_error, "solve_order": self.solve_order}

    def build(self, model: ParticleModel, optics: Optics) -> TMatrix:
        """``model``'s T-matrix at this discretisation (no search, no estimate of its own:
        the provenance states the reference build's, ``truncation_estimate_of``)."""
        tm = build_exact_tmatrix(model, optics, self.tolerance, order=self.order,
                                 method=self.method or None, radial_steps=self.radial_steps,
                                 estimate=False, richardson=self.richardson,
                                 solve_order=self.solve_order, condition=False)
        tm.provenance.update({"truncation_estimate": self.truncation_estimate,
                              "truncation_estimate_of": "the fit's reference build",
                              "tolerance_met": bool(self.truncation_estimate
                                                    <= self.tolerance),
                              "radial_step_error": self.step_error,
                              "discretisation": self.as_dict()})
        return tm


def _cheaper_steps(model: ParticleModel, optics: Optics, ref: Discretisation,
                   ref_tm: TMatrix) -> Discretisation:
    """The imbedding's fit discretisation: plain RK4 at the fewest steps predicted to keep its
    far-field change from the reference within :data:`STEP_AIM` of :data:`STEP_SHARE` of the
    reference's truncation estimate, checked against that bar (module docstring)."""
    assert ref.radial_steps is not None
    bar = STEP_SHARE * ref.truncation_estimate
    best = ref
    steps = ref.radial_steps
    failed = tuple(0 for _ in steps)  # the fewest steps known to pass lie above these
    for _ in range(STEP_TRIALS):
        trial = replace(ref, radial_steps=steps, richardson=False)
        change = far_field_change(trial.build(model, optics), ref_tm)
        if change <= bar:
            best = replace(trial, step_error=change)
            # RK4's error falls as the fourth power of the steps
            factor = (change / (STEP_AIM * bar)) ** 0.25 if change > 0 else 0.0
            nxt = tuple(min(s, max(MIN_STEPS, f + 1, math.ceil(s * factor)))
                        for s, f in zip(steps, failed, strict=True))
        elif best is ref:
            return best
        else:  # half way back to the last steps that passed
            failed = steps
            assert best.radial_steps is not None
            nxt = tuple(math.ceil((s + b) / 2)
                        for s, b in zip(steps, best.radial_steps, strict=True))
            if nxt == best.radial_steps:
                return best
        if nxt == steps:
            return best
        steps = nxt
    return best


#: reference builds of this process, by (model, wavelength, medium, tolerance)
_REFERENCES: LRUCache[tuple, TMatrix] = LRUCache(16)


def _key(model: ParticleModel, optics: Optics, tolerance: float) -> tuple:
    return (model, float(optics.wavelength_um), float(optics.n_medium), float(tolerance))


def _reference(model: ParticleModel, optics: Optics, tolerance: float) -> TMatrix:
    method = choose_method(profile_of(model))
    cap = None
    if method == "iitm":
        cap = start_order(optics.k, profile_of(model).r_outer) + IITM_EXTRA_ORDERS
        tolerance = max(tolerance, IITM_TOLERANCE)
    elif method == "ebcm":
        cap = start_order(optics.k, profile_of(model).r_outer) + EBCM_EXTRA_ORDERS
    tm = build_exact_tmatrix(model, optics, tolerance, max_seconds=math.inf, max_order=cap)
    ref = Discretisation.of(tm)
    if method != "iitm" or ref.radial_steps is None:
        tm.provenance["discretisation"] = ref.as_dict()
        return tm
    fit = _cheaper_steps(model, optics, ref, tm)
    if fit == ref:
        tm.provenance["discretisation"] = ref.as_dict()
        return tm
    out = fit.build(model, optics)
    out.provenance.update({"order_history": tm.provenance.get("order_history"),
                           "order_search_stop": tm.provenance.get("order_search_stop"),
                           "reference_radial_steps": list(ref.radial_steps)})
    return out


def reference_build(model: ParticleModel, optics: Optics,
                    tolerance: float = DEFAULT_TOLERANCE) -> TMatrix:
    """The reference build of ``model`` at the fit's discretisation (module docstring; its
    provenance's ``discretisation``), kept per process so that the stages' workers search
    once per model (or not at all: :func:`remember_reference`)."""
    key = _key(model, optics, tolerance)
    tm = _REFERENCES.get(key)
    if tm is None:
        tm = _REFERENCES.put(key, _reference(model, optics, tolerance))
    return tm


def remember_reference(model: ParticleModel, optics: Optics, tolerance: float,
                       tm: TMatrix) -> bool:
    """Keep ``tm`` as ``model``'s reference build in this process (a worker reading the
    driver's, instead of searching again) if its provenance says it is one (True)."""
    if not isinstance(tm.provenance.get("discretisation"), dict):
        return False
    _REFERENCES.put(_key(model, optics, tolerance), tm)
    return True
