"""Which analysis model each track of a run gets, and which tracks are analysed.

A run may fit a population of particle models (``holofit fit -p rod_paper -p sphere``): the
fit gives each track the model that fits its frames best (:mod:`holofit.fit.models`) and
records it in the fit table's ``model`` column and in the table of tracks beside it
(``tracks.csv``, :mod:`holofit.fit.track_status`), with the reason and remedy of every track
it left out. The analysis follows the fit, track by track: the analysis model of a track is
that of its particle model's kind (:data:`MODEL_OF_KIND`: spheres translate only, head-tail
symmetric bodies are rods, a Janus particle is ``janus``), so an isotropic scatterer in a rod
run is never given a D_r. An analysis model given explicitly (``--model``) is every track's.
Where a table says nothing of its tracks' models (a prefit table, an older fit table) the
sidecar's particle decides (:func:`model_from_sidecar`).

A :class:`TrackSelection` names the tracks analysed (``--particle`` / ``--exclude-particle``);
a track left out by it is reported, not dropped silently.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.analysis.errors import AnalysisError
from holofit.analysis.recipes import MODELS, recipe_for
from holofit.analysis.settings import AnalysisConfig
from holofit.io.tables import sidecar_path

__all__ = [
    "FIT_TRACKS_NAME",
    "MODEL_OF_KIND",
    "FitTrack",
    "TrackModel",
    "TrackSelection",
    "analysis_model_of",
    "default_model",
    "model_from_sidecar",
    "read_fit_tracks",
    "settings_for_model",
    "track_kinds",
    "track_model",
]

#: the analysis model of each particle model whose kind decides it (a dimer: by its spheres,
#: :func:`analysis_model_of`); an isotropic particle translates only, a head-tail symmetric
#: body turns about its axis (the paper's rods), a Janus particle shows its cap
MODEL_OF_KIND = {"sphere": "sphere", "coated_sphere": "sphere", "janus": "janus",
                 "spherocylinder": "rod", "cylinder": "rod", "spheroid": "rod",
                 "ellipsoid": "rod"}
#: the fit's table of tracks, beside its fit table (:func:`holofit.fit.track_status.write_tracks`)
FIT_TRACKS_NAME = "tracks.csv"
#: how the sidecar of the fit's table of tracks begins its ``kind``
FIT_TRACKS_KIND = "the fit's tracks"
#: the statuses of the fit's tracks that it left out (:mod:`holofit.fit.track_status`)
FIT_LEFT_OUT = ("left_out", "unmodelled", "excluded")
#: the column of the fit table that names each row's particle model
MODEL_COLUMN = "model"


def analysis_model_of(kind: str | None, particle: Mapping[str, Any] | None = None
                      ) -> tuple[str | None, str]:
    """The analysis model of a particle model ``kind`` and why; None (and why) when none suits.

    ``particle`` holds the model's parameters where the kind alone does not decide: a dimer of
    two equal spheres is head-tail symmetric (``rod``), one of two different spheres is not.
    """
    if kind in MODEL_OF_KIND:
        return MODEL_OF_KIND[kind], f"the fit's particle, a {kind}"
    if kind == "dimer":
        p = particle or {}
        if p and p.get("radius1_um") == p.get("radius2_um") and p.get("index1") == p.get(
                "index2"):
            return "rod", "the fit's particle, a dimer of two equal spheres"
        return None, "its particle is a dimer (of spheres not known to be equal)"
    return None, f"its particle is a {kind}" if kind else "no particle model is recorded"


def _sidecar(fit_table: Path) -> tuple[dict[str, Any] | None, str]:
    side = sidecar_path(fit_table)
    try:
        doc = json.loads(side.read_text())
    except (OSError, ValueError):
        return None, f"{side} is missing or unreadable"
    return (doc, "") if isinstance(doc, dict) else (None, f"{side} holds no JSON object")


def model_from_sidecar(fit_table: str | Path) -> tuple[str | None, str]:
    """The analysis model of a fit table from its sidecar's particle; or None and why not.

    A prefit table is a sphere's; a fit table records ``particle_model`` and the particle's
    parameters (``config.particle``), read by :func:`analysis_model_of`.
    """
    doc, why = _sidecar(Path(fit_table))
    if doc is None:
        return None, why
    if str(doc.get("kind", "")).startswith("prefit table"):
        return "sphere", "a prefit table (Lorenz-Mie spheres)"
    particle = (doc.get("config") or {}).get("particle") or {}
    kind = doc.get("particle_model") or particle.get("model")
    model, why = analysis_model_of(kind, particle)
    if model is None and not kind:
        why = f"{sidecar_path(Path(fit_table))} names no particle"
    return model, why


def track_kinds(table: pd.DataFrame) -> dict[int, str]:
    """Each track's particle model from the fit table's ``model`` column (the kind on most of
    its rows; the fit gives a track one model, so its rows agree); {} without the column."""
    if MODEL_COLUMN not in table.columns or "particle" not in table.columns:
        return {}
    kinds = table[MODEL_COLUMN].astype("string").str.strip()
    ids = pd.to_numeric(table["particle"], errors="coerce")
    out: dict[int, str] = {}
    for p, k in kinds[kinds.notna() & (kinds != "") & ids.notna()].groupby(ids):
        out[int(p)] = str(k.value_counts().index[0])
    return out


def default_model(fit_table: str | Path) -> tuple[str | None, str]:
    """The analysis model of a table's tracks where a track's own model says nothing: the
    sidecar's particle's, else that of the first track of the ``model`` column; or None and
    why not."""
    model, why = model_from_sidecar(fit_table)
    if model is not None:
        return model, why
    try:
        head = pd.read_csv(fit_table, usecols=lambda c: c in ("particle", MODEL_COLUMN),
                           dtype=str)
    except (OSError, ValueError, pd.errors.ParserError, pd.errors.EmptyDataError):
        return None, why
    for p, kind in sorted(track_kinds(head).items()):
        m, _ = analysis_model_of(kind)
        if m is not None:
            return m, f"the fit table's model column (track {p}, a {kind})"
    return None, why


@dataclass(frozen=True)
class FitTrack:
    """The fit's record of one track (a row of the fit's ``tracks.csv``).

    Attributes
    ----------
    particle : int
        The track.
    kind : str
        The particle model the fit gave it ('' when not recorded).
    status : str
        ``fitted``, ``left_out``, ``unmodelled`` or ``excluded``
        (:data:`holofit.fit.track_status.TRACK_STATUSES`).
    reason, remedy : str
        Why (the model test's result, or the cause of leaving it out) and what to try.
    statics : dict
        The static parameters its final pass fixed (``static_*`` columns, the model's units).
    """

    particle: int
    kind: str
    status: str
    reason: str = ""
    remedy: str = ""
    statics: dict[str, float] = field(default_factory=dict)

    @property
    def fitted(self) -> bool:
        return self.status == "fitted"

    @property
    def left_out(self) -> bool:
        """The fit left it out (no static parameters, or a selection's)."""
        return self.status in FIT_LEFT_OUT


def _text(value: Any) -> str:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) \
        else str(value)


def read_fit_tracks(fit_table: str | Path) -> dict[int, FitTrack]:
    """The fit's table of tracks beside ``fit_table`` by track; {} when there is none.

    Raises
    ------
    AnalysisError
        A table of tracks that cannot be read, or without ``particle`` and ``status``
        (naming the file).
    """
    path = Path(fit_table).parent / FIT_TRACKS_NAME
    if not path.is_file() or path.resolve() == Path(fit_table).resolve():
        return {}
    side, _ = _sidecar(path)
    if side is not None and not str(side.get("kind", "")).startswith(FIT_TRACKS_KIND):
        return {}  # another table of that name (an analysis' own tracks.csv): not the fit's
    try:
        table = pd.read_csv(path, dtype={"reason": str, "remedy": str, "model": str})
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise AnalysisError(f"{path}: the fit's table of tracks is unreadable ({exc})") from None
    if not {"particle", "status"} <= set(table.columns):
        raise AnalysisError(f"{path}: the fit's table of tracks has no 'particle' and "
                            "'status' columns")
    out: dict[int, FitTrack] = {}
    for _, row in table.iterrows():
        statics = {k[len("static_"):]: float(row[k]) for k in table.columns
                   if k.startswith("static_") and pd.notna(row[k])}
        p = int(row["particle"])
        out[p] = FitTrack(p, _text(row.get("model")), _text(row["status"]),
                          _text(row.get("reason")), _text(row.get("remedy")), statics)
    return out


@dataclass(frozen=True)
class TrackSelection:
    """Which tracks are analysed, and whether one model is imposed on all of them.

    Attributes
    ----------
    particles : tuple of int, optional
        Only these tracks (``--particle``; None: every track).
    exclude_particles : tuple of int
        Not these (``--exclude-particle``).
    model : str, optional
        Every track analysed with this model (``--model``); None: each track with its own
        (module docstring).
    """

    particles: tuple[int, ...] | None = None
    exclude_particles: tuple[int, ...] = ()
    model: str | None = None

    def __post_init__(self) -> None:
        if self.model is not None and self.model not in MODELS:
            raise ValueError(f"model {self.model!r}: expected one of {', '.join(MODELS)}")

    def kept(self, have: Iterable[int], source: str) -> set[int]:
        """The tracks of ``have`` analysed.

        Raises
        ------
        AnalysisError
            A track asked for or left out that ``source`` does not hold, or none left.
        """
        have = sorted(set(have))
        asked = set(have if self.particles is None else self.particles)
        unknown = sorted((asked | set(self.exclude_particles)) - set(have))
        if unknown:
            raise AnalysisError(f"{source}: no track(s) {unknown} (tracks: "
                                f"{', '.join(map(str, have))}) for --particle / "
                                "--exclude-particle")
        keep = asked - set(self.exclude_particles)
        if not keep:
            raise AnalysisError(f"{source}: --particle / --exclude-particle leave no track to "
                                "analyse")
        return keep

    def why_left_out(self, particle: int) -> str:
        if particle in self.exclude_particles:
            return f"left out by --exclude-particle {particle}"
        return "left out: not among the --particle tracks asked for"

    def summary(self) -> dict[str, Any]:
        return {"particles": None if self.particles is None else list(self.particles),
                "exclude_particles": list(self.exclude_particles), "model": self.model}


@dataclass(frozen=True)
class TrackModel:
    """The analysis model of one track: ``model`` (None: none suits), the fit's particle
    model ``kind`` ('' when not known) and ``source``, why."""

    model: str | None
    kind: str
    source: str


def track_model(particle: int, kinds: Mapping[int, str], fit_tracks: Mapping[int, FitTrack],
                selection: TrackSelection, default: tuple[str | None, str],
                primary: Mapping[str, Any] | None = None) -> TrackModel:
    """The analysis model of track ``particle`` (module docstring): the selection's model when
    it names one; else that of the particle model the fit gave the track (its rows' ``model``,
    else the fit's table of tracks); else ``default`` (model, why: the sidecar's).
    ``primary`` holds the parameters of the run's primary particle (a dimer's spheres)."""
    kind = kinds.get(particle) or (fit_tracks[particle].kind if particle in fit_tracks else "")
    if selection.model is not None:
        return TrackModel(selection.model, kind, "given (--model)")
    if kind:
        prim = primary if primary and primary.get("model") == kind else None
        model, why = analysis_model_of(kind, prim)
        return TrackModel(model, kind, why)
    return TrackModel(default[0], kind, default[1])


#: settings a model's recipe decides when they are not given (:class:`AnalysisConfig`)
_RECIPE_SETTINGS = ("head_tail", "reject", "drop_ambiguous")


def settings_for_model(settings: AnalysisConfig, model: str) -> AnalysisConfig:
    """``settings`` for a track of analysis model ``model``.

    The same settings where the model is theirs. For another model: the recipe's choices
    (head-tail correction, rejection, ambiguous frames) that equal the default of the
    settings' model are that model's defaults, not the user's, and become ``model``'s; the
    sizes (``a_um``, ``b_um`` and their errors) are the settings' particle's and do not hold
    for another, so the track's own table medians replace them.
    """
    if model == settings.model:
        return settings
    base = recipe_for(settings.model)
    kw = {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}
    for name in _RECIPE_SETTINGS:
        if kw[name] == getattr(base, name) or not base.orientation:
            kw[name] = None
    for name in ("a_um", "b_um", "a_err_um", "b_err_um"):
        kw[name] = None
    kw["model"] = model
    return AnalysisConfig(**kw)
