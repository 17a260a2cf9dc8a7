"""Frame functions for the batch-runner tests (module level, so worker processes can import
them)."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

COLUMNS = ("frame", "status", "message", "a", "b", "c", "threads", "fit_time_s")


@dataclass(frozen=True)
class ToyConfig:
    """What the toy frame function does for which frames."""

    fail_frames: tuple[int, ...] = ()
    nonconverged_frames: tuple[int, ...] = ()
    crash_frames: tuple[int, ...] = ()
    log_dir: str | None = None
    sleep_s: float = 0.0


def toy_payload(frame: int) -> np.ndarray:
    """Noisy samples of a quadratic whose coefficients depend on the frame."""
    rng = np.random.default_rng(frame)
    t = np.linspace(-1, 1, 50)
    return np.stack([t, 1.0 + 0.1 * frame + 2.0 * t - 0.5 * t**2 + rng.normal(0, 0.01, t.size)])


def toy_frame(config: ToyConfig, frame: int, payload: np.ndarray) -> dict:
    """Fit a quadratic (nonlinear least squares, so results depend on floating point)."""
    if config.log_dir is not None:
        with open(Path(config.log_dir) / f"{os.getpid()}.log", "a") as fh:
            fh.write(f"{frame}\n")
    if config.sleep_s:
        time.sleep(config.sleep_s)
    if frame in config.crash_frames:
        os._exit(3)  # a worker dying without a Python exception
    if frame in config.fail_frames:
        raise ValueError(f"bad data in frame {frame}")
    t, y = payload
    sol = least_squares(lambda p: p[0] + p[1] * t + p[2] * t**2 - y, np.zeros(3), method="lm")
    converged = frame not in config.nonconverged_frames
    return {
        "status": "ok" if converged else "not_converged",
        "message": "" if converged else "toy: pretend the fit ran out of iterations",
        "a": sol.x[0],
        "b": sol.x[1],
        "c": sol.x[2],
        "threads": os.environ.get("OMP_NUM_THREADS", "unset"),
    }


def calls(log_dir: str | Path) -> list[int]:
    """Frames the toy function was called for (all processes)."""
    out: list[int] = []
    for p in Path(log_dir).glob("*.log"):
        out += [int(v) for v in p.read_text().split()]
    return sorted(out)


def run_toy_batch(out: str, workers: int, n_frames: int, sleep_s: float) -> None:
    """A toy batch of slow frames (what the kill and lock tests run in a child process)."""
    from holofit.batch import BatchSettings, run_batch

    summary = run_batch(
        toy_frame, ToyConfig(sleep_s=sleep_s), range(n_frames), toy_payload,
        toy_table(out, desc="toy"), options=BatchSettings(workers=workers, progress=False),
    )
    for note in summary.notes:
        print("note:", note, flush=True)


#: columns of the toy table keyed by (particle, frame)
PAIR_COLUMNS = ("particle", "frame", "status", "message", "value", "fit_time_s")


def pair_item(config: ToyConfig, key: tuple[int, int], payload: float) -> dict:
    """An item keyed by (particle, frame): its value is the payload; errors as configured
    (``fail_frames`` holds the frames that fail for particle 1)."""
    particle, frame = key
    if config.log_dir is not None:
        with open(Path(config.log_dir) / f"{os.getpid()}.log", "a") as fh:
            fh.write(f"{particle},{frame}\n")
    if particle == 1 and frame in config.fail_frames:
        raise ValueError(f"bad item {key}")
    return {"status": "ok", "message": "", "value": payload}


def toy_table(out: str | Path, columns=COLUMNS, fingerprint: str = "toy", **fields):
    """The :class:`~holofit.batch.layout.StageTable` of a toy batch into ``out`` (meta empty
    and desc ``"batch"`` unless given)."""
    from holofit.batch import StageTable

    fields.setdefault("meta", {})
    fields.setdefault("desc", "batch")
    return StageTable(Path(out), tuple(columns), fingerprint=fingerprint, **fields)


#: columns of the worker-resource toy table
RESOURCE_COLUMNS = ("frame", "status", "message", "pid", "made", "resource", "fit_time_s")


def resource_frame(config: dict, frame: int, payload: object) -> dict:
    """A frame function that takes a per-worker resource (:func:`holofit.batch.worker_resource`)
    and says which process made it and how many times."""
    from holofit.batch.worker import worker_resource, worker_resource_kinds

    value = worker_resource("toy resource", config["key"], lambda: f"made in {os.getpid()}")
    return {"status": "ok", "message": "", "pid": os.getpid(), "resource": value,
            "made": worker_resource_kinds()["toy resource"][config["key"]]}
