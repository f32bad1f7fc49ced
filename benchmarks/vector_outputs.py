"""Vector outputs: fit time and theta's effective samples per second of
modular_vector against the number of runs and of output dimensions.

Cooling curves (Newton's law, theta = k, Ta) on a grid of K times; four
ragged experiments of known noise, no discrepancy; 4 chains x (500 + 500)
after the program is compiled. Each row: stage 1 (one GP per component),
sampling, theta's smallest bulk ESS and ESS per second of sampling.

    python benchmarks/vector_outputs.py [--runs 40 100 200] [--dims 31 121]
    python benchmarks/vector_outputs.py --large

Writes benchmarks/vector_outputs.json and prints a table. --large is the
issue's size instead: 1,000 runs of 12 features with 11 parameters (a
smooth synthetic simulator, three experiments measuring every feature),
written to benchmarks/vector_outputs_large.json.
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

from stancal.fitting.vector_calibrate import calibrate_vector  # noqa: E402
from stancal.problem.vector_data import VectorCalibrationData  # noqa: E402

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


def measure(data: VectorCalibrationData) -> dict:
    """One modular fit, 4 x (500 + 500): its times, theta's smallest bulk ESS, R-hat, divergences."""
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = calibrate_vector(data, discrepancy="none", chains=4, warmup=500, draws=500, seed=1)
    ess = min(v["ess_bulk"] for v in result.theta_summary().values())
    return {"components": data.basis.count, "variance_runs": len(result.emulator.variance_runs),
            "total_s": time.perf_counter() - started, "sample_s": result.timing["sample_s"],
            "min_ess_theta": ess, "ess_per_s": ess / result.timing["sample_s"],
            "max_rhat": result.diagnostics.max_rhat, "divergences": result.diagnostics.divergences}


def one(runs: int, dims: int) -> dict:
    return {"runs": runs, "dims": dims, **measure(problem(runs, dims))}


FEATURES, PARAMETERS = 12, 11


def features(x: np.ndarray, theta: np.ndarray, mixing: np.ndarray) -> np.ndarray:
    """12 smooth features of one input x and 11 parameters (rows: settings)."""
    j = np.arange(1, FEATURES + 1) / FEATURES
    linear = theta @ mixing  # (settings, 12)
    return (linear + np.sin(np.pi * (x[:, None] + theta[:, :1] * j)) + x[:, None] * theta[:, 1:2] * j
            + 0.5 * np.exp(-((j - theta[:, 2:3]) ** 2) / 0.1))


def large_problem(runs: int = 1000, seed: int = 0) -> VectorCalibrationData:
    rng = np.random.default_rng(seed)
    mixing = rng.normal(0, 0.5, (PARAMETERS, FEATURES))
    names = [f"t{q + 1}" for q in range(PARAMETERS)]
    settings = rng.uniform(size=(runs, 1 + PARAMETERS))
    outputs = features(settings[:, 0], settings[:, 1:], mixing)
    table = pd.DataFrame(settings, columns=["x", *names]).assign(run=np.arange(runs))
    long = table.loc[table.index.repeat(FEATURES)].reset_index(drop=True)
    long["feature"] = np.tile(np.arange(1, FEATURES + 1), runs)
    long["y"] = outputs.ravel()
    truth = rng.uniform(0.2, 0.8, PARAMETERS)
    x = np.array([0.2, 0.5, 0.8])
    measured = features(x, np.tile(truth, (3, 1)), mixing) + 0.02 * rng.standard_normal((3, FEATURES))
    physical = pd.DataFrame({"shot": np.repeat(["s1", "s2", "s3"], FEATURES), "x": np.repeat(x, FEATURES),
                             "feature": np.tile(np.arange(1, FEATURES + 1), 3), "y": measured.ravel(),
                             "sd": 0.02})
    return VectorCalibrationData(physical, "shot", ["x"], "y", "feature", dict.fromkeys(names, (0.0, 1.0)),
                                 runs=long, run="run", noise_sd="sd")


def large() -> dict:
    return {"runs": 1000, "dims": FEATURES, "parameters": PARAMETERS, **measure(large_problem(runs=1000))}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, nargs="+", default=[40, 100, 200])
    parser.add_argument("--dims", type=int, nargs="+", default=[31, 121])
    parser.add_argument("--large", action="store_true", help="1,000 runs x 12 features x 11 parameters")
    args = parser.parse_args()
    if args.large:
        row = large()
        (Path(__file__).parent / "vector_outputs_large.json").write_text(json.dumps(row, indent=2))
        print(json.dumps(row, indent=2))
        return
    rows = [one(runs, dims) for dims in args.dims for runs in args.runs]
    (Path(__file__).parent / "vector_outputs.json").write_text(json.dumps(rows, indent=2))
    print("| runs | output dims | components | whole fit (s) | sampling (s) | min ESS theta | ESS/s | R-hat |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['runs']} | {r['dims']} | {r['components']} | {r['total_s']:.0f} | {r['sample_s']:.0f} | "
              f"{r['min_ess_theta']:.0f} | {r['ess_per_s']:.1f} | {r['max_rhat']:.3f} |")


if __name__ == "__main__":
    main()
