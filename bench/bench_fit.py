"""The library and the DDA fit per frame (issue targets: library_rod_frame_s <= 1,
fit_rod_frame_initial_s <= 10), and the tracking final pass along a 200-frame track
(``fit_track``: ``fit_rod_frame_final_s`` and ``fit_janus_frame_final_s`` <= 0.1,
``fit_<p>_evals_per_frame`` <= 20; see track_cases.py).

Each particle runs in its own process (see fit_cases.py, track_cases.py). The single-frame
cases' own final-pass time is ``fit_<p>_frame_final_s`` of fit_cases.py, which the tracking
group (run after it) reports per frame along the track instead.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _run(case: str, script: str = "fit_cases.py") -> dict[str, float]:
    out = subprocess.run([sys.executable, str(HERE / script), case], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_fit() -> dict[str, float]:
    results: dict[str, float] = {}
    for case in ("rod", "rod_ideal", "janus"):
        results.update(_run(case))
    return results


def bench_fit_track() -> dict[str, float]:
    results: dict[str, float] = {}
    for case in ("rod", "janus"):
        results.update(_run(case, "track_cases.py"))
    return results


BENCHMARKS = {"fit": bench_fit, "fit_track": bench_fit_track}
