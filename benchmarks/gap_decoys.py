"""What the gap diagnosis says about the decoys of the cooling case study:
the total Sobol index of every discrepancy variable (humidity and operator
play no part in the data) and each candidate's shrinkage.

    .venv/bin/python benchmarks/gap_decoys.py [--chains 2] [--warmup 1000] [--draws 1000]

Prints one line per variable and per candidate, with 90 % intervals.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import stancal  # noqa: E402
from ess_per_second import sampling_arguments  # noqa: E402
from stancal.config import load_config  # noqa: E402


def main() -> None:
    args = sampling_arguments()
    problem = load_config(ROOT / "case_studies" / "cooling" / "config.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        analysis = stancal.diagnose_gap(problem.data, problem.candidates, simulator=problem.simulator,
                                        chains=args.chains, warmup=args.warmup, draws=args.draws,
                                        seed=1, backend=args.backend)
    summary = analysis.to_json()
    for variable, value in summary["where"]["importance"].items():
        print(f"importance {variable:>12}: {value['mean']:.3f} [{value['q05']:.3f}, {value['q95']:.3f}]")
    for candidate in summary["candidates"]:
        s = candidate["shrinkage"]
        print(f"candidate {candidate['name']:>16}: ELPD {candidate['elpd_diff']:+.1f} ± "
              f"{candidate['elpd_diff_se']:.1f}, shrinkage {s['mean']:.2f} [{s['q05']:.2f}, {s['q95']:.2f}]")


if __name__ == "__main__":
    main()
