"""Truncation order: where to start, and the measured change that says when to stop.

The order starts at ``L_0 = ceil(kR + 4 (kR)^(1/3) + 2)`` (Wiscombe's rule for the
circumscribing sphere, where a sphere's series has converged to about 1e-8) and grows in steps
of :data:`ORDER_STEP`; the estimate of the truncation error at order ``L`` is the change of the
far field between the T-matrices of orders ``L - ORDER_STEP`` and ``L``
(:func:`far_field_change`), on fixed probe waves and directions. For spectrally converging
builds (spheroids, layered spheres) that change overestimates the error at ``L`` by orders of
magnitude; for algebraically converging ones (edges, curvature jumps) it is about the error at
``L`` itself, so it is what the provenance records in both cases.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from holofit.scattering.tmatrix import TMatrix

__all__ = ["ORDER_STEP", "far_field_change", "probe_change", "probe_far_fields", "start_order"]

#: orders added per refinement
ORDER_STEP = 4
#: zyz Euler angles (rad) of the probe plane waves (lab: along -z, polarised along x)
PROBE_EULERS: tuple[tuple[float, float, float], ...] = (
    (0.5, 0.0, 0.0), (0.5, np.pi / 4, 0.3), (0.5, 1.4, 0.0), (1.0, 2.5, 0.0))


def start_order(k: float, radius_um: float) -> int:
    """``ceil(kR + 4 (kR)^(1/3) + 2)`` (at least 4)."""
    x = k * radius_um
    return max(4, int(np.ceil(x + 4.0 * x ** (1.0 / 3.0) + 2.0)))


@lru_cache(maxsize=4)
def _probe_directions(count: int = 96) -> NDArray[np.float64]:
    rng = np.random.default_rng(20260)
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d.setflags(write=False)
    return d


def probe_far_fields(tm: TMatrix) -> NDArray[np.complex128]:
    """Far-field amplitudes ``A`` (probe, direction, 3) of the probe waves."""
    dirs = _probe_directions()
    out = []
    for e in PROBE_EULERS:
        c = tm.lab_coefficients(e, np.array([1.0, 0.0, 0.0]))
        out.append(tm.expansion(c.vector).far_amplitude(dirs))
    return np.array(out)


def probe_change(fa: NDArray, fb: NDArray) -> float:
    """``max |A_a - A_b| / max |A_b|`` of two :func:`probe_far_fields`."""
    return float(np.abs(fa - fb).max() / np.abs(fb).max())


def far_field_change(a: TMatrix, b: TMatrix) -> float:
    """``max |A_a - A_b| / max |A_b|`` over the probes (:func:`probe_far_fields`)."""
    return probe_change(probe_far_fields(a), probe_far_fields(b))
