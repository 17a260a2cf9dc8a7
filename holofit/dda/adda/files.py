"""ADDA's input and output files: the dipole set (shape file), the scattering directions
(pairs file), the amplitude matrix (``ampl_scatgrid``) and the cross sections."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.dda.adda.errors import AddaError
from holofit.dda.lattice import Lattice
from holofit.io.shapefile import write_shape_file

__all__ = [
    "ANGLE_CHECK_DEG",
    "AddaGeometry",
    "adda_geometry",
    "read_ampl_scatgrid",
    "read_cross_sections",
    "write_geometry",
    "write_pairs_file",
]

#: tolerance on the printed (%.2f) angles of ampl_scatgrid against the requested ones, deg
ANGLE_CHECK_DEG = 0.0051

_AMPL_HEADER = "theta phi s1.r s1.i s2.r s2.i s3.r s3.i s4.r s4.i".split()


@dataclass(frozen=True)
class AddaGeometry:
    """A dipole set as ADDA reads it (ADDA's particle frame: holofit's flipped by T).

    Attributes
    ----------
    ijk : ndarray of int, shape (N, 3)
        Dipole indices, each axis starting at 0 (tight box).
    domain : ndarray of int, shape (N,)
        1-based material (domain) number of each dipole.
    n_domains : int
        Number of materials (``-m`` pairs given to ADDA).
    d : float
        Dipole size, um.
    box : tuple of int
        ``(nx, ny, nz)``: ADDA's box; ``-size`` is ``nx * d``.
    centre_offset_um : ndarray, shape (3,)
        Particle centre relative to the box centre (ADDA's phase origin), in *holofit's*
        particle frame, um.
    indices : tuple of complex
        Absolute refractive index of each domain.
    """

    ijk: NDArray[np.int64]
    domain: NDArray[np.int64]
    n_domains: int
    d: float
    box: tuple[int, int, int]
    centre_offset_um: NDArray[np.float64]
    indices: tuple[complex, ...]

    @property
    def n_dipoles(self) -> int:
        return int(self.ijk.shape[0])

    @property
    def size_um(self) -> float:
        """ADDA's ``-size``: the box length along x, um."""
        return self.box[0] * self.d

    def positions_adda(self) -> NDArray[np.float64]:
        """Dipole positions relative to the box centre, ADDA's particle frame, um."""
        return (self.ijk - (np.asarray(self.box) - 1) / 2.0) * self.d


def adda_geometry(lattice: Lattice, threshold: float = 0.5) -> AddaGeometry:
    """The dipoles of ``lattice`` that ADDA will see, in ADDA's (T-flipped) particle frame.

    A voxel is kept if its total material fraction is at least ``threshold`` (binary lattices:
    all); its domain is its dominant material. The box is re-tightened around the kept voxels,
    and the particle centre is located relative to that box's centre.
    """
    ijk, domain = lattice.binary_dipoles(threshold)
    if ijk.shape[0] == 0:
        raise ValueError("ADDA engine: no voxel is filled enough to be written as a dipole")
    domain = domain + 1
    lo, hi = ijk.min(axis=0), ijk.max(axis=0)
    # box centre of the kept voxels, holofit particle frame; particle centre relative to it
    box_centre = lattice.origin + lattice.d * (lo + hi) / 2.0
    flipped = np.column_stack([ijk[:, 0] - lo[0], hi[1] - ijk[:, 1], hi[2] - ijk[:, 2]])
    box = tuple(int(v) for v in hi - lo + 1)
    return AddaGeometry(
        ijk=flipped.astype(np.int64), domain=domain.astype(np.int64),
        n_domains=int(lattice.fractions.shape[1]), d=float(lattice.d),
        box=box,  # type: ignore[arg-type]
        centre_offset_um=-box_centre, indices=tuple(lattice.indices),
    )


def write_geometry(path: str | Path, geometry: AddaGeometry) -> Path:
    """Write the dipoles ADDA gets as a text shape file (``Nmat=`` line if several materials)."""
    return write_shape_file(
        path, geometry.ijk, geometry.domain - 1 if geometry.n_domains > 1 else None,
        comments=("holofit dipole set for ADDA (ADDA particle frame = holofit's flipped by Rx(pi))",
                  f"d = {geometry.d!r} um, box = {geometry.box}"),
    )


def write_pairs_file(path: str | Path, theta_deg: ArrayLike, phi_deg: ArrayLike) -> Path:
    """Write ADDA's ``-scat_grid_inp`` file with ``global_type=pairs`` (full precision)."""
    th = np.asarray(theta_deg, dtype=float).ravel()
    ph = np.asarray(phi_deg, dtype=float).ravel()
    head = f"global_type=pairs\nN={th.size}\npairs=\n"
    body = "\n".join(f"{t!r} {p!r}" for t, p in zip(th.tolist(), ph.tolist(), strict=True))
    Path(path).write_text(head + body + "\n")
    return Path(path)


def read_ampl_scatgrid(
    path: str | Path,
    theta_deg: ArrayLike | None = None,
    phi_deg: ArrayLike | None = None,
) -> NDArray[np.complex128]:
    """Read ADDA's ``ampl_scatgrid``: the amplitude matrix ``[S1, S2, S3, S4]`` per row (M, 4).

    Rows are in the order of the requested directions (pairs: file order; grid: theta outer,
    phi inner). The printed angles are rounded (``%.2f``), so they are only compared with the
    requested ``theta_deg``, ``phi_deg`` (if given) to catch a row-order mismatch.

    Raises
    ------
    AddaError
        Wrong header, wrong number of rows, or printed angles that do not match.
    """
    path = Path(path)
    try:
        with path.open() as fh:
            header = fh.readline().split()
            data = np.loadtxt(fh, ndmin=2)
    except FileNotFoundError:
        raise AddaError(f"{path}: ADDA wrote no ampl_scatgrid") from None
    except ValueError as exc:
        raise AddaError(f"{path}: unreadable amplitude table: {exc}") from None
    if header != _AMPL_HEADER:
        raise AddaError(f"{path}: unexpected header {' '.join(header)!r}; expected "
                        f"{' '.join(_AMPL_HEADER)!r} (run with -scat_matr ampl)")
    if data.shape[1] != 10:
        raise AddaError(f"{path}: expected 10 columns, got {data.shape[1]}")
    if theta_deg is not None and phi_deg is not None:
        th = np.asarray(theta_deg, dtype=float).ravel()
        ph = np.asarray(phi_deg, dtype=float).ravel()
        if data.shape[0] != th.size:
            raise AddaError(f"{path}: {data.shape[0]} rows for {th.size} requested directions")
        d_th = np.abs(data[:, 0] - th)
        d_ph = np.abs((data[:, 1] - ph + 180.0) % 360.0 - 180.0)
        bad = np.nonzero((d_th > ANGLE_CHECK_DEG) | (d_ph > ANGLE_CHECK_DEG))[0]
        if bad.size:
            i = int(bad[0])
            raise AddaError(
                f"{path}: row {i + 2} has angles ({data[i, 0]}, {data[i, 1]}) deg but direction "
                f"{i} was ({th[i]:.4f}, {ph[i]:.4f}) deg: rows are not in the requested order"
            )
    return data[:, 2::2] + 1j * data[:, 3::2]


def read_cross_sections(path: Path) -> dict[str, float]:
    """``name = value`` lines of ADDA's ``CrossSec-X/Y`` (Cext, Qext, Cabs, ... in um^2 / 1)."""
    out: dict[str, float] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            name, _, value = line.partition("=")
            try:
                out[name.strip()] = float(value)
            except ValueError:
                continue
    return out
