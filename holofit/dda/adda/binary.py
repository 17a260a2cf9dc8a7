"""Finding the user's ADDA binary and asking it its version.

holofit never contains ADDA: it runs the user's own build, found through an explicit path (the
``[dda] adda_path`` config key or an argument), the ``HOLOFIT_ADDA`` environment variable, or
``adda`` on ``PATH``, in that order (``adda/README.md`` at the repository root says how to build
one).
"""

from __future__ import annotations

import functools
import os
import re
import shlex
import shutil
import subprocess
import warnings
from dataclasses import dataclass
from pathlib import Path

from holofit.dda.adda.errors import AddaError, AddaNotFoundError, AddaWarning

__all__ = [
    "ADDA_BINARY_NAME",
    "ADDA_ENV_VAR",
    "MIN_VERSION",
    "TESTED_VERSIONS",
    "AddaVersion",
    "adda_version",
    "find_adda",
    "parse_version",
]

#: environment variable naming the ADDA binary
ADDA_ENV_VAR = "HOLOFIT_ADDA"
#: executable name looked up on PATH
ADDA_BINARY_NAME = "adda"
#: ADDA versions whose flags, file formats and conventions were verified against holofit
TESTED_VERSIONS = ("1.5.0-alpha3",)
#: oldest version with the behaviour the adapter relies on (``-maxiter`` only warns since 1.4)
MIN_VERSION = (1, 4)
#: holofit lab -> ADDA lab (and holofit particle frame -> ADDA particle frame): Rx(pi)


def find_adda(adda_path: str | os.PathLike[str] | None = None) -> Path:
    """Locate the ADDA binary.

    Order: ``adda_path`` (argument or the config's ``adda_path``), then the environment variable
    ``HOLOFIT_ADDA``, then ``adda`` on ``PATH``. A value may be a path or a command name.

    Raises
    ------
    AddaNotFoundError
        Naming every place that was tried.
    """
    tried: list[str] = []
    candidates: list[tuple[str, str]] = []
    if adda_path is not None and str(adda_path) != "":
        candidates.append(("adda_path", str(adda_path)))
    env = os.environ.get(ADDA_ENV_VAR, "")
    if env:
        candidates.append((ADDA_ENV_VAR, env))
    for source, value in candidates:
        found = _executable(value)
        if found is None:
            raise AddaNotFoundError(
                f"ADDA binary given by {source} = {value!r} does not exist or is not executable"
            )
        return found
    tried.append(f"{ADDA_ENV_VAR} (unset)")
    on_path = shutil.which(ADDA_BINARY_NAME)
    if on_path is not None:
        return Path(on_path).resolve()
    tried.append(f"{ADDA_BINARY_NAME!r} on PATH (not found)")
    raise AddaNotFoundError(
        "no ADDA binary found; tried " + ", ".join(tried) + ". Build ADDA "
        "(https://github.com/adda-team/adda, `make seq` in src/) and set "
        f"{ADDA_ENV_VAR}=/path/to/adda, put `adda` on PATH, or give adda_path in the config."
    )


def _executable(value: str) -> Path | None:
    path = Path(value).expanduser()
    if path.is_file() and os.access(path, os.X_OK):
        return path.resolve()
    if os.sep not in value:
        found = shutil.which(value)
        if found is not None:
            return Path(found).resolve()
    return None


@dataclass(frozen=True)
class AddaVersion:
    """What ``adda -V`` says about a binary.

    Attributes
    ----------
    binary : str
        Resolved path of the binary.
    version : str
        Version string, e.g. ``"1.5.0-alpha3"``.
    commit : str
        Git hash in parentheses after the version, if printed.
    banner : str
        The first line of ``adda -V``.
    tested : bool
        True if ``version`` is in :data:`TESTED_VERSIONS`.
    """

    binary: str
    version: str
    commit: str
    banner: str
    tested: bool

    @property
    def numbers(self) -> tuple[int, ...]:
        """Leading numeric part of the version, e.g. (1, 5, 0)."""
        match = re.match(r"(\d+(?:\.\d+)*)", self.version)
        return tuple(int(v) for v in match.group(1).split(".")) if match else ()


_VERSION_RE = re.compile(r"ADDA\s+v\.?\s*(\d[^\s()]*)\s*(?:\(([^)]*)\))?")


def parse_version(text: str, binary: str = "adda") -> AddaVersion:
    """Parse the output of ``adda -V`` (first line ``ADDA v.1.5.0-alpha3 (acbebb0)``).

    Raises
    ------
    AddaError
        If the text does not look like ADDA's version banner.
    """
    for line in text.splitlines():
        match = _VERSION_RE.search(line)
        if match:
            version = match.group(1)
            return AddaVersion(binary=binary, version=version, commit=match.group(2) or "",
                               banner=line.strip(), tested=version in TESTED_VERSIONS)
    head = text.strip().splitlines()[:3]
    raise AddaError(f"{binary} -V did not print an ADDA version banner; it printed: {head!r}")


@functools.cache
def adda_version(binary: str) -> AddaVersion:
    """Version of the ADDA binary at ``binary``, checked once per process (cached).

    Warns (:class:`AddaWarning`) once if the version is not one holofit was tested with.
    """
    command = [binary, "-V"]
    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=60,
                              stdin=subprocess.DEVNULL)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise AddaError(f"could not run `{shlex.join(command)}`: {exc}") from exc
    if proc.returncode != 0:
        raise AddaError(
            f"`{shlex.join(command)}` exited with status {proc.returncode}: "
            f"{(proc.stderr or proc.stdout).strip()[-2000:]}"
        )
    info = parse_version(proc.stdout + "\n" + proc.stderr, binary)
    if not info.tested:
        note = ""
        if info.numbers and info.numbers[:2] < MIN_VERSION:
            note = (" Versions before 1.4 stop with an error at -maxiter and were never tried"
                    " with holofit.")
        warnings.warn(
            f"ADDA {info.version} at {binary} is not a version holofit was tested with "
            f"({', '.join(TESTED_VERSIONS)}); results are used as they come.{note}",
            AddaWarning, stacklevel=2,
        )
    return info
