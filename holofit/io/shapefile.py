"""ADDA text shape files: one dipole per line, ``ix iy iz`` or ``ix iy iz domain``.

The format ADDA reads with ``-shape read`` (and writes with ``-save_geom``): integer lattice
indices, an optional 1-based domain (material) number, ``#`` comments and an optional
``Nmat=N`` line. holofit reads users' dipole sets from it (the ``voxels`` particle model) and
writes its own lattices in it for ADDA.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["read_shape_file", "write_shape_file"]


def read_shape_file(path: str | Path) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Read an ADDA text shape file.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    ijk : ndarray of int, shape (N, 3)
        Dipole indices as in the file.
    domain : ndarray of int, shape (N,)
        0-based domain (material) of each dipole (0 where the file gives none).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        A line that is not ``ix iy iz [domain]``, no dipoles, or a domain number below 1; the
        message names the file and the line.
    """
    path = Path(path)
    rows = []
    try:
        with path.open() as fh:
            for lineno, line in enumerate(fh, 1):
                text = line.split("#", 1)[0].strip()
                if not text or text.lower().startswith("nmat"):
                    continue
                parts = text.split()
                if len(parts) not in (3, 4):
                    raise ValueError(f"{path}:{lineno}: expected 'ix iy iz [domain]', got {text!r}")
                try:
                    values = [int(v) for v in parts]
                except ValueError:
                    raise ValueError(
                        f"{path}:{lineno}: expected integers 'ix iy iz [domain]', got {text!r}"
                    ) from None
                rows.append(values + ([1] if len(parts) == 3 else []))
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: shape file not found") from None
    if not rows:
        raise ValueError(f"{path}: no dipoles in shape file")
    arr = np.array(rows, dtype=np.int64)
    if arr[:, 3].min() < 1:
        raise ValueError(f"{path}: domain numbers start at 1")
    return arr[:, :3], arr[:, 3] - 1


def write_shape_file(
    path: str | Path,
    ijk: ArrayLike,
    domain: ArrayLike | None = None,
    comments: Sequence[str] = (),
) -> Path:
    """Write dipoles as an ADDA text shape file.

    Parameters
    ----------
    path : str or Path
        Output file.
    ijk : array_like of int, shape (N, 3)
        Dipole indices.
    domain : array_like of int, shape (N,), optional
        0-based material of each dipole; with more than one material the file gets an
        ``Nmat=`` line and a fourth (1-based) column.
    comments : sequence of str
        Lines written first, each behind ``#``.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    ijk = np.asarray(ijk, dtype=np.int64).reshape(-1, 3)
    lines = [f"# {c}" for c in comments]
    n_mat = 1 if domain is None else int(np.max(domain)) + 1
    if n_mat > 1:
        lines.append(f"Nmat={n_mat}")
        body = np.column_stack([ijk, np.asarray(domain, dtype=np.int64) + 1])
    else:
        body = ijk
    rows = [" ".join(map(str, row)) for row in body.tolist()]
    path.write_text("\n".join(lines + rows) + "\n")
    return path
