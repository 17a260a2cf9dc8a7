"""Where the frames run: in this process, in a local process pool, or on a Dask cluster.

All three offer the same three operations to the runner (submit a call, wait for the first
results, shut down), so the runner's bookkeeping (journal, table, progress, failures) is one
piece of code whatever the backend.

- :class:`SerialBackend`: in the calling process, one frame at a time (debugging, and the
  one-core benchmark).
- :class:`ProcessPoolBackend`: ``concurrent.futures.ProcessPoolExecutor`` with freshly spawned
  worker processes, each single-threaded (:mod:`holofit.batch.threads`).
- :class:`DaskBackend`: ``distributed.Client`` connected to a running scheduler
  (``tcp://host:8786``, e.g. started by dask-jobqueue on SLURM) or to a
  ``LocalCluster`` of single-threaded worker processes on the loopback interface.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import os
import signal
import socket
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from holofit.batch.errors import BatchError, SchedulerError, WorkerLost
from holofit.batch.lifeline import die_with_parent
from holofit.batch.mainguard import main_hidden_from_workers
from holofit.batch.threads import (
    limit_threads_in_this_process,
    single_thread_environment,
    single_thread_variables,
)

__all__ = [
    "Backend",
    "DaskBackend",
    "ProcessPoolBackend",
    "SerialBackend",
    "WorkerLost",
]

#: seconds allowed to reach a Dask scheduler before giving up with a message
CONNECT_TIMEOUT_S = 10.0
#: further seconds allowed for the scheduler's handshake once connected
HANDSHAKE_GRACE_S = 2.0


class Backend:
    """Interface of a backend (see the module docstring)."""

    #: how many calls can run at the same time
    slots: int = 1
    name: str = ""
    #: True if a dying worker takes only the calls it held down (Dask: the scheduler reruns
    #: or fails just those; the worker is replaced by its nanny); False if it breaks every
    #: call in flight and the backend must be restarted (a process pool)
    isolates_lost_workers: bool = True

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:  # pragma: no cover
        raise NotImplementedError

    def wait(self, futures: Iterable[Any], timeout: float) -> set[Any]:  # pragma: no cover
        """The futures among ``futures`` that are done (waits up to ``timeout`` s for one)."""
        raise NotImplementedError

    def result(self, future: Any) -> Any:
        """The value of a done future; :class:`WorkerLost` if its worker died."""
        return future.result()

    def restart(self) -> None:
        """Replace broken workers (after :class:`WorkerLost`)."""

    def close(self) -> None:
        """Stop the workers."""

    def describe(self) -> dict[str, Any]:
        return {"backend": self.name, "workers": self.slots}

    def __enter__(self) -> Backend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SerialBackend(Backend):
    """Run every call at once in this process."""

    name = "serial"
    slots = 1

    def submit(self, fn: Callable[..., Any], *args: Any) -> cf.Future:
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(*args))
        except BaseException as exc:  # the runner decides what an error means
            fut.set_exception(exc)
        return fut

    def wait(self, futures: Iterable[Any], timeout: float) -> set[Any]:
        return {f for f in futures if f.done()}


def _pool_worker_init(parent_pid: int) -> None:
    # a worker whose driver is killed must not live on (holofit.batch.lifeline)
    die_with_parent(parent_pid)
    # Ctrl-C goes to the whole process group: let the parent shut the pool down cleanly.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_threads_in_this_process()


class ProcessPoolBackend(Backend):
    """Local pool of ``workers`` spawned, single-threaded processes.

    Processes are started with the ``spawn`` method (a clean interpreter: no inherited
    threads or locks) while the single-thread environment is set, so their BLAS and numba
    pools have one thread, and without running the parent's ``__main__`` script again
    (:mod:`holofit.batch.mainguard`: a script that calls the stages without
    ``if __name__ == "__main__":`` works as pasted). They end when this process ends, even
    by SIGKILL (:mod:`holofit.batch.lifeline`).
    """

    name = "processes"
    isolates_lost_workers = False

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.slots = workers
        self._pool = self._new_pool()

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(
            max_workers=self.slots,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_pool_worker_init,
            initargs=(os.getpid(),),
        )

    def submit(self, fn: Callable[..., Any], *args: Any) -> cf.Future:
        # workers start lazily on submit: keep the environment single-threaded and the
        # user's script out of their reach meanwhile
        with single_thread_environment(), main_hidden_from_workers((fn, *args)):
            return self._pool.submit(fn, *args)

    def wait(self, futures: Iterable[Any], timeout: float) -> set[Any]:
        done, _ = cf.wait(list(futures), timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return set(done)

    def result(self, future: cf.Future) -> Any:
        try:
            return future.result()
        except cf.process.BrokenProcessPool as exc:
            raise WorkerLost(f"a worker process died ({exc})") from None

    def restart(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = self._new_pool()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class DaskBackend(Backend):
    """Frames as tasks of a Dask distributed cluster.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://10.0.0.5:8786``) or a path to a scheduler
        file. If not given, a ``LocalCluster`` of ``workers`` single-threaded worker processes
        listening on 127.0.0.1 only is started (and stopped by :meth:`close`).
    workers : int
        Workers of the local cluster.
    connect_timeout_s : float
        Seconds allowed to reach a running scheduler.

    Raises
    ------
    SchedulerError
        If the scheduler file does not exist or names no address, or no scheduler answers at
        the address within ``connect_timeout_s`` (a refused connection fails at once).
    """

    name = "dask"

    def __init__(
        self,
        scheduler: str | None = None,
        workers: int = 2,
        connect_timeout_s: float = CONNECT_TIMEOUT_S,
    ) -> None:
        try:
            import distributed
        except ModuleNotFoundError:  # pragma: no cover - depends on the installation
            raise BatchError(
                "the Dask backend needs dask and distributed: pip install 'holofit[cluster]'"
            ) from None
        self._distributed = distributed
        self._cluster = None
        if scheduler is None:
            if workers < 1:
                raise ValueError(f"workers must be >= 1, got {workers}")
            self._cluster = distributed.LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                env=single_thread_variables(),
            )
            self.client = distributed.Client(self._cluster)
            self.address = self._cluster.scheduler_address
        else:
            self.address = scheduler
            self.client = _connect(distributed, scheduler, connect_timeout_s)
        self.client.run(limit_threads_in_this_process)
        self.slots = max(sum(self.client.nthreads().values()), 1)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self.client.submit(fn, *args, pure=False)

    def wait(self, futures: Iterable[Any], timeout: float) -> set[Any]:
        futures = list(futures)
        try:
            done, _ = self._distributed.wait(
                futures, timeout=timeout, return_when="FIRST_COMPLETED"
            )
        except TimeoutError:  # builtin since Python 3.11 (asyncio's is the same class)
            return set()
        return set(done)

    def result(self, future: Any) -> Any:
        try:
            return future.result()
        except self._distributed.KilledWorker as exc:
            raise WorkerLost(f"Dask workers died running this frame ({exc})") from None

    def describe(self) -> dict[str, Any]:
        return {
            "backend": "dask",
            "workers": self.slots,
            "scheduler": self.address if self._cluster is None else "local cluster",
        }

    def close(self) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def _is_scheduler_file(scheduler: str) -> bool:
    return scheduler.endswith(".json") or Path(scheduler).is_file()


def scheduler_address(scheduler: str) -> str:
    """The address of a scheduler given as an address or as a scheduler file.

    ``distributed.Client(scheduler_file=...)`` waits for a missing file to appear, without a
    time limit or a word; a scheduler file is read here instead.

    Raises
    ------
    SchedulerError
        If the file does not exist, is not JSON, or has no ``address`` entry.
    """
    if not _is_scheduler_file(scheduler):
        return scheduler
    path = Path(scheduler)
    advice = (
        "give the file a running scheduler writes (dask scheduler --scheduler-file PATH; a "
        "queued scheduler job writes it when it starts) or the scheduler's address "
        "(tcp://HOST:8786)"
    )
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise SchedulerError(f"{path}: Dask scheduler file not found; {advice}") from None
    except (OSError, ValueError) as exc:
        raise SchedulerError(f"{path}: not a readable Dask scheduler file ({exc})") from None
    address = doc.get("address") if isinstance(doc, dict) else None
    if not isinstance(address, str) or not address:
        raise SchedulerError(f"{path}: not a Dask scheduler file (it has no 'address' entry)")
    return address


def _unreachable(scheduler: str, address: str, why: str) -> SchedulerError:
    where = address if address == scheduler else f"{address} (from {scheduler})"
    return SchedulerError(
        f"cannot reach the Dask scheduler at {where}: {why}; is the scheduler running, and is "
        "the address right?"
    )


def _probe(scheduler: str, address: str, timeout_s: float) -> None:
    """Fail at once on a refused connection (``Client`` would retry until its timeout)."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
    except ValueError as exc:
        raise _unreachable(scheduler, address, f"not an address ({exc})") from None
    if scheme not in ("tcp", "tls"):
        return
    try:
        host, port = parse_host_port(location, 8786)
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except TimeoutError:
        raise _unreachable(scheduler, address, f"no answer within {timeout_s:g} s") from None
    except OSError as exc:
        raise _unreachable(scheduler, address, exc.strerror or str(exc)) from None
    except ValueError as exc:  # a malformed host or port (a ValueError has no strerror)
        raise _unreachable(scheduler, address, str(exc)) from None


def _connect(distributed: Any, scheduler: str, timeout_s: float) -> Any:
    """A ``Client`` of the scheduler, or :class:`SchedulerError` within about ``timeout_s``.

    ``Client(timeout=...)`` bounds the TCP connection but not the handshake that follows, so
    a peer that accepts and then says nothing would hold it forever: the client is made in a
    helper thread that is abandoned (daemon) if it has not finished in time.
    """
    address = scheduler_address(scheduler)
    _probe(scheduler, address, timeout_s)
    outcome: dict[str, Any] = {}

    def make() -> None:
        try:
            outcome["client"] = distributed.Client(address, timeout=timeout_s)
        except Exception as exc:
            outcome["error"] = exc

    helper = threading.Thread(target=make, name="holofit-dask-connect", daemon=True)
    helper.start()
    helper.join(timeout_s + HANDSHAKE_GRACE_S)
    if "client" in outcome:
        return outcome["client"]
    exc = outcome.get("error")
    if exc is None:
        why = f"no Dask handshake within {timeout_s + HANDSHAKE_GRACE_S:g} s"
    elif isinstance(exc, OSError | TimeoutError):
        why = str(exc)
    else:  # something answers, but not as a Dask scheduler does
        why = f"what answers is not a Dask scheduler ({type(exc).__name__}: {exc})"
    raise _unreachable(scheduler, address, why)
