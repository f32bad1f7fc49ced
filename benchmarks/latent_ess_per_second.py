"""Sampling time and effective samples of theta per second for the
latent-GP programs on their case studies: Poisson counts with a GP
discrepancy (cheap simulator and runs), censored decay data, and a
functional Young's modulus.

    .venv/bin/python benchmarks/latent_ess_per_second.py [--chains 4] [--warmup 500] [--draws 500]

ESS/s = min bulk ESS of theta / seconds of sampling (warmup included; with
runs, stage 1's emulator fit too), chains in parallel on the machine's cores.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ess_per_second import sampling_arguments  # noqa: E402

CASES = (  # (name, case study, method)
    ("counts, Poisson + GP", "detector_counts", "koh"),
    ("counts from runs", "detector_counts", "koh_emulator"),
    ("censored decay", "detection_limit", "koh"),
    ("functional E(T)", "beam_stiffness", "koh"),
)


def main() -> None:
    args = sampling_arguments()
    rows = []
    for name, folder, method in CASES:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            problem = load_config(ROOT / "case_studies" / folder / "config.toml")
            result = stancal.calibrate(problem.data, simulator=problem.simulator, method=method,
                                       chains=args.chains, warmup=args.warmup, draws=args.draws, seed=1,
                                       backend=args.backend, **{k: v for k, v in problem.model.items()
                                                                if k != "method"})
        ess = min(v["ess_bulk"] for v in result.theta_summary().values())
        rows.append({
            "case": name, "program": result.method, "backend": result.backend,
            "sample_s": round(result.timing["sample_s"], 1),
            "theta_ess_bulk": round(ess),
            "theta_ess_per_s": round(ess / result.timing["sample_s"], 1),
            "divergences": result.diagnostics.divergences,
            "max_rhat": round(result.diagnostics.max_rhat, 3),
            "theta": ", ".join(f"{k} {v['q50']:.4g} [{v['q05']:.4g}, {v['q95']:.4g}]"
                               for k, v in result.theta_summary().items()),
        })
    print(pd.DataFrame(rows).to_markdown(index=False))


if __name__ == "__main__":
    main()
