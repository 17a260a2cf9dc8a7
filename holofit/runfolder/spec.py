"""What a run folder's Makefile needs to know, checked: :class:`RunFolderConfig`, and the rules
for its parts (paths make can use, the options a stage may be given, the analysis model of a
particle).
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from holofit.analysis.population import analysis_model_of
from holofit.runfolder.errors import RunFolderError

__all__ = [
    "ANALYSIS_MODEL_OF",
    "RESERVED_OPTIONS",
    "STAGES",
    "RunFolderConfig",
    "analysis_model_for",
    "analysis_reads_model",
    "check_make_path",
    "check_stage_options",
    "make_value",
]

#: stages whose extra options the Makefile takes (``CROP_OPTS``, ..., ``ANALYZE_OPTS``)
STAGES = ("crop", "prefit", "library", "fit", "analyze")

#: options the Makefile sets itself, by stage: an extra option may not repeat them (the inputs
#: and outputs are the run folder's; engine, model, temperature, workers and the scheduler are
#: Makefile variables; --overwrite is decided by the Makefile, see holofit.runfolder.makefile)
_BATCH = ("-j", "--workers", "--scheduler", "--overwrite", "-i", "--instrument", "-o", "--out")
RESERVED_OPTIONS: dict[str, tuple[str, ...]] = {
    "crop": ("-b", "--background", "--dark", "--dark-count", "--normalized", "-i",
             "--instrument", "-o", "--out"),
    "prefit": _BATCH,
    "library": (*_BATCH, "-p", "--particle-model", "--prefit", "--engine"),
    "fit": (*_BATCH, "-p", "--particle-model", "--prefit", "--library", "--pass", "--engine"),
    "analyze": ("-m", "--model", "--temperature-c", "-o", "--out"),
}

#: the particle models a run folder analyses without being told how, and the analysis of those
#: the analysis cannot decide from the fit table alone
#: (:func:`holofit.analysis.population.analysis_model_of`): a dimer of spheres not known to be
#: equal is analysed as a rod (``holofit analyze --model rod``); models missing here
#: (ellipsoid, voxels: no symmetry axis the analysis can rely on) need one given
ANALYSIS_MODEL_OF: dict[str, str] = {
    "sphere": "sphere",
    "coated_sphere": "sphere",
    "janus": "janus",
    "spherocylinder": "rod",
    "cylinder": "rod",
    "spheroid": "rod",
    "dimer": "rod",
}

#: characters of a path that make can use as a prerequisite and the shell as a word, unquoted
_SAFE_PATH = re.compile(r"[\w./+,@=~-]+")


def analysis_model_for(kind: str, given: str | None,
                       particle: Mapping[str, Any] | None = None) -> str:
    """The diffusion analysis of a particle model ``kind`` (``given`` wins) of
    :data:`ANALYSIS_MODEL_OF`: the one the analysis itself reads from the fit table
    (:func:`holofit.analysis.population.analysis_model_of`, with the model's parameters
    ``particle``), else :data:`ANALYSIS_MODEL_OF`'s.

    Raises
    ------
    RunFolderError
        No model for ``kind`` and none given.
    """
    if given:
        return given
    if kind not in ANALYSIS_MODEL_OF:
        raise RunFolderError(
            f"which diffusion analysis suits a {kind!r} particle? give the analysis model "
            f"(--model rod, janus or sphere)")
    own, _ = analysis_model_of(kind, particle)
    return own if own is not None else ANALYSIS_MODEL_OF[kind]


def analysis_reads_model(kind: str, particle: Mapping[str, Any] | None, model: str) -> bool:
    """The analysis gives a track of particle model ``kind`` the analysis ``model`` by itself
    (from the fit table's model column and sidecar): the Makefile need not pass ``--model``."""
    return analysis_model_of(kind, particle)[0] == model


def check_make_path(path: str, what: str) -> str:
    """``path`` itself, if make and the shell can use it unquoted.

    Raises
    ------
    RunFolderError
        A path with a space or one of ``: # $ % * ? [ ] ' " \\ ; & | < > ( )``: make splits
        prerequisites at spaces and gives the others meanings of its own.
    """
    if not _SAFE_PATH.fullmatch(path):
        bad = sorted({c for c in path if not _SAFE_PATH.fullmatch(c)})
        shown = " ".join("space" if c == " " else repr(c) for c in bad)
        raise RunFolderError(
            f"{what} {path}: make cannot use a path with {shown} in it; link it from a path "
            f"without (ln -s '{path}' /data/movie01.tif) and give that")
    return path


def check_stage_options(stage: str, text: str) -> str:
    """The extra options of a stage, as one line; refuses those the Makefile sets itself.

    Raises
    ------
    RunFolderError
        Unbalanced quotes, a line break, or a reserved option (:data:`RESERVED_OPTIONS`).
    """
    if "\n" in text or "\r" in text:
        raise RunFolderError(f"{stage} options: one line expected, got {text!r}")
    try:
        words = shlex.split(text)
    except ValueError as exc:
        raise RunFolderError(f"{stage} options {text!r}: {exc}") from None
    reserved = RESERVED_OPTIONS[stage]
    for word in words:
        name = word.split("=", 1)[0] if word.startswith("--") else word[:2]
        if name in reserved:
            raise RunFolderError(
                f"{stage} options {text!r}: {name} is set by the run folder's Makefile "
                f"(inputs, outputs, engine, model, temperature: holofit init's options; "
                f"workers and scheduler: make JOBS=... SCHEDULER=...; --overwrite: decided "
                f"by make, or make OVERWRITE=1)")
    return " ".join(text.split())


def make_value(text: str) -> str:
    """``text`` as the value of a make variable: ``$`` doubled, ``#`` escaped."""
    return text.replace("$", "$$").replace("#", r"\#")


@dataclass(frozen=True)
class RunFolderConfig:
    """Everything a run folder's Makefile and README say.

    Attributes
    ----------
    movie : str
        Absolute path of the raw movie (file or folder of frames); checked by
        :func:`check_make_path`, as are the next two.
    backgrounds, darks : tuple of str
        Absolute paths of the background and dark files.
    dark_count : float, optional
        Dark level in counts (instead of dark frames).
    normalized : bool
        The movie is background-divided already.
    particle_kind : str
        The particle model (``sphere``, ``spherocylinder``, ...).
    anisotropic : bool
        The particle has an orientation: the library stage runs.
    analysis_model : str
        The diffusion analysis of the run's (primary) particle model.
    temperature_c : float
        Sample temperature, C.
    engine : str, optional
        Scattering engine of library and fit (None: the particle config's).
    options : dict
        Stage -> extra options (a key of :data:`STAGES`; checked by
        :func:`check_stage_options`).
    holofit : str
        The shell command that runs holofit.
    instrument_source, particle_source : str
        Where the config copies came from.
    alternatives : tuple of str
        The copies of the population's other models (``particle_<kind>.toml``): each track is
        fitted with the model that fits it best (:mod:`holofit.fit.models`).
    analysis_forced : bool
        The Makefile passes ``--model analysis_model`` to the analysis, imposing it on every
        track: it was given (``holofit init --model``), or the analysis cannot tell it from
        the fit table of a single-model run (a dimer of spheres not known to be equal).
        Otherwise the analysis reads each track's model from the fit table, in a run of one
        model as in a population.
    header : tuple of str
        Lines about who wrote the folder and how (version, date, command).
    """

    movie: str
    backgrounds: tuple[str, ...]
    darks: tuple[str, ...]
    dark_count: float | None
    normalized: bool
    particle_kind: str
    anisotropic: bool
    analysis_model: str
    temperature_c: float
    engine: str | None
    options: Mapping[str, str] = field(default_factory=dict)
    holofit: str = "holofit"
    instrument_source: str = ""
    particle_source: str = ""
    alternatives: tuple[str, ...] = ()
    header: tuple[str, ...] = ()
    analysis_forced: bool = False

    def option(self, stage: str) -> str:
        """Extra options of ``stage`` (empty when none)."""
        return self.options.get(stage, "")


#: the former name, kept for existing code (deprecated)
RunSpec = RunFolderConfig
