"""The whole pipeline on one rod and on three rods in one field of view (issue target:
``pipeline_three_rods_over_one_rod <= 3.3``: the cost grows linearly with the particles; see
pipeline_cases.py). Each case runs in its own process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _run(n_rods: int, frames: int = 12) -> dict[str, float]:
    out = subprocess.run([sys.executable, str(HERE / "pipeline_cases.py"), str(n_rods),
                          "--frames", str(frames)], check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_pipeline() -> dict[str, float]:
    results = {**_run(1), **_run(3)}
    results["pipeline_three_rods_over_one_rod"] = (results["pipeline_three_rods_s"]
                                                   / results["pipeline_one_rod_s"])
    return results


BENCHMARKS = {"pipeline": bench_pipeline}
