"""The cluster engine (superposition T-matrix; issue targets: cluster_tmatrix_build_dimer_s
<= 1, dda_dimer_orientation_cluster_s <= 0.01, fit_dimer_crop_cluster_s <= 2).

Each case runs in its own process (see cluster_cases.py). The real-data comparison with the
DDA (``realdata``, ``realdata_dda``; minutes) is run by ``python bench/cluster_cases.py
realdata_dda``, not by ``make bench``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _run(case: str) -> dict[str, float]:
    out = subprocess.run([sys.executable, str(HERE / "cluster_cases.py"), case], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_cluster() -> dict[str, float]:
    results: dict[str, float] = {}
    for case in ("build", "orientation", "fit", "fit_ideal", "realdata"):
        results.update(_run(case))
    return results


BENCHMARKS = {"cluster": bench_cluster}
