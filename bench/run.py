"""Run holofit's benchmarks and write a flat JSON map ``name -> number`` (unit in the name).

Usage: ``python bench/run.py [--out bench/results.json] [--only NAME ...]``. ``make bench``
runs it on one core (OMP/BLAS/numba threads = 1). Each ``bench_*.py`` module beside this file
exposes ``BENCHMARKS``: a dict of name -> callable returning a dict of results.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def discover() -> dict:
    benches = {}
    for path in sorted(HERE.glob("bench_*.py")):
        module = importlib.import_module(path.stem)
        benches.update(getattr(module, "BENCHMARKS", {}))
    return benches


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=HERE / "results.json")
    parser.add_argument("--only", nargs="*", default=None, help="benchmark groups to run")
    args = parser.parse_args()
    benches = discover()
    selected = args.only or list(benches)
    results: dict[str, float] = {}
    if args.out.exists() and args.only:
        results.update(json.loads(args.out.read_text()))
    for name in selected:
        t0 = time.perf_counter()
        print(f"[bench] {name} ...", flush=True)
        got = benches[name]()
        for key, value in got.items():
            print(f"    {key} = {value:.6g}", flush=True)
        results.update(got)
        print(f"    ({time.perf_counter() - t0:.1f} s)", flush=True)
    results["machine_cpu_count"] = float(len(__import__("os").sched_getaffinity(0)))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".json.part")
    tmp.write_text(json.dumps(dict(sorted(results.items())), indent=2) + "\n")
    tmp.replace(args.out)
    print(f"wrote {args.out} ({platform.processor() or platform.machine()})")


if __name__ == "__main__":
    main()
