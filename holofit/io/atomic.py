"""Atomic file output: write to a temporary file beside the target, then rename.

A reader (or a rerun) therefore sees either the complete old file, the complete new file, or
no file, never a half-written one.

A writer that is killed (``kill -9``, a node lost) cannot delete its temporary file, so the
next writer of the same target removes it: every temporary is named
``.<target name>.holofit-<host>-<pid>-<random>.part`` and is locked (``flock``) by its writer
for as long as it is being written. The lock dies with the process whatever killed it, so a
temporary of the target that nobody holds locked, and whose process is not alive on this host,
is a leftover and is removed; a live writer's temporary (locked) is never touched, nor is any
other file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import socket
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "atomic_path",
    "atomic_write_text",
    "create_temporary",
    "publish",
    "remove_stale_temporaries",
]

#: leftovers of holofit versions that did not lock their temporaries are removed once they are
#: this old (seconds): no live writer leaves its file unmodified that long
LEGACY_STALE_AFTER_S = 600.0


def _default_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


#: permissions of a new output file (as ``open()`` would create it); ``mkstemp`` uses 0600
FILE_MODE = _default_mode()


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9]+", "", socket.gethostname())[:32] or "host"


def _temporary_re(name: str) -> re.Pattern[str]:
    """Names of holofit's temporaries of target ``name`` (``host``/``pid`` None: legacy)."""
    return re.compile(
        rf"^\.{re.escape(name)}\.(?:holofit-(?P<host>[A-Za-z0-9]+)-(?P<pid>\d+)-)?"
        r"[a-z0-9_]{8}\.part$"
    )


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def _lock(fd: int) -> bool:
    """Try to lock ``fd`` exclusively without waiting: True if locked, False if held."""
    if fcntl is None:
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Remove the temporaries of ``path`` that killed writers left behind.

    Only files named as :func:`create_temporary` names them for this very target are
    considered, and one is removed only if no process holds its lock and (same host) its writer
    is not alive. A leftover of an older holofit, which did not lock, is removed once it is
    :data:`LEGACY_STALE_AFTER_S` old. Anything in doubt (a file system without locks) is kept.

    Returns
    -------
    list of Path
        The files removed.
    """
    path = Path(path)
    pattern = _temporary_re(path.name)
    removed: list[Path] = []
    try:
        entries = list(os.scandir(path.parent))
    except FileNotFoundError:
        return removed
    for entry in entries:
        match = pattern.match(entry.name)
        if match is None or not entry.is_file(follow_symlinks=False):
            continue
        try:
            fd = os.open(entry.path, os.O_RDONLY)
        except OSError:
            continue
        try:
            try:
                if not _lock(fd):
                    continue  # a live writer holds it
            except OSError:
                continue  # no locks on this file system: cannot tell, keep it
            info = os.fstat(fd)
            if match["pid"] is None:
                if time.time() - info.st_mtime < LEGACY_STALE_AFTER_S:
                    continue
            elif match["host"] == _host() and _pid_alive(int(match["pid"])):
                continue
            with contextlib.suppress(FileNotFoundError):
                if os.stat(entry.path, follow_symlinks=False).st_ino == info.st_ino:
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
        finally:
            os.close(fd)
    return removed


def create_temporary(path: str | Path) -> tuple[Path, int]:
    """A new, locked temporary file beside ``path`` (after removing stale ones).

    The file is created under a name no cleaner looks at, locked, and only then renamed to its
    temporary name, so a cleaner never sees it unlocked while its writer lives.

    Returns
    -------
    tmp : Path
        The temporary file (empty, mode 0600).
    fd : int
        An open descriptor that holds the lock: keep it open while writing, close it after
        :func:`publish` or after deleting the file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path)
    fd, creating = tempfile.mkstemp(prefix=f".{path.name}.new-", suffix=".tmp", dir=path.parent)
    try:
        with contextlib.suppress(OSError):  # without locks: name and pid still protect it
            _lock(fd)
        random = Path(creating).name.removeprefix(f".{path.name}.new-").removesuffix(".tmp")
        tmp = path.parent / f".{path.name}.holofit-{_host()}-{os.getpid()}-{random}.part"
        os.rename(creating, tmp)
    except BaseException:
        os.close(fd)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(creating)
        raise
    return tmp, fd


def publish(tmp: Path, path: Path) -> None:
    """Give a finished temporary file the usual permissions and rename it to ``path``."""
    os.chmod(tmp, FILE_MODE)
    os.replace(tmp, path)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the target's directory; rename it to ``path`` on success.

    On an exception the temporary file is removed and ``path`` is left untouched; if the
    process is killed, the next writer of ``path`` removes it (:func:`remove_stale_temporaries`).
    """
    path = Path(path)
    tmp_path, fd = create_temporary(path)
    try:
        yield tmp_path
        publish(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise
    finally:
        os.close(fd)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
