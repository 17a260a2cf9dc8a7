"""Provenance for every output: versions, the command line, inputs, configuration, units."""

from __future__ import annotations

import datetime as _dt
import hashlib
import platform
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

import holofit

__all__ = ["command_line", "describe_input", "sidecar", "versions"]

_PACKAGES = ("numpy", "scipy", "numba", "pandas", "tifffile", "click", "opencv-python-headless")


def versions() -> dict[str, str]:
    """Versions of Python, holofit and the libraries that shape its numbers."""
    out = {"python": platform.python_version(), "holofit": holofit.__version__}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def command_line() -> str:
    """The command that is running, as typed (best effort)."""
    argv = list(sys.argv)
    if argv and argv[0].endswith(("holofit", "__main__.py")):
        argv[0] = "holofit"
    return " ".join(argv)


def describe_input(path: str | Path, checksum: bool = False) -> dict[str, Any]:
    """Path, size and (optionally) SHA-256 of an input file or folder."""
    p = Path(path)
    info: dict[str, Any] = {"path": str(p)}
    if p.is_file():
        info["bytes"] = p.stat().st_size
        if checksum:
            h = hashlib.sha256()
            with p.open("rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
            info["sha256"] = h.hexdigest()
    elif p.is_dir():
        info["kind"] = "folder"
    return info


def sidecar(
    *,
    kind: str,
    units: dict[str, str] | None = None,
    config: dict[str, Any] | None = None,
    inputs: list[str | Path] | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The JSON document written next to an output file.

    Parameters
    ----------
    kind : str
        What the output is (e.g. ``"crop table"``).
    units : dict, optional
        Column or field name -> unit.
    config : dict, optional
        The configuration that produced it.
    inputs : list, optional
        Input files.
    extra : dict, optional
        Anything else (ground truth of a simulation, fit settings, ...).
    """
    return {
        "kind": kind,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": command_line(),
        "versions": versions(),
        "units": units or {},
        "config": config or {},
        "inputs": [describe_input(p) for p in (inputs or [])],
        **(extra or {}),
    }
