"""Dask's cost and gain for stancal's many-fit commands (issue 16).

    python benchmarks/cluster.py [--repeats 2]

- Per-task overhead: N tasks that do nothing, on the local cluster (one
  worker per core) against the same tasks in-process; and the cluster's
  start and stop.
- Speed-up: the cooling gap diagnosis (tests' settings: 2 x (400 + 700)) in
  one process against the local cluster, alternated in this process so that
  both see the same machine load; and SBC with one chain per fit (koh
  with a GP discrepancy, 40 simulations), where a fit leaves cores idle.

    python benchmarks/cluster.py --parts sbc   # one part; the others' figures are kept

Writes benchmarks/cluster.json and prints the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stancal.diagnosing.gap import diagnose_gap  # noqa: E402
from stancal.fitting.cluster import IN_PROCESS, FitRunner, FitTask  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402

SAMPLING = {"chains": 2, "warmup": 400, "draws": 700, "seed": 3}


def nothing(i: int) -> int:
    return i


def task_overhead(tasks: int) -> dict[str, float]:
    batch = [FitTask(f"task {i}", nothing, {"i": i}) for i in range(tasks)]
    started = time.perf_counter()
    with FitRunner(progress=False) as runner:
        ready = time.perf_counter()
        runner.map(batch)
        mapped = time.perf_counter()
    stopped = time.perf_counter()
    with FitRunner(IN_PROCESS, progress=False) as runner:
        here = time.perf_counter()
        runner.map(batch)
        here = time.perf_counter() - here
    return {"tasks": tasks, "workers": os.cpu_count(), "start_s": ready - started, "stop_s": stopped - mapped,
            "per_task_ms": 1000 * (mapped - ready) / tasks, "per_task_in_process_ms": 1000 * here / tasks}


def gap_seconds(scheduler: str | None) -> float:
    problem = load_config(ROOT / "case_studies" / "cooling" / "config.toml")
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        diagnose_gap(problem.data, problem.candidates, simulator=problem.simulator, scheduler=scheduler,
                     **SAMPLING)
    return time.perf_counter() - started


def sbc_seconds(scheduler: str | None, simulations: int = 40) -> float:
    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import cooling_data

    from stancal.diagnosing.sbc import simulation_based_calibration

    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        simulation_based_calibration(cooling_data(seed=7),
                                     simulator=ROOT / "case_studies" / "cooling" / "simulator.stan",
                                     method="koh", discrepancy="gp", simulations=simulations, draws_per_fit=100,
                                     chains=1, seed=1, scheduler=scheduler)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--tasks", type=int, default=200)
    parser.add_argument("--parts", nargs="+", default=["overhead", "gap", "sbc"], choices=["overhead", "gap", "sbc"])
    args = parser.parse_args()
    path = Path(__file__).parent / "cluster.json"
    figures = json.loads(path.read_text()) if path.is_file() else {}
    if "overhead" in args.parts:
        figures["overhead"] = task_overhead(args.tasks)
    for part, key, run in (("gap", "cooling_gap", gap_seconds), ("sbc", "sbc_one_chain", sbc_seconds)):
        if part in args.parts:
            times: dict[str, list[float]] = {"in_process_s": [], "local_cluster_s": []}
            for _ in range(args.repeats):  # alternated: both see the same load
                times["in_process_s"].append(run(IN_PROCESS))
                times["local_cluster_s"].append(run(None))
            figures[key] = {**times, "speed_up": sum(times["in_process_s"]) / sum(times["local_cluster_s"])}
    path.write_text(json.dumps(figures, indent=2))
    o, g = figures["overhead"], figures["cooling_gap"]
    print(f"local cluster of {o['workers']} workers: start {o['start_s']:.1f} s, stop {o['stop_s']:.1f} s; "
          f"{o['per_task_ms']:.1f} ms per task (in-process {o['per_task_in_process_ms']:.3f} ms)")
    print(f"cooling gap: in-process {g['in_process_s']} s, local cluster {g['local_cluster_s']} s; "
          f"speed-up {g['speed_up']:.2f}")
    b = figures["sbc_one_chain"]
    print(f"SBC, one chain per fit: in-process {b['in_process_s']} s, local cluster {b['local_cluster_s']} s; "
          f"speed-up {b['speed_up']:.2f}")


if __name__ == "__main__":
    main()
