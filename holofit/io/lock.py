"""One writer per output folder: a lock file that names its holder.

A stage that writes into a folder (``holofit crop``, ``prefit``, ``fit``) holds
``<folder>/.holofit.lock`` while it runs::

    with output_lock(out_dir, stage="prefit") as lock:
        ...                        # write the folder's files
    if lock.note:                  # an earlier holder was killed and left its lock file
        print(lock.note)

A second run into the same folder is refused at once with :class:`OutputLocked`, whose
message names the folder and the holder (stage, pid, host, command, start time), instead of
fitting everything a second time and racing the first run for the same files.

Mechanism: an advisory ``flock`` on the lock file. The kernel releases it when its process
ends, however it ends, so a file left behind by a run killed with SIGKILL is harmless: the
next run takes the lock, reads the dead holder's description from the file and reports the
take-over in :attr:`OutputLock.note`. On a clean exit the file is removed. On Linux, ``flock``
on NFS is carried out with NFS byte-range locks, so runs on different hosts sharing a folder
exclude each other too; a file system that supports no locks at all gives a run without a
lock and a note saying so, rather than no run.

Nested locks of the same folder in one process are allowed (a stage that holds the folder
lock may call the batch runner, which takes it again).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shlex
import socket
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None  # type: ignore[assignment]

__all__ = ["LOCK_NAME", "LockHolder", "OutputLock", "OutputLocked", "output_lock"]

#: name of the lock file inside the output folder
LOCK_NAME = ".holofit.lock"

#: errors of a file system that offers no locks (the run goes on unlocked, with a note)
_NO_LOCKS = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or held) a folder's lock.

    Attributes
    ----------
    stage : str
        The stage writing the folder (``prefit``, ``crop``, ...).
    pid : int
        Its process id.
    host : str
        The host it runs on.
    command : str
        Its command line.
    started : str
        When it took the lock (local time, ISO 8601).
    """

    stage: str
    pid: int
    host: str
    command: str
    started: str

    @classmethod
    def this_process(cls, stage: str) -> LockHolder:
        return cls(
            stage=stage,
            pid=os.getpid(),
            host=socket.gethostname(),
            command=shlex.join(sys.argv) if sys.argv and sys.argv[0] else sys.executable,
            started=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        )

    @classmethod
    def parse(cls, text: str) -> LockHolder | None:
        """The holder described by a lock file's text (None if empty or unreadable)."""
        try:
            doc = json.loads(text)
            return cls(
                str(doc["stage"]), int(doc["pid"]), str(doc["host"]), str(doc["command"]),
                str(doc["started"]),
            )
        except (ValueError, KeyError, TypeError):
            return None

    def describe(self) -> str:
        return (
            f"{self.stage}, pid {self.pid} on {self.host}, started {self.started}: "
            f"{self.command}"
        )


class OutputLocked(RuntimeError):
    """Another run is writing into the output folder.

    Attributes
    ----------
    folder : Path
        The folder.
    holder : LockHolder or None
        Who holds its lock (None if the lock file could not be read).
    """

    def __init__(self, folder: Path, holder: LockHolder | None) -> None:
        who = holder.describe() if holder is not None else "holder unknown"
        super().__init__(
            f"{folder}: another holofit run is writing into this folder ({who}); wait for it "
            f"to finish or choose another output folder (lock file {folder / LOCK_NAME})"
        )
        self.folder = folder
        self.holder = holder


@dataclass
class OutputLock:
    """A held folder lock (what :func:`output_lock` yields).

    Attributes
    ----------
    folder : Path
        The locked folder.
    holder : LockHolder
        This process's description, as written in the lock file.
    previous : LockHolder or None
        The holder of a lock file left behind by a run that ended without releasing it
        (killed): its lock was taken over.
    locked : bool
        False if the file system supports no locks (the run goes on unprotected).
    """

    folder: Path
    holder: LockHolder
    previous: LockHolder | None = None
    locked: bool = True

    @property
    def path(self) -> Path:
        return self.folder / LOCK_NAME

    @property
    def note(self) -> str | None:
        """What the user should know about this lock, if anything."""
        if not self.locked:
            return (
                f"{self.folder}: the file system supports no file locks, so nothing stops a "
                "second run from writing into this folder at the same time"
            )
        if self.previous is not None:
            return (
                f"{self.folder}: took over the lock left by a run that is no longer running "
                f"({self.previous.describe()})"
            )
        return None


#: folders locked by this process -> [lock, open file descriptor, nesting depth]
_HELD: dict[Path, list] = {}


def _read(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    chunks = []
    while chunk := os.read(fd, 65536):
        chunks.append(chunk)
    return b"".join(chunks).decode("utf-8", "replace")


def _holder_of(path: Path) -> LockHolder | None:
    # the holder writes its description right after taking the lock: allow it a moment
    for attempt in range(5):
        try:
            holder = LockHolder.parse(path.read_text(encoding="utf-8", errors="replace"))
        except OSError:
            holder = None
        if holder is not None:
            return holder
        time.sleep(0.02 * (attempt + 1))
    return None


def _acquire(folder: Path, holder: LockHolder) -> tuple[OutputLock, int | None]:
    path = folder / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            if fcntl is None:  # pragma: no cover - not POSIX
                raise OSError(errno.ENOSYS, "no fcntl")
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise OutputLocked(folder, _holder_of(path)) from None
        except OSError as exc:
            os.close(fd)
            if exc.errno in _NO_LOCKS:
                return OutputLock(folder, holder, locked=False), None
            raise
        # the holder before us may have removed the file between our open and our flock:
        # then we locked an orphan inode, and must lock the file that is there now
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            continue
        previous = LockHolder.parse(_read(fd)) if os.fstat(fd).st_size else None
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, (json.dumps(asdict(holder), indent=1) + "\n").encode())
        os.fsync(fd)
        return OutputLock(folder, holder, previous), fd


def _release(lock: OutputLock, fd: int | None) -> None:
    if fd is None:
        return
    # remove the file while still holding the lock (a waiting run then finds it gone and
    # creates a new one, see _acquire), then release by closing
    with contextlib.suppress(FileNotFoundError):
        lock.path.unlink()
    os.close(fd)


@contextlib.contextmanager
def output_lock(folder: str | Path, stage: str) -> Iterator[OutputLock]:
    """Hold the write lock of ``folder`` (created if needed) inside the block.

    Parameters
    ----------
    folder : str or Path
        The output folder.
    stage : str
        What is writing (``prefit``, ``crop``, ...), recorded for a refused second run.

    Yields
    ------
    OutputLock
        Its :attr:`~OutputLock.note` says whether a dead run's lock was taken over.

    Raises
    ------
    OutputLocked
        If another process holds the lock; the message names the folder and the holder.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    key = folder.resolve()
    held = _HELD.get(key)
    if held is not None:  # nested in this process
        held[2] += 1
        try:
            yield held[0]
        finally:
            held[2] -= 1
        return
    lock, fd = _acquire(folder, LockHolder.this_process(stage))
    _HELD[key] = [lock, fd, 1]
    try:
        yield lock
    finally:
        del _HELD[key]
        _release(lock, fd)
