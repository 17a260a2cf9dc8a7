"""What a run folder's Makefile needs to know, checked: :class:`RunFolderConfig`, and the rules
for its parts (paths make can use, the options a stage may be given, the analysis model of a
particle).
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Mapping
from dataclasses import dataclass, field

from holofit.runfolder.errors import RunFolderError

__all__ = [
    "ANALYSIS_MODEL_OF",
    "RESERVED_OPTIONS",
    "STAGES",
    "RunFolderConfig",
    "analysis_model_for",
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

#: the diffusion analysis that suits each particle model (``holofit analyze --model``); models
#: missing here (ellipsoid, voxels: no symmetry axis the analysis can rely on) need one given
ANALYSIS_MODEL_OF: dict[str, str] = {
    "sphere": "sphere",
    "janus": "janus",
    "spherocylinder": "rod",
    "cylinder": "rod",
    "spheroid": "rod",
    "dimer": "rod",
}

#: characters of a path that make can use as a prerequisite and the shell as a word, unquoted
_SAFE_PATH = re.compile(r"[\w./+,@=~-]+")


def analysis_model_for(kind: str, given: str | None) -> str:
    """The ``holofit analyze --model`` of a particle model ``kind`` (``given`` wins).

    Raises
    ------
    RunFolderError
        No default for ``kind`` and none given.
    """
    if given:
        return given
    try:
        return ANALYSIS_MODEL_OF[kind]
    except KeyError:
        raise RunFolderError(
            f"which diffusion analysis suits a {kind!r} particle? give the analysis model "
            f"(--model rod, janus or sphere)") from None


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
        ``holofit analyze --model``.
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

    def option(self, stage: str) -> str:
        """Extra options of ``stage`` (empty when none)."""
        return self.options.get(stage, "")


#: the former name, kept for existing code (deprecated)
RunSpec = RunFolderConfig
