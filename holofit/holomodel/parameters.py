"""The parameters of a hologram fit: what they are called, their units, their finite-difference
steps, and how the optimiser's vector maps onto a particle state.

A fit varies some of

- the position ``x_um, y_um, z_um`` (full-frame, um; :mod:`holofit.conventions`),
- the orientation (anisotropic particles),
- the scattered-field scaling ``alpha``,
- the objective's numerical aperture ``numerical_aperture`` (an optics parameter: it changes the
  lens image of the solved particle, not the solve; :mod:`holofit.scattering.lens`),
- the objective's spherical-aberration coefficients ``sa4_rad, sa6_rad, ...``
  (:mod:`holofit.aberration`; kind ``aberration``: like the NA they change the lens image, not
  the solve, and their Jacobian columns are exact, :meth:`LensImage.field_derivatives
  <holofit.scattering.lens.LensImage.field_derivatives>`),
- the particle model's own ("static") parameters: its sizes (``a_um``, ``radius_um``, ...) and
  the real parts of its refractive indices, named ``n`` (one index), ``n_core``/``n_cap``
  (``index_core``/``index_cap``), ``n1``/``n2`` (``index1``/``index2``, or a voxel file's
  domains), the names the fit tables use.

Orientation is reported as the zyz Euler angles ``theta_rad, psi_rad`` (and ``phi_rad`` for
particles that are not axisymmetric), but the optimiser does not move the Euler angles: they are
singular where the axis is along the optical axis (``psi`` undefined at ``theta = 0``). It
moves a rotation vector ``w`` applied in the lab to the start orientation ``R0``,
``R = exp([w]x) R0``, with ``w`` in the plane perpendicular to the start axis for axisymmetric
particles (two components ``rot_a``, ``rot_b``) and free in 3-D otherwise (``rot_c`` about the
start axis): the map is smooth everywhere and its Jacobian columns are never degenerate.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import SPHERICAL_NAMES, Aberration
from holofit.config_schema import INDEX_RANGE
from holofit.conventions import (
    axis_from_angles,
    euler_zyz,
    euler_zyz_from_matrix,
    rotation_from_vector,
)
from holofit.particles import Cluster, ParticleModel, VoxelShape

__all__ = [
    "ABERRATION",
    "APERTURE",
    "ORIENTATION_COLUMNS",
    "POSITION",
    "Parameter",
    "ParameterSpace",
    "State",
    "index_column",
    "particle_with",
    "static_parameters",
    "static_values",
]

#: finite-difference steps (um for lengths, rad for rotations, 1 for index and alpha)
POSITION_STEP_UM = 1e-5
ROTATION_STEP_RAD = 2e-3
SIZE_STEP_UM = 2e-3
INDEX_STEP = 1e-3
ALPHA_STEP = 1e-5
#: the lens image moves smoothly with the aperture; the quadrature's node count changes in
#: steps, so the step is large enough that its ~1e-10 jumps do not matter
APERTURE_STEP = 1e-3

ORIENTATION_COLUMNS = ("theta_rad", "psi_rad", "phi_rad")


@dataclass(frozen=True)
class Parameter:
    """One fitted quantity.

    Attributes
    ----------
    name : str
        Its name in the fit tables (``z_um``, ``a_um``, ``n_cap``, ``alpha``, ``rot_a``).
    kind : {"position", "orientation", "scale", "static", "optics", "aberration"}
        What it changes: position moves the solved field, orientation and static parameters
        need a new solve, scale is ``alpha``, optics (the numerical aperture) and aberration
        (a spherical-aberration coefficient) change the lens image of the solved field.
    unit : str
        ``um``, ``rad`` or ``1``.
    step : float
        Finite-difference step of its Jacobian column, in its unit.
    lower, upper : float
        Physical range: a fit that ends outside it is flagged (``poor_fit``).
    field : str, optional
        The particle model's field a static parameter sets.
    element : int, optional
        Element of a tuple-valued field (a voxel file's indices).
    """

    name: str
    kind: str
    unit: str
    step: float
    lower: float = -math.inf
    upper: float = math.inf
    field: str | None = None
    element: int | None = None


POSITION: tuple[Parameter, ...] = (
    Parameter("x_um", "position", "um", POSITION_STEP_UM),
    Parameter("y_um", "position", "um", POSITION_STEP_UM),
    Parameter("z_um", "position", "um", POSITION_STEP_UM),
)
ALPHA = Parameter("alpha", "scale", "1", ALPHA_STEP, 0.05, 5.0)
#: the objective's NA: larger than 0; above the medium's index the lens collects every
#: propagating wave and the hologram no longer changes with it
APERTURE = Parameter("numerical_aperture", "optics", "1", APERTURE_STEP, 0.05, math.inf)
#: the spherical-aberration coefficients (rad; :mod:`holofit.aberration`): the image moves
#: smoothly with them and their columns are exact, so the step only serves a held copy
ABERRATION_STEP = 1e-3
ABERRATION: tuple[Parameter, ...] = tuple(
    Parameter(name, "aberration", "rad", ABERRATION_STEP) for name in SPHERICAL_NAMES)
ROTATIONS: tuple[Parameter, ...] = (
    Parameter("rot_a", "orientation", "rad", ROTATION_STEP_RAD),
    Parameter("rot_b", "orientation", "rad", ROTATION_STEP_RAD),
    Parameter("rot_c", "orientation", "rad", ROTATION_STEP_RAD),
)


def index_column(field_name: str, element: int | None = None) -> str:
    """Fit-table name of a refractive-index field: ``index`` -> ``n``, ``index_cap`` ->
    ``n_cap``, ``index1`` -> ``n1``, element ``k`` of ``indices`` -> ``n{k+1}``."""
    if element is not None:
        return f"n{element + 1}"
    suffix = field_name.removeprefix("index")
    return "n" + suffix


def static_parameters(model: ParticleModel) -> tuple[Parameter, ...]:
    """The model's sizes and real index parts as fit parameters (a voxel file: its indices)."""
    out: list[Parameter] = []
    if isinstance(model, VoxelShape | Cluster):
        for k in range(len(model.indices)):
            out.append(Parameter(index_column("indices", k), "static", "1", INDEX_STEP,
                                 *INDEX_RANGE, field="indices", element=k))
        return tuple(out)
    for f in model.size_fields:
        out.append(Parameter(f, "static", "um", SIZE_STEP_UM, 0.0, math.inf, field=f))
    for f in model.nonnegative_fields:
        out.append(Parameter(f, "static", "um", SIZE_STEP_UM, 0.0, math.inf, field=f))
    for f in model.index_fields:
        out.append(Parameter(index_column(f), "static", "1", INDEX_STEP, *INDEX_RANGE, field=f))
    return tuple(out)


def _perpendicular_basis(u: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Two unit vectors perpendicular to ``u`` and to each other (right-handed with u)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


@dataclass(frozen=True)
class State:
    """A point of parameter space: everything a hologram depends on.

    Attributes
    ----------
    position : tuple of float
        ``(x, y, z)``, um, full frame.
    rotation : ndarray (3, 3) or None
        Particle-to-lab rotation actually used for the model (for an axisymmetric particle,
        ``Rz(psi) Ry(theta)`` of its axis); None for isotropic particles.
    alpha : float
        Scattered-field scaling.
    statics : tuple of (str, float)
        Static parameters by name.
    numerical_aperture : float, optional
        The objective's NA the hologram is imaged with; None: the optics' own (a lens or
        the ideal model, as the instrument says).
    aberration : Aberration, optional
        The objective's pupil phase the hologram is imaged with (:mod:`holofit.aberration`);
        None: the optics' own.
    """

    position: tuple[float, float, float]
    rotation: NDArray[np.float64] | None
    alpha: float
    statics: tuple[tuple[str, float], ...] = ()
    numerical_aperture: float | None = None
    aberration: Aberration | None = None

    def angles(self) -> tuple[float, float, float]:
        """``(psi, theta, phi)`` of the rotation, rad (zeros for an isotropic particle)."""
        if self.rotation is None:
            return 0.0, 0.0, 0.0
        psi, theta, phi = euler_zyz_from_matrix(self.rotation)
        return float(psi), float(theta), float(phi)


@dataclass
class ParameterSpace:
    """The parameters of one fit and the map from the optimiser's vector to a :class:`State`.

    Parameters
    ----------
    model : ParticleModel
        The particle (static parameters start from its values).
    free : iterable of str
        Names of the varied parameters: position and static names, ``alpha``,
        ``"numerical_aperture"`` (the start state must then hold one), the spherical-aberration
        coefficients ``"sa4_rad"``, ``"sa6_rad"``, ... (the start state must then hold an
        :class:`~holofit.aberration.Aberration`; missing coefficients start at 0), and
        ``"orientation"`` for the rotation (two or three components, see the module
        docstring). Everything else stays at its start value.
    start : State
        Start values of every parameter.
    fit_spin : bool, optional
        Vary the spin about the particle axis (default: for particles that are not
        axisymmetric).
    step_overrides : dict, optional
        Finite-difference steps by parameter name, replacing the defaults (which suit a DDA
        discretisation: 2 nm for sizes, 1e-3 for indices; an exact engine such as Lorenz-Mie
        can use much smaller ones).
    """

    model: ParticleModel
    free: Iterable[str]
    start: State
    fit_spin: bool | None = None
    step_overrides: dict[str, float] | None = None
    parameters: tuple[Parameter, ...] = field(init=False)
    _basis: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        free = set(self.free)
        statics = static_parameters(self.model)
        known = ({p.name for p in (*POSITION, ALPHA, APERTURE, *ABERRATION, *statics)}
                 | {"orientation"})
        unknown = sorted(free - known)
        if unknown:
            raise ValueError(
                f"unknown fit parameter(s) {', '.join(unknown)} for a {self.model.kind}; known: "
                f"{', '.join(sorted(known))}"
            )
        if "orientation" in free and not self.model.anisotropic:
            free.discard("orientation")
        if self.fit_spin is None:
            self.fit_spin = not self.model.axisymmetric
        params: list[Parameter] = [p for p in POSITION if p.name in free]
        if "orientation" in free:
            params += list(ROTATIONS[: 3 if self.fit_spin else 2])
        params += [p for p in statics if p.name in free]
        if "alpha" in free:
            params.append(ALPHA)
        if APERTURE.name in free:
            if self.start.numerical_aperture is None:
                raise ValueError(
                    "fitting the numerical aperture needs a start value: the instrument's "
                    "numerical_aperture, or one given for the fit")
            params.append(APERTURE)
        fitted_aberration = [p for p in ABERRATION if p.name in free]
        if fitted_aberration:
            if self.start.aberration is None:
                raise ValueError(
                    "fitting the spherical aberration needs a start value: the instrument's "
                    "aberration (Aberration() for none) in the start state")
            n_terms = SPHERICAL_NAMES.index(fitted_aberration[-1].name) + 1
            self.start = replace(self.start, aberration=self.start.aberration.padded(n_terms))
            params += fitted_aberration
        if self.step_overrides:
            params = [replace(p, step=self.step_overrides.get(p.name, p.step)) for p in params]
        self.parameters = tuple(params)
        self.free = tuple(p.name for p in params)
        if self.start.rotation is not None:
            u0 = self.start.rotation[:, 2]
            e1, e2 = _perpendicular_basis(u0)
            self._basis = np.column_stack([e1, e2, u0])
        else:
            self._basis = np.eye(3)
        self._all_statics = statics
        self._static_start = dict(self.start.statics)
        missing = [p.name for p in statics if p.name not in self._static_start]
        if missing:
            raise ValueError(f"start state lacks static parameter(s) {', '.join(missing)}")

    # -- vectors ------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        """Names of the optimiser's vector components."""
        return tuple(p.name for p in self.parameters)

    def rotation_axes(self) -> list[NDArray[np.float64]]:
        """Lab axes of the rotation components ``rot_a, rot_b[, rot_c]`` (unit vectors)."""
        n = sum(1 for p in self.parameters if p.kind == "orientation")
        return [self._basis[:, k].copy() for k in range(n)]

    def initial_vector(self) -> NDArray[np.float64]:
        """The optimiser's start vector (rotation components start at 0)."""
        values = self._flat(self.start)
        return np.array([0.0 if p.kind == "orientation" else values[p.name]
                         for p in self.parameters])

    @staticmethod
    def _flat(state: State) -> dict[str, float]:
        out = dict(zip(("x_um", "y_um", "z_um"), state.position, strict=True))
        out["alpha"] = state.alpha
        out.update(state.statics)
        if state.numerical_aperture is not None:
            out[APERTURE.name] = state.numerical_aperture
        if state.aberration is not None:
            out.update(state.aberration.values())
        return out

    def state(self, vector: Sequence[float] | NDArray) -> State:
        """The state at an optimiser vector."""
        values = self._flat(self.start)
        w = np.zeros(3)
        for p, v in zip(self.parameters, vector, strict=True):
            if p.kind == "orientation":
                w[ROTATIONS.index(p)] = float(v)
            else:
                values[p.name] = float(v)
        rotation = self.start.rotation
        if rotation is not None and np.any(w):
            r = rotation_from_vector(self._basis @ w) @ rotation
            if self.fit_spin:
                rotation = r
            else:
                # an axisymmetric particle: keep phi = 0, only the axis matters
                theta, psi = _angles_of_axis(r[:, 2])
                rotation = euler_zyz(psi, theta, 0.0)
        return State(
            position=(values["x_um"], values["y_um"], values["z_um"]),
            rotation=rotation,
            alpha=values["alpha"],
            statics=tuple((p.name, values[p.name]) for p in self._all_statics),
            numerical_aperture=values.get(APERTURE.name),
            aberration=(None if self.start.aberration is None
                        else Aberration.from_values(values, self.start.aberration)),
        )

    def holding(self, name: str, vector: Sequence[float] | NDArray
                ) -> tuple[ParameterSpace, list[int]]:
        """This space with parameter ``name`` held at its value in ``vector``.

        Returns
        -------
        space : ParameterSpace
            The same start rotation (so the same rotation axes), the other values from
            ``vector``: its vector's components mean what the same names mean here.
        index : list of int
            Where its components sit in this space's vector.
        """
        rotations = [p.name for p in self.parameters if p.kind == "orientation"]
        names = [n for n in self.names if n != name and n not in rotations]
        if rotations and name not in rotations:
            names.append("orientation")
        start = replace(self.state(vector), rotation=self.start.rotation)
        held = ParameterSpace(self.model, names, start, fit_spin=self.fit_spin,
                              step_overrides=self.step_overrides)
        return held, [self.names.index(n) for n in held.names]

    # -- the particle -------------------------------------------------------------------
    def particle(self, state: State) -> ParticleModel:
        """The particle model with the state's static parameters."""
        return particle_with(self.model, dict(state.statics))

    # -- reporting ----------------------------------------------------------------------
    def report(self, vector: Sequence[float] | NDArray,
               covariance: NDArray[np.float64] | None = None) -> tuple[dict, dict]:
        """Values and 1-sigma errors of every reported quantity at ``vector``.

        Position, alpha and static parameters are reported as they are (the numerical
        aperture and the aberration coefficients only when fitted: fixed ones are the
        instrument's); the orientation as
        ``theta_rad, psi_rad`` (``phi_rad`` with spin) and the axis ``ux, uy, uz``, with errors
        propagated from the rotation-vector covariance (NaN for quantities held fixed).
        """
        state = self.state(vector)
        values: dict[str, float] = self._flat(state)
        for name in (APERTURE.name, *SPHERICAL_NAMES):
            if name not in self.names:
                values.pop(name, None)
        errors: dict[str, float] = {k: math.nan for k in values}
        var = np.full(len(self.parameters), np.nan) if covariance is None else np.diag(
            covariance)
        for i, p in enumerate(self.parameters):
            if p.kind != "orientation":
                errors[p.name] = float(np.sqrt(var[i])) if var[i] >= 0 else math.nan
        if state.rotation is None:
            return values, errors
        psi, theta, phi = state.angles()
        values.update(theta_rad=theta, psi_rad=psi)
        axis = axis_from_angles(theta, psi)
        values.update(ux=float(axis[0]), uy=float(axis[1]), uz=float(axis[2]))
        if self.fit_spin:
            values["phi_rad"] = phi
        rot_idx = [i for i, p in enumerate(self.parameters) if p.kind == "orientation"]
        names = ["theta_rad", "psi_rad", "ux", "uy", "uz"] + (["phi_rad"] if self.fit_spin
                                                              else [])
        for n in names:
            errors[n] = math.nan
        if rot_idx and covariance is not None and np.all(np.isfinite(covariance)):
            # linear propagation: d(reported)/d(rotation vector) by central differences
            x = np.asarray(vector, dtype=float)
            jac = np.empty((len(names), len(rot_idx)))
            for col, i in enumerate(rot_idx):
                h = 1e-6
                up, dn = x.copy(), x.copy()
                up[i] += h
                dn[i] -= h
                a, b = self._orientation_values(up), self._orientation_values(dn)
                diff = np.array([a[n] - b[n] for n in names])
                diff[1] = (diff[1] + np.pi) % (2 * np.pi) - np.pi  # psi wraps
                if self.fit_spin:
                    diff[-1] = (diff[-1] + np.pi) % (2 * np.pi) - np.pi
                jac[:, col] = diff / (2 * h)
            cov = covariance[np.ix_(rot_idx, rot_idx)]
            prop = np.diag(jac @ cov @ jac.T)
            for n, v in zip(names, prop, strict=True):
                errors[n] = float(np.sqrt(v)) if v >= 0 else math.nan
        return values, errors

    def _orientation_values(self, vector: NDArray[np.float64]) -> dict[str, float]:
        s = self.state(vector)
        psi, theta, phi = s.angles()
        ax = axis_from_angles(theta, psi)
        return {"theta_rad": theta, "psi_rad": psi, "phi_rad": phi, "ux": float(ax[0]),
                "uy": float(ax[1]), "uz": float(ax[2])}

    def out_of_range(self, state: State) -> list[str]:
        """Descriptions of the fitted parameters outside their physical range."""
        flat = self._flat(state)
        bad = []
        for p in self.parameters:
            if p.kind == "orientation":
                continue
            v = flat[p.name]
            if not (p.lower <= v <= p.upper) or not math.isfinite(v):
                bad.append(f"{p.name} = {v:.4g} outside [{p.lower:g}, {p.upper:g}]")
        return bad


def _angles_of_axis(u: NDArray[np.float64]) -> tuple[float, float]:
    u = u / np.linalg.norm(u)
    theta = math.acos(max(-1.0, min(1.0, float(u[2]))))
    psi = math.atan2(float(u[1]), float(u[0])) if math.hypot(u[0], u[1]) > 1e-15 else 0.0
    return theta, psi


def particle_with(model: ParticleModel, statics: dict[str, float]) -> ParticleModel:
    """``model`` with static parameters (fit-table names) replaced; imaginary parts kept."""
    changes: dict[str, object] = {}
    indices = list(model.indices) if isinstance(model, VoxelShape | Cluster) else None
    for p in static_parameters(model):
        if p.name not in statics:
            continue
        value = statics[p.name]
        assert p.field is not None  # every static parameter names its model field
        if p.element is not None and indices is not None:
            indices[p.element] = complex(value, complex(indices[p.element]).imag)
        elif p.unit == "1":
            old = complex(getattr(model, p.field))
            changes[p.field] = complex(value, old.imag) if old.imag else float(value)
        else:
            changes[p.field] = float(value)
    if indices is not None:
        changes["indices"] = tuple(indices)
    names = {f.name for f in fields(model)}
    return model.replace(**{k: v for k, v in changes.items() if k in names})


def static_values(model: ParticleModel) -> tuple[tuple[str, float], ...]:
    """The model's static parameters by fit-table name (real parts of indices)."""
    out = []
    for p in static_parameters(model):
        if p.element is not None:
            v = complex(model.indices[p.element]).real  # type: ignore[attr-defined]
        else:
            assert p.field is not None  # every static parameter names its model field
            v = complex(getattr(model, p.field)).real
        out.append((p.name, float(v)))
    return tuple(out)
