"""How the command line reports failures: a foreseeable failure is one line, never a traceback.

Every holofit error type that stands for bad input or a failing external program (a config
file, a movie, a crop folder, a fit table, ADDA, a solver that does not converge, a missing
input file) is turned, at the top of the command line, into

    holofit <stage>: error: <message>

and exit status 1, so no command needs its own ``try``/``except`` for them. ``--debug`` (or
``HOLOFIT_DEBUG=1``) shows the traceback instead. Any other exception is a bug and keeps its
traceback.

Ctrl-C (SIGINT) ends a command with one line saying that what is done is kept and that the
same command (or ``make``) resumes it, and exit status 130 (128 + SIGINT, as a shell reports
it), instead of click's "Aborted!" with status 1.

While a command runs, warnings (Python's ``warnings``) are printed as one line each, without the
source line they were raised from, and third-party log records (tifffile's) are held back and
printed after holofit's own output, or appended to its error, instead of before it.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import sys
import warnings
from collections.abc import Iterator
from typing import Any

import click

__all__ = ["DEBUG_ENV", "INTERRUPTED_EXIT", "HolofitGroup", "StageFailure", "foreseeable_types"]

#: exit status of a command stopped by Ctrl-C: 128 + SIGINT, as shells report it
INTERRUPTED_EXIT = 130

#: environment variable that turns on tracebacks, as ``--debug`` does
DEBUG_ENV = "HOLOFIT_DEBUG"

#: holofit's error types for foreseeable failures, by defining module (looked up only in modules
#: already imported: an exception of a type whose module was never imported cannot occur)
FORESEEABLE: tuple[tuple[str, str], ...] = (
    ("holofit.config_schema", "ConfigError"),
    ("holofit.crop.errors", "CropError"),
    ("holofit.tables.cropset", "CropSetError"),
    ("holofit.io.movie", "MovieError"),
    ("holofit.batch.errors", "BatchError"),
    ("holofit.io.lock", "OutputLocked"),
    ("holofit.fit.stage", "FitStageError"),
    ("holofit.analysis.errors", "AnalysisError"),
    ("holofit.analysis.settings", "SettingError"),
    ("holofit.batch.journal", "JournalError"),
    ("holofit.tables.fit", "FitTableError"),
    ("holofit.dda.adda.errors", "AddaError"),
    ("holofit.dda.solver", "ConvergenceError"),
    ("holofit.simulate.holograms", "SimulationError"),
)

#: operating-system failures a user can cause and fix (a missing input, a read-only folder, a
#: full disk)
_OS_ERRNOS = {
    errno.ENOENT, errno.EACCES, errno.EPERM, errno.EISDIR, errno.ENOTDIR, errno.EEXIST,
    errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.ENAMETOOLONG,
}


def foreseeable_types() -> tuple[type[BaseException], ...]:
    """The error types of :data:`FORESEEABLE` whose modules are loaded."""
    found = []
    for module, name in FORESEEABLE:
        loaded = sys.modules.get(module)
        kind = getattr(loaded, name, None) if loaded is not None else None
        if isinstance(kind, type) and issubclass(kind, BaseException):
            found.append(kind)
    return tuple(found)


def _message(exc: BaseException) -> str | None:
    """The user's message for a foreseeable failure; None for a bug."""
    if isinstance(exc, foreseeable_types()):
        return str(exc)
    if isinstance(exc, OSError) and exc.errno in _OS_ERRNOS:
        if exc.filename is not None and exc.strerror:
            where = f"{exc.filename}" + (f" -> {exc.filename2}" if exc.filename2 else "")
            return f"{where}: {exc.strerror}"
        return str(exc)
    return None


class StageFailure(click.ClickException):
    """A foreseeable failure of a stage, shown as ``holofit <stage>: error: <message>``."""

    exit_code = 1

    def __init__(self, stage: str, message: str) -> None:
        super().__init__(message)
        self.stage = stage

    def show(self, file: Any = None) -> None:
        stage = f" {self.stage}" if self.stage else ""
        click.echo(f"holofit{stage}: error: {self.format_message()}", err=True, file=file)


def _debug(ctx: click.Context) -> bool:
    root = ctx.find_root()
    if root.params.get("debug"):
        return True
    return os.environ.get(DEBUG_ENV, "").strip().lower() not in ("", "0", "false", "no")


class _Held(logging.Handler):
    """Holds third-party log records back until holofit has spoken."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
        except Exception:
            message = str(record.msg)
        if record.name.split(".")[0] == "holofit":  # holofit's own: shown as it comes
            click.echo(f"holofit: {record.levelname.lower()}: {message}", err=True)
            return
        line = f"{record.name}: {message}"
        if line not in self.lines:
            self.lines.append(line)


def _show_warning(message: Warning | str, category: type[Warning], *_: Any, **__: Any) -> None:
    click.echo(f"holofit: warning: {category.__name__}: {message}", err=True)


@contextlib.contextmanager
def _quiet_libraries(debug: bool) -> Iterator[_Held]:
    """Warnings as single lines; third-party log records held (printed as they come in debug)."""
    held = _Held()
    root = logging.getLogger()
    if debug:
        yield held
        return
    root.addHandler(held)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            yield held
    finally:
        root.removeHandler(held)


_STAGE_KEY = "holofit.stage"


class HolofitGroup(click.Group):
    """A click group whose subcommands' foreseeable failures become :class:`StageFailure`.

    Nested groups (``simulate``) use it too; the outermost one reports.
    """

    def invoke(self, ctx: click.Context) -> Any:
        if ctx.parent is not None:
            try:
                return super().invoke(ctx)
            finally:
                ctx.meta.setdefault(_STAGE_KEY, _stage(ctx))
        debug = _debug(ctx)
        with _quiet_libraries(debug) as held:
            try:
                result = super().invoke(ctx)
            except click.exceptions.Exit:
                raise
            except (KeyboardInterrupt, click.exceptions.Abort) as exc:
                if debug and isinstance(exc, KeyboardInterrupt):
                    raise
                stage = ctx.meta.get(_STAGE_KEY, _stage(ctx))
                click.echo(f"\nholofit {stage}: interrupted: what is done is kept; run the "
                           "same command again (or make, in a run folder) to resume", err=True)
                raise click.exceptions.Exit(INTERRUPTED_EXIT) from None
            except click.ClickException as exc:
                if held.lines and not debug:
                    # click types ``message`` Final; appending in place keeps the exception's
                    # own class and formatting (UsageError's usage line, BadParameter's hint)
                    exc.message += "".join(  # type: ignore[misc]
                        f"\n  ({line})" for line in held.lines)
                raise
            except Exception as exc:
                message = _message(exc)
                if message is None or debug:
                    for line in held.lines:  # context for the traceback that follows
                        click.echo(line, err=True)
                    raise
                message += "".join(f"\n  ({line})" for line in held.lines)
                raise StageFailure(ctx.meta.get(_STAGE_KEY, _stage(ctx)), message) from None
        stage = ctx.meta.get(_STAGE_KEY, _stage(ctx))
        for line in held.lines:
            click.echo(f"holofit {stage}: note: {line}", err=True)
        return result


def _stage(ctx: click.Context) -> str:
    """``crop`` or ``simulate hologram``: the subcommand that ran under ``ctx``."""
    names = ctx.command_path.split()[1:]
    if ctx.invoked_subcommand:
        names.append(ctx.invoked_subcommand)
    return " ".join(names)
