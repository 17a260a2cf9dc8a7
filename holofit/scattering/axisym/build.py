"""The exact T-matrix of a body of revolution: method, order and quadrature chosen, provenance
recorded.

Method by particle (the measured reasons are in ``docs/validation/exact_tmatrix.md``):

* homogeneous spheroids, flat-ended cylinders and spherocylinders: the extended boundary
  condition method (:mod:`holofit.scattering.axisym.ebcm`), the fastest and, for smooth
  bodies, spectrally convergent in the order; it solves at a searched order ``L`` and keeps
  the T-matrix at the start order ``L_0`` (the sub-blocks of orders ``n, l <= L_0``: the orders
  past ``L_0`` change those elements, while the far field itself needs no more than ``L_0``);
* layered spheres and Janus particles (uniform or tapered caps): invariant imbedding
  (:mod:`holofit.scattering.axisym.iitm`), which handles inhomogeneous bodies and is exact
  for concentric layers up to the radial integration; for caps the polar field is multiplied
  by ``eps`` with the inverse rule (the cap's rim plane is a cone ``theta = pi / 2``);
* a homogeneous sphere: Lorenz-Mie.

The order starts at :func:`holofit.scattering.axisym.order.start_order` and grows until the far
field changes by less than ``tolerance`` between orders ``L - 4`` and ``L``
(:func:`~holofit.scattering.axisym.order.far_field_change`), or the change stops falling
(:data:`STALL_ORDERS` orders without a new smallest change: double precision's floor, where
the EBCM's surface integrals cancel by more digits than the change still has; the order of
the smallest change is kept), or a cap is reached (the equilibrated ``Q`` beyond
:data:`EBCM_MAX_CONDITION`; :data:`MAX_ORDER_EXTRA` orders past the start; or the time budget
``max_seconds``, counted in the process's CPU time so that the order reached does not depend
on the machine's load); the imbedding's steps of the kept build double until Richardson's estimate
of their error is below :data:`IITM_STEP_SHARE` of its truncation estimate, or a tenth of
``tolerance`` if larger (concentric layers, whose coefficients are exact but for the radial
integration: a hundredth of ``tolerance``; with the order given: a tenth; at most three
times).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

import holofit
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.axisym.blocks import tmatrix_from_blocks
from holofit.scattering.axisym.ebcm import EBCMSystem, ebcm_solve, ebcm_system
from holofit.scattering.axisym.iitm import integrate_profile, mie_start
from holofit.scattering.axisym.order import (
    ORDER_STEP,
    far_field_change,
    probe_change,
    probe_far_fields,
    start_order,
)
from holofit.scattering.axisym.profiles import (
    CapProfile,
    LayeredProfile,
    Profile,
    profile_of,
    supports_model,
)
from holofit.scattering.legendre import legendre_tables
from holofit.scattering.tmatrix import TMatrix

__all__ = [
    "DEFAULT_TOLERANCE",
    "build_exact_tmatrix",
    "build_profile_tmatrix",
    "choose_method",
    "model_description",
    "supports",
]

#: default target of the far-field change between orders L - 4 and L
DEFAULT_TOLERANCE = 1e-5
#: the EBCM's order is not raised once the condition number of the equilibrated ``Q`` of any
#: ``m`` exceeds this (double precision keeps about 16 - log10(cond) digits of the solve)
EBCM_MAX_CONDITION = 1e10
#: orders past the start beyond which the order is not raised
MAX_ORDER_EXTRA = 36
#: the search stops once this many successive orders have not lowered the smallest
#: order-to-order change so far, and keeps the order of the smallest: past a precision floor
#: (the EBCM's cancellation in its surface integrals) the change grows again, and the
#: EBCM's changes, kept at the start order, fall steadily below it (measured on the rod and
#: the cylinder: ``docs/validation/exact-studies.md``)
STALL_ORDERS = 1
#: a change counts as a new smallest only if it is below the smallest so far by more than this
#: share: at double precision's floor the rounding of the EBCM's surface integrals moves the
#: change by several per cent from one way of summing them to another, so a change that
#: falls by less is noise, not convergence
STALL_MARGIN = 0.05
#: the EBCM's ``Q`` and ``RgQ`` are computed this many orders past the order tried, so that
#: the next steps of the search are solves of their sub-blocks
EBCM_AHEAD = 12
#: default budget of the order search, s of the process's CPU time (on an idle machine, with
#: one thread, its wall time): no higher order is tried that would end past it (predicted
#: from the last build's time and its growth with the order)
DEFAULT_MAX_SECONDS = 2.0
#: the radial steps of the imbedding's kept build are refined until Richardson's change (of
#: the T-matrix's elements) is below this share of its truncation estimate: finer steps would
#: not change the stated accuracy (the extrapolated T-matrix is closer still)
IITM_STEP_SHARE = 0.05
#: the file format :func:`holofit.dda.tmatrix_io.load_tmatrix` reads
FILE_FORMAT = "holofit-tmatrix/1"


def supports(model: ParticleModel) -> bool:
    """True if :func:`build_exact_tmatrix` builds ``model``'s T-matrix."""
    return supports_model(model)


def choose_method(profile: Profile) -> str:
    """``"mie"``, ``"ebcm"`` or ``"iitm"`` for a profile (module docstring)."""
    if isinstance(profile, LayeredProfile) and len(profile.radii) == 1:
        return "mie"
    if profile.homogeneous:
        return "ebcm"
    return "iitm"


def _ebcm_nodes(order: int) -> int:
    """Gauss-Legendre nodes per surface piece: ``2 L + 10`` (the integrands' angular degree is
    about ``2 L``; measured: a spheroid's T changes by < 1e-12 from 2L + 10 to 4L nodes, and
    ``3 L / 2 + 10`` leaves it 5e-5 off at order 24)."""
    return 2 * order + 10


def _iitm_steps(profile: Profile, k: float, n_medium: float, order: int) -> list[int]:
    """Starting Runge-Kutta steps per segment: four per unit of the segment's optical
    thickness in the densest material plus the growth ``2L / r`` of the highest order, at least
    eight (measured on the 47 nm TiO2 cap at order 16: 28 steps with Richardson's
    extrapolation leave the far field 1.3e-6 from a converged integration; the check in
    :func:`_iitm_build` doubles them where the step target needs more)."""
    br = profile.breaks()
    n_max = max(abs(complex(v)) for v in _indices(profile)) / n_medium
    out = []
    for a, b in itertools.pairwise(br):
        rate = k * n_max + 2.0 * order / a
        out.append(max(8, int(np.ceil(4.0 * rate * (b - a)))))
    return out


def _indices(profile: Profile) -> list[complex]:
    if isinstance(profile, LayeredProfile):
        return list(profile.indices)
    if isinstance(profile, CapProfile):
        return [profile.index_core, profile.index_cap]
    return [complex(profile.index)]


def _iitm_build(profile: Profile, order: int, k: float, n_medium: float, step_tolerance: float,
                steps: Sequence[int] | None = None, richardson: bool = True
                ) -> tuple[NDArray, dict[str, Any]]:
    """IITM blocks at ``order``; steps doubled until Richardson's change is below
    ``step_tolerance`` (at most three times), unless ``steps`` fixes them (one per segment;
    ignored where the profile has another number of segments); ``richardson`` False: plain
    RK4 at the fixed steps."""
    polar = "inverse" if isinstance(profile, CapProfile) and not profile.tapered else "laurent"
    if steps is not None and len(steps) != len(profile.breaks()) - 1:
        steps = None
    counts = list(steps) if steps is not None else _iitm_steps(profile, k, n_medium, order)
    for _ in range(4):
        res = integrate_profile(profile, order, k, n_medium, counts,
                                richardson=richardson or steps is None, polar_rule=polar)
        if res.richardson_change <= step_tolerance or steps is not None:
            break
        counts = [2 * c for c in counts]
    info = {"radial_steps": res.steps, "richardson_change": res.richardson_change,
            "riccati_evaluations": res.evaluations, "polar_rule": polar,
            "radial_rule": "laurent",
            "integrator": ("RK4 + Richardson (h, 2h)" if richardson or steps is None
                           else "RK4"),
            "segments_um": profile.breaks()}
    return res.blocks, info


class _EBCMBuilder:
    """The EBCM's builds of one profile at solve orders ``L`` kept at ``out_order``: ``Q``
    and ``RgQ`` computed once at a higher order, every lower order a solve of their
    sub-blocks (:func:`~holofit.scattering.axisym.ebcm.ebcm_solve`). The first system is
    :data:`EBCM_AHEAD` orders past the first order asked (where a smooth body converges); a
    body that needs more gets one at ``top``, the highest order the search may try.
    ``condition``: also the condition numbers of ``Q``, which only the search reads."""

    def __init__(self, profile: Profile, k: float, n_medium: float, out_order: int | None,
                 top: int, condition: bool = True) -> None:
        self.profile, self.k, self.n_medium = profile, k, n_medium
        self.out_order, self.top = out_order, top
        self.condition = condition
        self.system: EBCMSystem | None = None
        self.system_seconds = 0.0

    def _next_system_order(self, L: int) -> int:
        return max(L, min(L + EBCM_AHEAD, self.top)) if self.system is None else max(L,
                                                                                     self.top)

    def __call__(self, L: int) -> tuple[NDArray, int, dict[str, Any]]:
        if self.system is None or self.system.order < L:
            order = self._next_system_order(L)
            legendre_tables(np.array([0.5]), 2)  # loads the compiled code outside the timing
            t0 = time.process_time()
            self.system = ebcm_system(self.profile, order, self.k, self.n_medium,
                                      _ebcm_nodes(order), max_m=self.out_order)
            self.system_seconds = time.process_time() - t0
        out = L if self.out_order is None else min(L, self.out_order)
        blocks, cond = ebcm_solve(self.system, L, out, self.condition)
        info = {"solve_order": L, "quadrature_nodes_per_piece": _ebcm_nodes(self.system.order),
                "quadrature_order": self.system.order,
                "surface_pieces": len(self.profile.surface_kinks()) + 1,
                "q_condition_max": float(cond.max()) if self.condition else None}
        return blocks, out, info

    def next_seconds(self, L_next: int, last_seconds: float) -> float:
        """Predicted time of the build at ``L_next``, s (a solve, or a new system: with ``m``
        kept to the start order its cost grows about as the order's cube)."""
        if self.system is not None and L_next <= self.system.order:
            return last_seconds
        order = self.system.order if self.system is not None else L_next
        return self.system_seconds * (self._next_system_order(L_next) / max(order, 1)) ** 3


def build_profile_tmatrix(profile: Profile, k: float, n_medium: float,
                          tolerance: float = DEFAULT_TOLERANCE, order: int | None = None,
                          method: str | None = None,
                          max_seconds: float = DEFAULT_MAX_SECONDS, *,
                          radial_steps: Sequence[int] | None = None, estimate: bool = True,
                          max_order: int | None = None, richardson: bool = True,
                          solve_order: int | None = None, condition: bool = True) -> TMatrix:
    """The T-matrix of a profile (see :func:`build_exact_tmatrix`)."""
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    method = method or choose_method(profile)
    radius = float(profile.r_outer)
    L0 = start_order(k, radius)
    # the EBCM solves at a searched order and keeps the T-matrix at the start order (or the
    # given one): its orders past L0 change the low orders' elements, not the far field's need
    out_order = (int(order) if order is not None else L0) if method == "ebcm" else None
    if order is not None:
        top = int(solve_order) if solve_order is not None else int(order)
    else:
        top = L0 + MAX_ORDER_EXTRA if max_order is None else max(int(max_order), L0)
    # the condition number steers the order search, which always computes it
    ebcm = _EBCMBuilder(profile, k, n_medium, out_order, top,
                        condition=condition or order is None)
    # the imbedding's radial steps: with the order given, Richardson's change below a tenth
    # of the tolerance; in the search, the start steps (enough to measure the change between
    # orders), the kept build's refined below IITM_STEP_SHARE of its truncation estimate
    step_target = [0.1 * tolerance if order is not None else math.inf]

    def build(L: int) -> tuple[TMatrix, dict[str, Any]]:
        out = L
        if method == "mie":
            blocks = mie_start(L, k, profile.r_start, complex(profile.index_start) / n_medium)
            info: dict[str, Any] = {}
        elif method == "ebcm":
            blocks, out, info = ebcm(L)
        elif method == "iitm":
            blocks, info = _iitm_build(profile, L, k, n_medium, step_target[0], radial_steps,
                                       richardson)
        else:
            raise ValueError(f"unknown method {method!r} (mie, ebcm, iitm)")
        return tmatrix_from_blocks(blocks, out, k, radius), info

    history: list[tuple[int, float]] = []
    stop = "order given"
    if order is not None:
        L = int(solve_order) if method == "ebcm" and solve_order is not None else int(order)
        tm, info = build(L)
        change = math.nan
        if estimate:
            lower, _ = build(max(1, L - ORDER_STEP))
            change = far_field_change(lower, tm)
        else:
            stop = "order given, not estimated"
        history.append((L, change))
    else:
        prev_probe = probe_far_fields(build(max(1, L0 - ORDER_STEP))[0])
        best: tuple[float, TMatrix, dict[str, Any]] | None = None
        stalled = 0
        L = L0
        while True:
            t_build = time.process_time()
            cand, cand_info = build(L)
            t_build = time.process_time() - t_build
            if (method == "ebcm" and cand_info["q_condition_max"] > EBCM_MAX_CONDITION
                    and best is not None):
                stop = "EBCM conditioning"
                break
            probe = probe_far_fields(cand)
            change = probe_change(prev_probe, probe)
            history.append((L, change))
            if best is None or change < (1.0 - STALL_MARGIN) * best[0]:
                best, stalled = (change, cand, cand_info), 0
            else:
                stalled += 1
            if change <= tolerance or method == "mie":
                stop = "tolerance met"
                break
            if stalled >= STALL_ORDERS:
                stop = "precision floor"
                break
            if method == "ebcm" and cand_info["q_condition_max"] > EBCM_MAX_CONDITION:
                stop = "EBCM conditioning"
                break
            if L >= L0 + MAX_ORDER_EXTRA or (max_order is not None
                                              and L + ORDER_STEP > max_order):
                stop = "order cap"
                break
            predicted = (ebcm.next_seconds(L + ORDER_STEP, t_build) if method == "ebcm"
                         else t_build * ((L + ORDER_STEP) / L) ** 4)
            if time.process_time() - cpu0 + predicted > max_seconds:
                stop = "time budget"
                break
            prev_probe = probe
            L += ORDER_STEP
        assert best is not None
        change, tm, info = best
        # concentric layers: each kept coefficient is exact but for the radial integration,
        # whose steps go to a hundredth of the tolerance; else to a share of the truncation
        target = (0.01 * tolerance if isinstance(profile, LayeredProfile)
                  else max(0.1 * tolerance, IITM_STEP_SHARE * change))
        if method == "iitm" and radial_steps is None and info["richardson_change"] > target:
            step_target[0] = target
            tm, info = build(tm.order)
    seconds = time.perf_counter() - t0
    cpu_seconds = time.process_time() - cpu0
    tm.provenance.update({
        "format": FILE_FORMAT, "engine": "exact", "method": method, "order": tm.order,
        "truncation_estimate": float(change), "tolerance": float(tolerance),
        "tolerance_met": bool(change <= tolerance), "order_history": history,
        "order_search_stop": stop,
        "k_per_um": float(k), "n_medium": float(n_medium), "radius_um": radius,
        "storage": "modulus 2L+1: one block per m", "build_seconds": seconds,
        "build_cpu_seconds": cpu_seconds,
        "holofit_version": holofit.__version__, **info,
    })
    return tm


def model_description(model: ParticleModel) -> dict[str, Any]:
    """The model as a T-matrix's provenance records it (``kind`` and its parameters, a
    complex index as ``[re, im]``)."""
    params = {}
    for name, value in model.parameters().items():
        v = complex(value) if isinstance(value, complex) else value
        params[name] = [v.real, v.imag] if isinstance(v, complex) else v
    return {"kind": model.kind, "parameters": params}


def build_exact_tmatrix(model: ParticleModel, optics: Optics,
                        tolerance: float = DEFAULT_TOLERANCE, order: int | None = None,
                        method: str | None = None,
                        max_seconds: float = DEFAULT_MAX_SECONDS, *,
                        radial_steps: Sequence[int] | None = None, estimate: bool = True,
                        max_order: int | None = None, richardson: bool = True,
                        solve_order: int | None = None, condition: bool = True) -> TMatrix:
    """The exact T-matrix of a body of revolution, in the particle frame.

    Same basis, normalisation and storage interface as the DDA-built one
    (:class:`holofit.scattering.tmatrix.TMatrix`; modulus ``2L + 1``, one block per ``m``), so
    every orientation, derivative and camera-plane evaluation reuses it unchanged.

    Parameters
    ----------
    model : ParticleModel
        A :func:`supports`-ed model (spherocylinder, spheroid, cylinder, sphere, coated sphere,
        Janus sphere, :class:`~holofit.scattering.axisym.profiles.TaperedJanusSphere`).
    optics : Optics
        Wavelength and medium (the polarisation does not enter).
    tolerance : float
        Target of the far-field change between orders ``L - 4`` and ``L`` (relative to the
        largest amplitude); recorded with ``tolerance_met`` when a cap stops the search first.
    order : int, optional
        A fixed order instead of the search.
    method : {"mie", "ebcm", "iitm"}, optional
        Override the choice of :func:`choose_method`.
    max_seconds : float
        CPU time of this process after which the order is no longer raised, s (load
        independent; with one thread, the wall time of an idle machine).
    radial_steps : sequence of int, optional
        The imbedding's Runge-Kutta steps per radial segment instead of its own rule (no
        doubling): a fit's builds keep one discretisation, so that the T-matrix moves
        smoothly with the sizes.
    estimate : bool
        With ``order``: also build at ``order - 4`` for the truncation estimate (False: not
        estimated, ``truncation_estimate`` NaN; a fit's rebuilds rely on the reference
        build's).
    max_order : int, optional
        The search raises the order no further than this (a cap that, unlike
        ``max_seconds``, does not depend on the machine's load).
    richardson : bool
        With ``radial_steps``: Richardson's extrapolation of the steps h and 2h (False: plain
        RK4, a third of the work, for steps fine enough on their own).
    solve_order : int, optional
        With ``order``, for the EBCM: solve at this order (at least ``order``) and keep the
        T-matrix at ``order`` (a fit's builds at its reference build's orders).
    condition : bool
        With ``order``, for the EBCM: record the condition number of the equilibrated ``Q``
        (``q_condition_max``; False: None, with no SVD per ``m``, as a fit's rebuilds
        use it). The order search always computes it.

    Raises
    ------
    TypeError
        For a model that is not a supported body of revolution.
    """
    profile = profile_of(model)
    tm = build_profile_tmatrix(profile, optics.k, optics.n_medium, tolerance, order, method,
                               max_seconds, radial_steps=radial_steps, estimate=estimate,
                               max_order=max_order, richardson=richardson,
                               solve_order=solve_order, condition=condition)
    tm.provenance.update({"model": model_description(model),
                          "wavelength_um": float(optics.wavelength_um)})
    return tm



