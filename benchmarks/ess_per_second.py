"""Compile time, sampling time and effective samples of theta per second for
each program on the standard problem: the cooling case study (39 physical
points, 60 simulator runs, one theta, GP emulator + GP discrepancy).

    .venv/bin/python benchmarks/ess_per_second.py [--chains 2] [--draws 1000]

ESS/s = min bulk ESS of theta / wall-clock seconds of sampling (warmup
included), chains run in parallel on the machine's cores.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import stancal  # noqa: E402
from stancal.config import load_config  # noqa: E402


def sampling_arguments() -> argparse.Namespace:
    """--chains, --warmup, --draws and --backend, shared by the benchmarks."""
    parser = argparse.ArgumentParser()
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=1000)
    parser.add_argument("--backend", default=None)
    return parser.parse_args()


def main() -> None:
    args = sampling_arguments()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        problem = load_config(ROOT / "case_studies" / "cooling" / "config.toml")
    rows = []
    for method in ("koh", "koh_emulator", "modular"):
        started = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = stancal.calibrate(
                problem.data, simulator=problem.simulator if method == "koh" else None,
                method=method, chains=args.chains, warmup=args.warmup, draws=args.draws,
                seed=1, backend=args.backend)
        total = time.perf_counter() - started
        ess = min(v["ess_bulk"] for v in result.theta_summary().values())
        rows.append({
            "method": method, "backend": result.backend,
            "compile_s": round(result.timing["compile_s"], 1),
            "sample_s": round(result.timing["sample_s"], 1),
            "total_s": round(total, 1),
            "theta_ess_bulk": round(ess),
            "theta_ess_per_s": round(ess / result.timing["sample_s"], 1),
            "divergences": result.diagnostics.divergences,
            "max_rhat": round(result.diagnostics.max_rhat, 3),
            "k_median": round(result.theta_summary()["k"]["q50"], 4),
        })
    print(pd.DataFrame(rows).to_markdown(index=False))


if __name__ == "__main__":
    main()
