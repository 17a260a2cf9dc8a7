"""Worker processes and the user's script: spawned workers must not run it again.

A process started with ``multiprocessing``'s ``spawn`` method (holofit's process pool, Dask's
local workers) first runs the parent's ``__main__`` script again, as ``__mp_main__``, so that
functions defined there can be unpickled. A script that calls holofit's stages at its top level,
without ``if __name__ == "__main__":``, would then start the whole pipeline again in every
worker (a second crop of the movie, a stage that finds its output folder locked, a worker that
dies at start), and a script fed through stdin (``python - < script.py``) names a ``<stdin>``
file the workers cannot find. Two defences:

- :func:`main_hidden_from_workers`: while holofit's pool starts workers, ``sys.modules
  ["__main__"]`` is a bare stand-in, so the workers have no script to run. Frame functions live
  in holofit's modules and need nothing from the script; a frame function or settings object
  defined in the script itself (a user's own :func:`holofit.batch.run_batch`) keeps the usual
  behaviour, since workers need the script to unpickle them.
- :func:`refuse_while_worker_starts`: a stage called while this process is itself a worker
  starting up (``multiprocessing`` marks that phase) ends the worker at once with one line
  saying what to do, instead of running the stage.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import sys
import types
from collections.abc import Iterable, Iterator
from typing import Any

__all__ = ["GUARD_ADVICE", "main_hidden_from_workers", "refuse_while_worker_starts",
           "worker_is_starting"]

#: what to do when a script without the guard is re-run by workers
GUARD_ADVICE = ('put the script\'s calls of holofit stages under `if __name__ == "__main__":` '
                "(README, 'Python use')")


def worker_is_starting() -> bool:
    """True while this process is a spawned worker re-running its parent's ``__main__``."""
    return bool(getattr(multiprocessing.current_process(), "_inheriting", False))


def refuse_while_worker_starts(stage: str) -> None:
    """End this process with a one-line message if it is a worker starting up.

    Parameters
    ----------
    stage : str
        The stage function called (named in the message).

    Raises
    ------
    SystemExit
        In a starting worker: its message goes to the worker's stderr without a traceback,
        and the worker ends (the parent records its frames as ``error``).
    """
    if worker_is_starting():
        raise SystemExit(
            f"holofit: {stage} was called again by a worker process while it started: the "
            f"script runs holofit stages at its top level, and every spawned worker runs the "
            f"script again; {GUARD_ADVICE}")


def _from_main(obj: Any) -> bool:
    module = getattr(obj, "__module__", None) if callable(obj) else type(obj).__module__
    return module in ("__main__", "__mp_main__")


@contextlib.contextmanager
def main_hidden_from_workers(objects: Iterable[Any] = ()) -> Iterator[None]:
    """Workers spawned inside this block do not run the parent's ``__main__`` again.

    Parameters
    ----------
    objects : iterable
        What the workers will be sent (the frame function, its settings): if any is defined
        in ``__main__``, the workers need the script, and nothing is hidden.
    """
    main = sys.modules.get("__main__")
    script = main is not None and (getattr(main, "__spec__", None) is not None
                                   or getattr(main, "__file__", None) is not None)
    if not script or any(_from_main(o) for o in objects):
        yield
        return
    assert main is not None  # a script implies a __main__ module
    # spawn's preparation data names the script by __main__'s __spec__ or __file__: a bare
    # module has neither, so the child runs no script
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main
