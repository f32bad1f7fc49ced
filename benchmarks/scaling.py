"""Wall time of a calibration against problem size, exact path against the
scalable one (issue: thousands of points and runs).

    .venv/bin/python benchmarks/scaling.py [--sizes 100 250 500 1000 2000 5000] [--out benchmarks/scaling]

For each size n = N (n physical points and N runs drawn from the sensor-log
case study) it times `modular` with approximation = "exact" (dense GPs) and
"hsgp" (the scalable programs), 4 chains x (500 + 500) draws, programs
compiled before the clock starts, each fit in its own process. The exact
path stops at the first size that takes more than 10 minutes (100 is there
so that it has a slope at all). It fits the log-log slope of time against n
for each path, prints a table, and writes scaling.json, scaling.png and the
peak resident memory of the whole process tree (PyStan samples in child
processes) for each fit.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np

import stancal
from stancal.backends import get_backend
from stancal.calibrate import choose_method, stan_programs
from stancal.config import load_config
from stancal.models import ModelOptions

ROOT = Path(__file__).resolve().parent.parent
EXACT_LIMIT_S = 600.0


class PeakMemory:
    """Peak of the summed resident memory of this process and its
    descendants, polled every 0.2 s from /proc."""

    def __init__(self) -> None:
        self.peak = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)

    @staticmethod
    def _tree_rss(root: int) -> int:
        children: dict[int, list[int]] = {}
        rss: dict[int, int] = {}
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                status = Path(f"/proc/{entry}/status").read_text()
            except OSError:
                continue
            fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
            pid, ppid = int(entry), int(fields["PPid"])
            children.setdefault(ppid, []).append(pid)
            rss[pid] = int(fields.get("VmRSS", "0 kB").split()[0]) * 1024
        total, stack = 0, [root]
        while stack:
            pid = stack.pop()
            total += rss.get(pid, 0)
            stack.extend(children.get(pid, []))
        return total

    def _poll(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self._tree_rss(os.getpid()))
            time.sleep(0.2)

    def __enter__(self) -> "PeakMemory":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def problem(size: int, seed: int = 0) -> stancal.CalibrationData:
    full = load_config(ROOT / "case_studies" / "sensor_log" / "config.toml").data
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(len(full.physical), size, replace=False))
    runs = full.runs.iloc[np.sort(rng.choice(len(full.runs), size, replace=False))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stancal.InputRangeWarning)
        return stancal.CalibrationData(full.physical.iloc[rows], full.inputs, full.output,
                                       {p.name: (p.lower, p.upper) for p in full.parameters}, runs=runs)


def time_fit(data: stancal.CalibrationData, approximation: str) -> dict:
    options = ModelOptions(approximation=approximation)
    get_backend(None).compile(stan_programs(choose_method(data, None, "modular", options)))
    with PeakMemory() as memory:
        started = time.perf_counter()
        result = stancal.calibrate(data, method="modular", approximation=approximation, chains=4,
                                   warmup=500, draws=500, seed=1)
        seconds = time.perf_counter() - started
    theta = result.theta_summary()
    return {"seconds": seconds, "method": result.method, "peak_memory_gb": memory.peak / 1e9,
            "max_rhat": result.diagnostics.max_rhat, "divergences": result.diagnostics.divergences,
            "theta": {k: {"mean": v["mean"], "sd": v["sd"]} for k, v in theta.items()}}


def slope(rows: list[dict]) -> float | None:
    if len(rows) < 2:
        return None
    n = np.log([r["size"] for r in rows])
    t = np.log([r["seconds"] for r in rows])
    return float(np.polyfit(n, t, 1)[0])


def run_one(size: int, approximation: str) -> dict | None:
    """One fit in its own process, stopped at EXACT_LIMIT_S (a dense fit
    cannot be interrupted from inside): its row, or None when it ran out."""
    command = [sys.executable, __file__, "--one", str(size), approximation]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=EXACT_LIMIT_S + 60)
    except subprocess.TimeoutExpired:
        return None
    if done.returncode != 0:
        raise RuntimeError(f"{approximation} at n = N = {size} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 250, 500, 1000, 2000, 5000])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "scaling")
    parser.add_argument("--one", nargs=2, metavar=("SIZE", "APPROXIMATION"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if args.one:  # a child process: one fit, its row as JSON on the last line
        size, approximation = int(args.one[0]), args.one[1]
        print(json.dumps({"size": size, **time_fit(problem(size), approximation)}))
        return
    results: dict[str, list[dict]] = {"exact": [], "hsgp": []}
    for approximation in ("hsgp", "exact"):
        for size in args.sizes:
            row = run_one(size, approximation)
            if row is None or row["seconds"] > EXACT_LIMIT_S:
                print(f"{approximation}: n = N = {size} took more than {EXACT_LIMIT_S:.0f} s; larger sizes skipped")
                if row is None:
                    break
            results[approximation].append(row)
            print(f"{approximation:>6} n = N = {size:>5}: {row['seconds']:7.1f} s, peak memory "
                  f"{row['peak_memory_gb']:.2f} GB, R-hat {row['max_rhat']:.3f}, {row['divergences']} divergences",
                  flush=True)
            if row["seconds"] > EXACT_LIMIT_S:
                break
    for exact in results["exact"]:  # the same data on both paths: the approximation's error in theta
        scalable = next((r for r in results["hsgp"] if r["size"] == exact["size"]), None)
        for name, reference in exact["theta"].items() if scalable else ():
            approx = scalable["theta"][name]
            print(f"n = N = {exact['size']}, {name}: hsgp mean {(approx['mean'] - reference['mean']) / reference['sd']:+.2f} "
                  f"exact sd from the exact one, sd {approx['sd'] / reference['sd'] - 1:+.0%}")
    slopes = {k: slope(v) for k, v in results.items()}
    for k, v in slopes.items():
        print(f"log-log slope of wall time against n, {k}: {v:.2f}" if v is not None else f"{k}: one size only")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps({"fits": results, "slopes": slopes}, indent=2))
    plot(results, slopes, args.out.with_suffix(".png"))


def plot(results: dict[str, list[dict]], slopes: dict[str, float | None], path: Path) -> None:
    from stancal.plots import finish, pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for name, rows in results.items():
        if rows:
            label = f"{name} (slope {slopes[name]:.2f})" if slopes[name] is not None else name
            ax.loglog([r["size"] for r in rows], [r["seconds"] for r in rows], "o-", label=label)
    ax.axhline(EXACT_LIMIT_S, color="grey", linestyle=":", label="10 minutes")
    ax.set_xlabel("n = N (physical points = simulator runs)")
    ax.set_ylabel("wall time of modular, 4 x (500 + 500) [s]")
    ax.legend()
    finish(fig, path)


if __name__ == "__main__":
    main()
