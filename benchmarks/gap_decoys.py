"""Where the gap diagnosis puts the cooling case study's gap: the total Sobol
index of every discrepancy variable. humidity and operator play no part in
the data (decoys), so theirs should be near 0 with an interval touching 0.

    .venv/bin/python benchmarks/gap_decoys.py [--chains 2] [--warmup 1000] [--draws 1000] [--seeds 3]

Fits the gap diagnosis's baseline (KOH with a GP discrepancy over the inputs
and covariates, and a constant discrepancy mean) for each seed and prints the
importances with their 90 % intervals over posterior draws.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import stancal  # noqa: E402
from stancal.diagnosing.gap_location import locate_gap  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=1000)
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    problem = load_config(ROOT / "case_studies" / "cooling" / "config.toml")
    for seed in range(1, args.seeds + 1):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            baseline = stancal.calibrate(problem.data, simulator=problem.simulator, mean_intercept=True,
                                         chains=args.chains, warmup=args.warmup, draws=args.draws, seed=seed)
        importance = locate_gap(baseline, seed=seed).importance
        print(f"seed {seed}: " + "; ".join(f"{v} {i['mean']:.3f} [{i['q05']:.3f}, {i['q95']:.3f}]"
                                           for v, i in importance.items()), flush=True)


if __name__ == "__main__":
    main()
