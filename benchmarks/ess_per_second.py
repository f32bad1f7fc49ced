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
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--backend", default=None)
    return parser.parse_args()


TARGET_ESS_PER_S = 150  # issue 13: koh_emulator and modular


def plain_baseline(data, args: argparse.Namespace) -> dict:
    """The hand-written joint-KOH program through PyStan, timed like stancal's."""
    import arviz_stats as ast
    import numpy as np
    import stan
    import xarray as xr

    from stancal.backends.pystan_compile import compile_programs, held_output
    from stancal.stan_source import flatten
    from stancal.standata import emulator_run_data

    program = flatten(Path(__file__).with_name("plain_koh_joint.stan"))
    started = time.perf_counter()
    compile_programs([program])
    s = data.scaling
    runs = emulator_run_data(data)
    stan_data = {"N": len(data.physical), "M": runs["M"], "D": len(data.inputs), "Q": len(data.parameters),
                 "x": s.to_unit(data.physical, data.inputs).tolist(),
                 "y": s.standardise(data.observations.value).tolist(),
                 **{k: np.asarray(runs[k]).tolist() for k in ("x_sim", "y_sim")},
                 "t_sim": np.asarray(runs["theta_sim"]).tolist()}
    with held_output():
        model = stan.build(program.code, data=stan_data, random_seed=1)
    compiled = time.perf_counter()
    with held_output():
        fit = model.sample(num_chains=args.chains, num_warmup=args.warmup, num_samples=args.draws)
    sampled = time.perf_counter() - compiled
    theta = np.asarray(fit["theta"]).reshape(-1, args.draws, args.chains).transpose(2, 1, 0)
    ess = float(np.min(ast.ess(xr.DataArray(theta, dims=["chain", "draw", "theta"]), method="bulk")))
    rhat = float(np.max(ast.rhat(xr.DataArray(theta, dims=["chain", "draw", "theta"]))))
    return {"method": "plain PyStan program (baseline)", "backend": "pystan",
            "compile_s": round(compiled - started, 1), "sample_s": round(sampled, 1),
            "theta_ess_bulk": round(ess), "theta_ess_per_s": round(ess / sampled, 1),
            "divergences": int(np.sum(fit["divergent__"])), "max_rhat": round(rhat, 3)}


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
        row["target"] = (f"{TARGET_ESS_PER_S} (x{TARGET_ESS_PER_S / 22:.1f} of 22)"
                         if row["method"] in ("koh_emulator", "modular") else "")
    print(f"{args.chains} chains x ({args.warmup} + {args.draws}), seed 1")
    print(pd.DataFrame(rows).to_markdown(index=False))


if __name__ == "__main__":
    main()
