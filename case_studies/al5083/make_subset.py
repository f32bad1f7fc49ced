"""A random subset of the Al-5083 runs, small enough for SEPIA's sampler to
finish (docs/al5083.md: one iteration on all 1,000 runs takes 14 s), written
as ``runs_subset.csv`` beside ``runs.csv`` so that stancal
(``config_subset.toml``) and SEPIA (``benchmarks/al5083_sepia_run.py``) see
the same runs:

    python case_studies/al5083/make_subset.py [--runs 100] [--seed 20261126]

The runs are drawn without replacement with numpy's default generator at the
seed given; the run numbers (rows of SEPIA's ``Al.trial5.design.txt``, from 0)
are kept. The data are SEPIA's (github.com/lanl/SEPIA, examples/Al_5083;
Walters et al. 2018, J. Appl. Phys., doi:10.1063/1.5051442)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
SEED = 20261126  # the subset in docs/al5083.md


def subset_runs(n_runs: int, seed: int = SEED, total: int = 1000) -> np.ndarray:
    """The run numbers of the subset, sorted."""
    return np.sort(np.random.default_rng(seed).choice(total, size=n_runs, replace=False))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--out", type=Path, default=HERE / "runs_subset.csv")
    args = parser.parse_args()
    runs = pd.read_csv(HERE / "runs.csv")
    keep = subset_runs(args.runs, args.seed, total=runs["run"].nunique())
    runs[runs["run"].isin(keep)].to_csv(args.out, index=False)
    print(f"{len(keep)} of {runs['run'].nunique()} runs (seed {args.seed}) -> {args.out}")


if __name__ == "__main__":
    main()
