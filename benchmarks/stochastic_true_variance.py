"""What plugging in the stochastic simulator's intrinsic variance surface
costs: the stochastic_cooling case fitted with stage 1's estimated surface
(stochastic kriging's plug-in, Ankenman, Nelson & Staum 2010, section 3.3)
and again with the true one, sd(t) = 0.2 * 10^(t / 60) deg C
(make_data.intrinsic_sd), everything else alike (seed, draws, the same
held-out readings). If the estimate's error mattered, k's interval, the
nugget, delta's sd and the bands would move between the two:

    .venv/bin/python benchmarks/stochastic_true_variance.py [--draws 800] [--chains 2]

Prints compare.py's table for both (docs/noise.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from unittest import mock

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "case_studies" / "stochastic_cooling"))
sys.path.insert(0, str(ROOT))

import compare  # noqa: E402  (the case study's own scoring)
import make_data  # noqa: E402  (its intrinsic_sd, the truth)

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.stan.standata import emulator_run_data  # noqa: E402

CASE = ROOT / "case_studies" / "stochastic_cooling"


def true_variance(data, stored) -> np.ndarray:
    """Each run's true intrinsic variance, standardised units, in emulator_run_data's order."""
    runs = emulator_run_data(data)
    t = data.runs["t"].to_numpy()
    assert len(t) == runs["M"]
    return (make_data.intrinsic_sd(t) / data.scaling.y_scale) ** 2


def fit(problem, chains: int, draws: int, true: bool) -> stancal.CalibrationResult:
    options = {"method": "modular", "stochastic": True, "chains": chains, "warmup": draws, "draws": draws,
               "seed": 5, "adapt_delta": 0.95}
    if not true:
        return stancal.calibrate(problem.data, **options)
    with mock.patch("stancal.fitting.stage_one.run_intrinsic_variance", true_variance), \
            mock.patch("stancal.stan.standata.run_intrinsic_variance", true_variance):
        return stancal.calibrate(problem.data, **options)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=800)
    parser.add_argument("--chains", type=int, default=2)
    args = parser.parse_args()
    problem = load_config(CASE / "config.toml")
    heldout = {"fitted": pd.read_csv(CASE / "heldout.csv"), "new": pd.read_csv(CASE / "heldout_new.csv")}
    rows = [compare.row(name, fit(problem, args.chains, args.draws, true), heldout, problem.data.scaling.y_scale)
            for name, true in (("estimated V", False), ("true V", True))]
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(pd.DataFrame(rows).round(4).T)


if __name__ == "__main__":
    main()
