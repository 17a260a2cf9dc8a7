"""Built-in DDA engine: first solves, cached interactions, warm starts, position updates, memory,
and the matrix-vector product itself next to ADDA's (``dda_matvec_*``, ``adda_matvec_*``).

Each case runs in its own process (see dda_cases.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _run(case: str) -> dict[str, float]:
    out = subprocess.run([sys.executable, str(HERE / "dda_cases.py"), case], check=True,
                         capture_output=True, text=True)
    for line in out.stderr.splitlines():  # skip reasons and notes of the case
        if line.startswith("    "):
            print(line)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_dda() -> dict[str, float]:
    results: dict[str, float] = {}
    for case in ("rod", "janus", "janus_tilted", "sphere92k", "matvec", "solve", "precision"):
        results.update(_run(case))
    return results


BENCHMARKS = {"dda": bench_dda}
