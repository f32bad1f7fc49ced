"""Vector outputs: fit time and theta's effective samples per second of
modular_vector against the number of runs and of output dimensions.

Cooling curves (Newton's law, theta = k, Ta) on a grid of K times; four
ragged experiments of known noise, no discrepancy; 4 chains x (500 + 500)
after the program is compiled. Each row: stage 1 (one GP per component),
sampling, theta's smallest bulk ESS and ESS per second of sampling.

    python benchmarks/vector_outputs.py [--runs 40 100 200] [--dims 31 121]

Writes benchmarks/vector_outputs.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stancal.vector_calibrate import calibrate_vector  # noqa: E402
from stancal.vector_data import VectorCalibrationData  # noqa: E402

THETA = {"k": (0.01, 0.1), "Ta": (15.0, 25.0)}


def newton(t, T0, k, Ta):
    return Ta + (T0 - Ta) * np.exp(-k * t)


def problem(runs: int, dims: int, seed: int = 0) -> VectorCalibrationData:
    rng = np.random.default_rng(seed)
    grid = np.linspace(0, 60, dims)
    settings = pd.DataFrame({"run": np.arange(runs), "T0": rng.uniform(55, 95, runs),
                             "k": rng.uniform(*THETA["k"], runs), "Ta": rng.uniform(*THETA["Ta"], runs)})
    long = settings.loc[settings.index.repeat(dims)].reset_index(drop=True)
    long["t"] = np.tile(grid, runs)
    long["T"] = newton(long.t, long.T0, long.k, long.Ta)
    rows = []
    for e in range(4):
        t = np.sort(rng.uniform(0, 60, rng.integers(8, 16)))
        T0 = rng.uniform(60, 90)
        rows.append(pd.DataFrame({"exp": f"e{e}", "T0": T0, "t": t, "sd": 0.3,
                                  "T": newton(t, T0, 0.045, 21.3) + 0.3 * rng.standard_normal(t.size)}))
    return VectorCalibrationData(pd.concat(rows, ignore_index=True), "exp", ["T0"], "T", "t", THETA,
                                 runs=long, run="run", noise_sd="sd")


def one(runs: int, dims: int) -> dict:
    data = problem(runs, dims)
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = calibrate_vector(data, discrepancy="none", chains=4, warmup=500, draws=500, seed=1)
    total = time.perf_counter() - started
    summary = result.theta_summary()
    ess = min(v["ess_bulk"] for v in summary.values())
    return {"runs": runs, "dims": dims, "components": data.basis.count, "total_s": total,
            "sample_s": result.timing["sample_s"], "min_ess_theta": ess,
            "ess_per_s": ess / result.timing["sample_s"], "max_rhat": result.diagnostics.max_rhat}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, nargs="+", default=[40, 100, 200])
    parser.add_argument("--dims", type=int, nargs="+", default=[31, 121])
    args = parser.parse_args()
    rows = [one(runs, dims) for dims in args.dims for runs in args.runs]
    (Path(__file__).parent / "vector_outputs.json").write_text(json.dumps(rows, indent=2))
    print("| runs | output dims | components | whole fit (s) | sampling (s) | min ESS theta | ESS/s | R-hat |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['runs']} | {r['dims']} | {r['components']} | {r['total_s']:.0f} | {r['sample_s']:.0f} | "
              f"{r['min_ess_theta']:.0f} | {r['ess_per_s']:.1f} | {r['max_rhat']:.3f} |")


if __name__ == "__main__":
    main()
