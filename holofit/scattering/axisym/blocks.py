"""From per-``m`` blocks to holofit's :class:`~holofit.scattering.tmatrix.TMatrix`.

A body of revolution about particle z couples ``m`` only to ``m' = m``; stored with modulus
``M = 2L + 1`` the residue classes ``m mod M`` are exactly the single orders ``m = -L..L``, so
:class:`TMatrix` keeps one dense block per ``m`` (its rows ``N``-type ``n = max(1,|m|)..L``, then
``M``-type) and every method of it (Wigner rotations, derivatives, files) works unchanged.

The blocks of ``-m`` follow from those of ``m`` by the body's mirror symmetry in the plane
``y = 0``: that reflection maps ``N_nm`` to ``(-1)^m N_n,-m`` and ``M_nm`` to
``-(-1)^m M_n,-m``, so ``T_NN`` and ``T_MM`` are equal for ``+-m`` and ``T_NM``, ``T_MN`` change
sign.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.scattering.tmatrix import TMatrix

__all__ = ["negative_m_block", "tmatrix_from_blocks", "unpad_block"]


def unpad_block(padded: NDArray, m: int, order: int) -> NDArray[np.complex128]:
    """The ``2 N``-square block of ``m >= 0`` (``N = L - max(1, m) + 1``) from its padded
    ``2L``-square form (rows ``i`` and ``L + i`` for ``n = max(1, m) + i``)."""
    L = order
    cnt = L - max(1, m) + 1
    sel = np.concatenate([np.arange(cnt), L + np.arange(cnt)])
    return np.ascontiguousarray(padded[np.ix_(sel, sel)])


def negative_m_block(block: NDArray) -> NDArray[np.complex128]:
    """The block of ``-m`` from that of ``m`` (module docstring)."""
    half = block.shape[0] // 2
    out = block.copy()
    out[:half, half:] *= -1.0
    out[half:, :half] *= -1.0
    return out


def tmatrix_from_blocks(padded: NDArray, order: int, k: float, radius_um: float,
                        provenance: dict[str, Any] | None = None) -> TMatrix:
    """A :class:`TMatrix` (modulus ``2L + 1``) from padded blocks ``(L + 1, 2L, 2L)`` of
    ``m = 0..L``."""
    L = order
    modulus = 2 * L + 1
    blocks: list[NDArray] = [np.zeros((0, 0), dtype=complex)] * modulus
    for m in range(L + 1):
        b = unpad_block(padded[m], m, L)
        blocks[m] = b
        if m > 0:
            blocks[modulus - m] = negative_m_block(b)
    return TMatrix(L, float(k), float(radius_um), modulus, blocks, provenance or {})
