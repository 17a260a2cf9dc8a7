"""T-matrix of the paper's rod and Janus particle: the build of the engine ``auto`` gives them
(the exact T-matrix: ``tmatrix_build_rod_s``, ``tmatrix_build_janus_s``, and a fit's rebuild of
a new size, ``tmatrix_rebuild_*``), the DDA's build cost and memory (``dda_tmatrix_build_*``;
the Janus particle also at the paper's 24 nm dipoles; its default is 24.09 nm), a new
orientation from a loaded DDA T-matrix, and the break-even against direct (warm-started)
solves.

Each case runs in its own process (see tmatrix_cases.py); the builds' files feed the
orientation cases through a temporary folder.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _run(case: str, folder: str) -> dict[str, float]:
    out = subprocess.run([sys.executable, str(HERE / "tmatrix_cases.py"), case, folder],
                         check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _break_even(results: dict[str, float], name: str) -> dict[str, float]:
    """Orientations after which the build has paid for itself: against direct solves of new
    orientations and of small rotations (warm-started, a fit's Jacobian steps), in wall time
    and in CPU time (the same on an idle core; CPU time is robust to a shared machine)."""
    out = {}
    for clock in ("", "_cpu"):
        build = results[f"dda_tmatrix_build_{name}{clock}_s"]
        t_mat = results[f"dda_{name}_orientation_tmatrix{clock}_s"]
        for kind, tag in (("orientation", "new"), ("small_rotation", "warm")):
            saved = results[f"dda_{name}_{kind}_direct{clock}_s"] - t_mat
            key = f"tmatrix_{name}_breakeven_{tag}{clock}_solves"
            out[key] = build / saved if saved > 0 else float("inf")
    return out


def bench_tmatrix() -> dict[str, float]:
    results: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as folder:
        for case in ("rod_auto_build", "janus_auto_build", "rod_build", "rod_orientation",
                     "janus_build", "janus_orientation", "janus_build_d24nm"):
            results.update(_run(case, folder))
    for name in ("rod", "janus"):
        results.update(_break_even(results, name))
    return results


BENCHMARKS = {"tmatrix": bench_tmatrix}
