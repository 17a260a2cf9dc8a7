"""The exact T-matrix of a body of revolution: method, order and quadrature chosen, provenance
recorded.

Method by particle (the measured reasons are in ``docs/validation/exact_tmatrix.md``):

* homogeneous spheroids, flat-ended cylinders and spherocylinders: the extended boundary
  condition method (:mod:`holofit.scattering.axisym.ebcm`), the fastest and, for smooth
  bodies, spectrally convergent in the order; its order is capped where ``Q`` becomes too
  ill-conditioned for double precision (:data:`EBCM_MAX_CONDITION`);
* layered spheres and Janus particles (uniform or tapered caps): invariant imbedding
  (:mod:`holofit.scattering.axisym.iitm`), which handles inhomogeneous bodies and is exact
  for concentric layers up to the radial integration; for caps the polar field is multiplied
  by ``eps`` with the inverse rule (the cap's rim plane is a cone ``theta = pi / 2``);
* a homogeneous sphere: Lorenz-Mie.

The order starts at :func:`holofit.scattering.axisym.order.start_order` and grows until the far
field changes by less than ``tolerance`` between orders ``L - 4`` and ``L``
(:func:`~holofit.scattering.axisym.order.far_field_change`), or a cap is reached (the EBCM's
conditioning: the last order whose ``Q`` is within :data:`EBCM_MAX_CONDITION` is kept;
:data:`MAX_ORDER_EXTRA` orders past the start; or the time budget ``max_seconds``); the
imbedding's steps double until Richardson's estimate of their error is below a tenth of
``tolerance`` (at most three times).
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
from holofit.scattering.axisym.ebcm import ebcm_blocks
from holofit.scattering.axisym.iitm import integrate_profile, mie_start
from holofit.scattering.axisym.order import ORDER_STEP, far_field_change, start_order
from holofit.scattering.axisym.profiles import (
    CapProfile,
    LayeredProfile,
    Profile,
    profile_of,
    supports_model,
)
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
#: the EBCM's order is not raised once cond(Q) of any m exceeds this (double precision keeps
#: about 16 - log10(cond) digits of T)
EBCM_MAX_CONDITION = 1e9
#: orders past the start beyond which the order is not raised
MAX_ORDER_EXTRA = 16
#: default wall-clock budget of the order search, s: no higher order is tried that would end
#: past it (predicted from the last build's time and its ~L^4 growth)
DEFAULT_MAX_SECONDS = 2.0
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
    about ``2 L``; measured: a spheroid's T changes by < 1e-12 from 2L + 10 to 4L nodes)."""
    return 2 * order + 10


def _iitm_steps(profile: Profile, k: float, n_medium: float, order: int) -> list[int]:
    """Starting Runge-Kutta steps per segment: twelve per unit of the segment's optical
    thickness in the densest material plus the growth ``2L / r`` of the highest order, at least
    eight (measured on the 47 nm TiO2 cap: Richardson's change ~1e-6 at order 16-20; the
    check in :func:`_iitm_build` doubles them where a resonance needs more)."""
    br = profile.breaks()
    n_max = max(abs(complex(v)) for v in _indices(profile)) / n_medium
    out = []
    for a, b in itertools.pairwise(br):
        rate = k * n_max + 2.0 * order / a
        out.append(max(8, int(np.ceil(12.0 * rate * (b - a)))))
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


def build_profile_tmatrix(profile: Profile, k: float, n_medium: float,
                          tolerance: float = DEFAULT_TOLERANCE, order: int | None = None,
                          method: str | None = None,
                          max_seconds: float = DEFAULT_MAX_SECONDS, *,
                          radial_steps: Sequence[int] | None = None, estimate: bool = True,
                          max_order: int | None = None, richardson: bool = True) -> TMatrix:
    """The T-matrix of a profile (see :func:`build_exact_tmatrix`)."""
    t0 = time.perf_counter()
    method = method or choose_method(profile)
    radius = float(profile.r_outer)

    def build(L: int) -> tuple[TMatrix, dict[str, Any]]:
        if method == "mie":
            blocks = mie_start(L, k, profile.r_start, complex(profile.index_start) / n_medium)
            info: dict[str, Any] = {}
        elif method == "ebcm":
            nodes = _ebcm_nodes(L)
            blocks, cond = ebcm_blocks(profile, L, k, n_medium, nodes)
            info = {"quadrature_nodes_per_piece": nodes,
                    "surface_pieces": len(profile.surface_kinks()) + 1,
                    "q_condition_max": float(cond.max())}
        elif method == "iitm":
            blocks, info = _iitm_build(profile, L, k, n_medium, 0.1 * tolerance, radial_steps,
                                       richardson)
        else:
            raise ValueError(f"unknown method {method!r} (mie, ebcm, iitm)")
        return tmatrix_from_blocks(blocks, L, k, radius), info

    history: list[tuple[int, float]] = []
    stop = "order given"
    if order is not None:
        tm, info = build(int(order))
        change = math.nan
        if estimate:
            lower, _ = build(max(1, int(order) - ORDER_STEP))
            change = far_field_change(lower, tm)
        else:
            stop = "order given, not estimated"
        history.append((int(order), change))
    else:
        L0 = start_order(k, radius)
        prev, prev_info = build(max(1, L0 - ORDER_STEP))
        tm, info, change = prev, prev_info, float("inf")
        L = L0
        while True:
            t_build = time.perf_counter()
            cand, cand_info = build(L)
            t_build = time.perf_counter() - t_build
            if (method == "ebcm" and cand_info["q_condition_max"] > EBCM_MAX_CONDITION
                    and history):
                stop = "EBCM conditioning"
                break
            change = far_field_change(prev, cand)
            tm, info = cand, cand_info
            history.append((L, change))
            if change <= tolerance or method == "mie":
                stop = "tolerance met"
                break
            if method == "ebcm" and cand_info["q_condition_max"] > EBCM_MAX_CONDITION:
                stop = "EBCM conditioning"
                break
            predicted = t_build * ((L + ORDER_STEP) / L) ** 4
            if L >= L0 + MAX_ORDER_EXTRA or (max_order is not None
                                              and L + ORDER_STEP > max_order):
                stop = "order cap"
                break
            if time.perf_counter() - t0 + predicted > max_seconds:
                stop = "time budget"
                break
            prev = cand
            L += ORDER_STEP
    seconds = time.perf_counter() - t0
    tm.provenance.update({
        "format": FILE_FORMAT, "engine": "exact", "method": method, "order": tm.order,
        "truncation_estimate": float(change), "tolerance": float(tolerance),
        "tolerance_met": bool(change <= tolerance), "order_history": history,
        "order_search_stop": stop,
        "k_per_um": float(k), "n_medium": float(n_medium), "radius_um": radius,
        "storage": "modulus 2L+1: one block per m", "build_seconds": seconds,
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
                        max_order: int | None = None, richardson: bool = True) -> TMatrix:
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
        Time after which the order is no longer raised, s.
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

    Raises
    ------
    TypeError
        For a model that is not a supported body of revolution.
    """
    profile = profile_of(model)
    tm = build_profile_tmatrix(profile, optics.k, optics.n_medium, tolerance, order, method,
                               max_seconds, radial_steps=radial_steps, estimate=estimate,
                               max_order=max_order, richardson=richardson)
    tm.provenance.update({"model": model_description(model),
                          "wavelength_um": float(optics.wavelength_um)})
    return tm



