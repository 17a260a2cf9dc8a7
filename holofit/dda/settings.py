"""Settings of the built-in DDA engine (the ``[dda]`` table of a particle-model file)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from holofit.config_schema import ConfigError, Spec, validate_table
from holofit.optics import Optics
from holofit.particles import ParticleModel

__all__ = ["DDA_ENGINES", "DDASettings"]

#: the discrete-dipole engines a ``[dda]`` table may name (their classes' ``name``); the engine
#: registry (:mod:`holofit.engines.registry`) lists them after the exact engines
DDA_ENGINES: tuple[str, ...] = ("builtin", "adda")

_SPECS: dict[str, Spec] = {
    "dipole_size_um": Spec("float", "the dipole size in um", 0.001, 1.0, required=False),
    "dipoles_per_wavelength": Spec(
        "float", "dipoles per wavelength in the particle", 3.0, 100.0, required=False,
        default=10.0,
    ),
    "layer_dipoles": Spec(
        "float", "dipoles across the thinnest layer (shell, cap)", 1.0, 50.0, required=False),
    "filling": Spec("str", "'fractional', 'ramp' or 'binary'", required=False,
                    default="fractional"),
    "polarizability": Spec("str", "'fcd', 'ldr', 'ldr_avg' or 'cm'", required=False,
                           default="fcd"),
    "tolerance": Spec("float", "the solver's relative residual", 1e-14, 0.1, required=False,
                      default=1e-5),
    "max_iterations": Spec("int", "the solver's iteration limit", 1, 100000, required=False,
                           default=2000),
    "precision": Spec("str", "'double' or 'single' FFT convolution", required=False,
                      default="double"),
    "solver": Spec("str", "'qmr' or 'bicgstab'", required=False, default="qmr"),
    "engine": Spec("str", "'builtin' or 'adda'", required=False, default="builtin"),
    "adda_path": Spec("str", "the ADDA executable (engine = 'adda')", required=False),
}


@dataclass(frozen=True)
class DDASettings:
    """How the built-in engine discretises and solves a particle.

    Attributes
    ----------
    dipole_size_um : float or None
        Lattice spacing; None: from ``dipoles_per_wavelength`` and the model's largest index.
        Fits must keep it fixed (the fit stage freezes it at its first model).
    dipoles_per_wavelength : float
        ``d = lambda_medium / (dpl * max |m|)``; 10 is ADDA's rule.
    layer_dipoles : float or None
        Also ``d <= t / layer_dipoles`` for the thinnest layer ``t`` of a coated or Janus
        sphere (None: off, the default). A thin high-index shell needs far more dipoles than
        the wavelength rule gives to be fitted without bias; this buys it at a cost of
        ``~layer_dipoles^3`` (see :func:`holofit.dda.voxelize.dipole_size`).
    filling : {"fractional", "ramp", "binary"}
        Plane-cut fractional filling (default; the voxelised volume is exact for faces of
        any orientation), the older smooth ramp of the signed distance (kept to compare), or
        centre-inside voxels (:mod:`holofit.dda.voxelize`).
    polarizability : {"fcd", "ldr", "ldr_avg", "cm"}
        Filtered coupled dipoles (FCD polarisability and filtered interaction; ADDA ``-pol fcd
        -int fcd``; the default: smaller hologram errors than LDR for high-index and
        absorbing materials, docs: validation, "the DDA"), the lattice dispersion
        relation (ADDA's default: use it to compare with ADDA), LDR with its direction- and
        polarisation-dependent S term replaced by the average 1/5 (``"ldr_avg"``), or
        Clausius-Mossotti. All but ``"ldr"`` are incidence-independent: the lattice then has a
        T-matrix (:mod:`holofit.scattering.tmatrix`).
    tolerance : float
        Relative residual of the QMR solve (ADDA's default 1e-5).
    max_iterations : int
        Iteration limit; a solve that hits it raises :class:`~holofit.dda.solver.ConvergenceError`.
    precision : {"double", "single"}
        Precision of the FFT convolution (single is faster, ~1e-7 relative error).
    solver : {"qmr", "bicgstab"}
        Krylov method: QMR for complex-symmetric systems (one product per iteration, ADDA's
        default) or BiCGStab (two per iteration).
    engine : {"builtin", "adda"}
        Which engine a pipeline run uses for this particle.
    adda_path : str or None
        The user's ADDA binary for ``engine = "adda"`` (else ``$HOLOFIT_ADDA``, then ``adda``
        on PATH; see adda/README.md).
    """

    dipole_size_um: float | None = None
    dipoles_per_wavelength: float = 10.0
    layer_dipoles: float | None = None
    filling: str = "fractional"
    polarizability: str = "fcd"
    tolerance: float = 1e-5
    max_iterations: int = 2000
    precision: str = "double"
    solver: str = "qmr"
    engine: str = "builtin"
    adda_path: str | None = None

    def __post_init__(self) -> None:
        choices = {"filling": ("fractional", "ramp", "binary"),
                   "polarizability": ("ldr", "ldr_avg", "cm", "fcd"),
                   "precision": ("double", "single"), "engine": DDA_ENGINES,
                   "solver": ("qmr", "bicgstab")}
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(
                    f"dda {name} must be one of {allowed}, got {getattr(self, name)!r}"
                )

    @classmethod
    def from_dict(cls, table: dict[str, Any], path: str | Path = "<dda settings>") -> DDASettings:
        """Validated settings from a ``[dda]`` table (errors name the file and key)."""
        values = validate_table(table, _SPECS, Path(path), "dda")
        try:
            return cls(**values)
        except ValueError as exc:
            raise ConfigError(f"{path}: [dda]: {exc}") from None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def dipole_size_for(self, model: ParticleModel, optics: Optics) -> float:
        """The lattice spacing for ``model``: ``dipole_size_um`` if set, else the
        dipoles-per-wavelength rule, and the thin-layer rule if ``layer_dipoles`` is set
        (:func:`holofit.dda.voxelize.dipole_size`), um."""
        if self.dipole_size_um is not None:
            return self.dipole_size_um
        from holofit.dda.voxelize import dipole_size

        return dipole_size(model, optics.wavelength_medium_um, optics.n_medium,
                           self.dipoles_per_wavelength, self.layer_dipoles)

    def replace(self, **changes: Any) -> DDASettings:
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update(changes)
        return DDASettings(**values)
