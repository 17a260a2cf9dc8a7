"""The library and the DDA fit per frame (issue targets: library_rod_frame_s <= 1,
fit_rod_frame_final_s <= 2, fit_rod_frame_initial_s <= 10, fit_janus_frame_final_s <= 5).

Each particle runs in its own process (see fit_cases.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _run(case: str) -> dict[str, float]:
    out = subprocess.run([sys.executable, str(HERE / "fit_cases.py"), case], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_fit() -> dict[str, float]:
    results: dict[str, float] = {}
    for case in ("rod", "rod_ideal", "janus"):
        results.update(_run(case))
    return results


BENCHMARKS = {"fit": bench_fit}
