"""Effective samples of theta per second on the joint-KOH benchmark: the
cooling case study (39 physical points, 60 simulator runs, one theta, GP
emulator + GP discrepancy over the simulator inputs), for stancal's programs and, in the same run, for
a plain joint-KOH program written by hand (plain_koh_joint.stan, no stancal
machinery) on the same standardised data. The machine is shared and noisy:
read the ratio to the baseline, not the absolute figure.

    .venv/bin/python benchmarks/ess_per_second.py [--chains 4] [--warmup 500] [--draws 500]

ESS/s = min bulk ESS of theta / wall-clock seconds of sampling (warmup and
generated quantities included; for modular, stage 1's emulator fit too),
chains in parallel on the machine's cores.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402


def sampling_arguments() -> argparse.Namespace:
    """--chains, --warmup, --draws and --backend, shared by the benchmarks."""
    parser = argparse.ArgumentParser()
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--backend", default=None)
    return parser.parse_args()


TARGET_ESS_PER_S = 150  # issue 13: koh_emulator and modular


def plain_baseline(data, args: argparse.Namespace) -> dict:
    """The hand-written joint-KOH program, sampled and timed as stancal's are
    (the same backend call, PyStan's default adapt_delta 0.8)."""
    import arviz_stats as ast
    import numpy as np
    import xarray as xr

    from stancal.problem.options import ModelOptions
    from stancal.stan.backends.pystan_backend import PyStanBackend
    from stancal.stan.registry import PROGRAMS
    from stancal.stan.source import flatten
    from stancal.stan.standata import build_stan_data, default_new_points, to_stan_json

    program = flatten(Path(__file__).with_name("plain_koh_joint.stan"))
    # the same standardised data koh_emulator gets, the variables the plain program declares
    full = to_stan_json(build_stan_data(data, PROGRAMS["koh_emulator"].data, ModelOptions(), default_new_points(data)))
    stan_data = {k: full[k] for k in ("N", "M", "D", "Q", "x", "y", "x_sim", "theta_sim", "y_sim")}
    sample = PyStanBackend().sample(program, stan_data, chains=args.chains, warmup=args.warmup,
                                    draws=args.draws, seed=1, inits=None, adapt_delta=0.8, max_treedepth=10)
    theta = xr.DataArray(sample.draws["theta"], dims=["chain", "draw", "theta"])
    ess = float(ast.ess(theta, method="bulk").min())
    return {"method": "plain PyStan program (baseline)", "backend": "pystan",
            "compile_s": round(sample.compile_seconds, 1), "sample_s": round(sample.sample_seconds, 1),
            "theta_ess_bulk": round(ess), "theta_ess_per_s": round(ess / sample.sample_seconds, 1),
            "divergences": int(np.sum(sample.sample_stats["diverging"])),
            "max_rhat": round(float(ast.rhat(theta).max()), 3)}


def main() -> None:
    args = sampling_arguments()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        problem = load_config(ROOT / "case_studies" / "cooling" / "config.toml")
        # the joint-KOH problem as the plain program states it: the discrepancy
        # over the simulator inputs only (the case study's covariates left out)
        d = problem.data
        data = stancal.CalibrationData(d.source, d.inputs, d.output,
                                       {p.name: (p.lower, p.upper) for p in d.parameters}, runs=d.runs)
    rows = [plain_baseline(data, args)]
    for method in ("koh", "koh_emulator", "modular"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = stancal.calibrate(
                data, simulator=problem.simulator if method == "koh" else None,
                method=method, chains=args.chains, warmup=args.warmup, draws=args.draws,
                seed=1, backend=args.backend)
        ess = min(v["ess_bulk"] for v in result.theta_summary().values())
        rows.append({
            "method": method, "backend": result.backend,
            "compile_s": round(result.timing["compile_s"], 1),
            "sample_s": round(result.timing["sample_s"], 1),
            "theta_ess_bulk": round(ess),
            "theta_ess_per_s": round(ess / result.timing["sample_s"], 1),
            "divergences": result.diagnostics.divergences,
            "max_rhat": round(result.diagnostics.max_rhat, 3),
        })
    baseline = rows[0]["theta_ess_per_s"]
    for row in rows:
        row["ratio_to_baseline"] = round(row["theta_ess_per_s"] / baseline, 2)
        row["target"] = TARGET_ESS_PER_S if row["method"] in ("koh_emulator", "modular") else ""
    print(f"{args.chains} chains x ({args.warmup} + {args.draws}), seed 1")
    print(pd.DataFrame(rows).to_markdown(index=False))


if __name__ == "__main__":
    main()
