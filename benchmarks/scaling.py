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
from stancal.fitting.plan import plan_scalar
from stancal.problem.config import load_config
from stancal.problem.options import ModelOptions
from stancal.stan.backends import get_backend

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

    def __enter__(self) -> PeakMemory:
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
    get_backend(None).compile(plan_scalar(data, None, "modular", options).stan_programs())
    with PeakMemory() as memory:
        started = time.perf_counter()
        result = stancal.calibrate(data, method="modular", approximation=approximation, chains=4,
                                   warmup=500, draws=500, seed=1)
        seconds = time.perf_counter() - started
    theta = result.theta_summary()
    return {"seconds": seconds, "method": result.method, "peak_memory_gb": memory.peak / 1e9,
            "max_rhat": result.diagnostics.max_rhat, "divergences": result.diagnostics.divergences,
            "theta": {k: {"mean": v["mean"], "sd": v["sd"]} for k, v in theta.items()}}


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
    parser.add_argument("--replot", action="store_true", help="redraw the figure from --out's JSON")
    parser.add_argument("--one", nargs=2, metavar=("SIZE", "APPROXIMATION"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if args.one:  # a child process: one fit, its row as JSON on the last line
        size, approximation = int(args.one[0]), args.one[1]
        print(json.dumps({"size": size, **time_fit(problem(size), approximation)}))
        return
    if args.replot:  # the figure and the summary again, from the JSON of an earlier sweep
        results = json.loads(args.out.with_suffix(".json").read_text())["fits"]
    else:
        results = sweep(args.sizes)
    report(results, args.out)


def sweep(sizes: list[int]) -> dict[str, list[dict]]:
    """Each path over the sizes; a fit stopped at the limit is kept as a row
    with "timed_out" and ends its path."""
    results: dict[str, list[dict]] = {"exact": [], "hsgp": []}
    for approximation in ("hsgp", "exact"):
        for size in sizes:
            row = run_one(size, approximation) or {"size": size, "timed_out": True}
            results[approximation].append(row)
            if row.get("timed_out"):
                print(f"{approximation}: n = N = {size} took more than {EXACT_LIMIT_S:.0f} s; larger sizes skipped")
                break
            print(f"{approximation:>6} n = N = {size:>5}: {row['seconds']:7.1f} s, peak memory "
                  f"{row['peak_memory_gb']:.2f} GB, R-hat {row['max_rhat']:.3f}, {row['divergences']} divergences",
                  flush=True)
            if row["seconds"] > EXACT_LIMIT_S:
                break
    return results


def slope(rows: list[dict]) -> dict[str, float | None]:
    """The log-log slope of wall time against n over the finished fits, and
    (when the path ended at the limit) the smallest slope that reaches the
    limit from its last finished fit."""
    done = [r for r in rows if not r.get("timed_out")]
    fitted = (float(np.polyfit(np.log([r["size"] for r in done]), np.log([r["seconds"] for r in done]), 1)[0])
              if len(done) >= 2 else None)
    cut = next((r for r in rows if r.get("timed_out")), None)
    at_least = (float(np.log(EXACT_LIMIT_S / done[-1]["seconds"]) / np.log(cut["size"] / done[-1]["size"]))
                if cut and done else None)
    return {"fitted": fitted, "at_least": at_least}


def report(results: dict[str, list[dict]], out: Path) -> None:
    finished = {k: [r for r in v if not r.get("timed_out")] for k, v in results.items()}
    for exact in finished["exact"]:  # the same data on both paths: the approximation's error in theta
        scalable = next((r for r in finished["hsgp"] if r["size"] == exact["size"]), None)
        for name, reference in exact["theta"].items() if scalable else ():
            approx = scalable["theta"][name]
            shift = (approx['mean'] - reference['mean']) / reference['sd']
            print(f"n = N = {exact['size']}, {name}: hsgp mean {shift:+.2f} "
                  f"exact sd from the exact one, sd {approx['sd'] / reference['sd'] - 1:+.0%}")
    slopes = {k: slope(v) for k, v in results.items()}
    for k, v in slopes.items():
        fitted = f"{v['fitted']:.2f}" if v["fitted"] is not None else "one finished size only"
        bound = f"; at least {v['at_least']:.2f} to reach the 10-minute limit" if v["at_least"] is not None else ""
        print(f"log-log slope of wall time against n, {k}: {fitted}{bound}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"fits": results, "slopes": slopes}, indent=2))
    plot(results, slopes, out.with_suffix(".png"))


def plot(results: dict[str, list[dict]], slopes: dict[str, dict], path: Path) -> None:
    from stancal.reporting.plots import finish, pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for (name, rows), colour in zip(results.items(), ("C0", "C1"), strict=False):
        done = [r for r in rows if not r.get("timed_out")]
        fitted, at_least = slopes[name]["fitted"], slopes[name]["at_least"]
        label = name + (f" (slope {fitted:.2f})" if fitted is not None else "")
        label += f" (slope at least {at_least:.1f})" if at_least is not None else ""
        ax.loglog([r["size"] for r in done], [r["seconds"] for r in done], "o-", color=colour, label=label)
        for cut in (r for r in rows if r.get("timed_out")):
            ax.loglog([done[-1]["size"], cut["size"]], [done[-1]["seconds"], EXACT_LIMIT_S], ":", color=colour)
            ax.loglog([cut["size"]], [EXACT_LIMIT_S], "^", color=colour, markersize=9)
            ax.annotate("stopped at 10 min", (cut["size"], EXACT_LIMIT_S), textcoords="offset points",
                        xytext=(6, -14), fontsize=8, color=colour)
    ax.axhline(EXACT_LIMIT_S, color="grey", linestyle=":", label="10 minutes")
    ax.set_xlabel("n = N (physical points = simulator runs)")
    ax.set_ylabel("wall time of modular, 4 x (500 + 500) [s]")
    ax.legend(loc="lower right")
    fig.tight_layout()
    finish(fig, path)


if __name__ == "__main__":
    main()
