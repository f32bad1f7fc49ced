"""stancal against SEPIA on the same 100 Al-5083 runs (docs/al5083.md):
stancal's side, run here, beside SEPIA's numbers, measured in a scratch
environment by benchmarks/al5083_sepia_run.py and recorded, with SEPIA's
commit and the command run, under "sepia" in benchmarks/al5083_sepia.json.

    nice -n 5 python benchmarks/al5083_sepia.py [--chains 2 --warmup 1000 --draws 1000 --seed 1]
    python benchmarks/al5083_sepia.py --sepia /tmp/al5083_sepia*.json   # record SEPIA's runs, then stop

``--sepia``: the JSON benchmarks/al5083_sepia_run.py wrote (its theta draws
beside it, .theta.npy) becomes the record's "sepia" entry, with the SEPIA
commit, the command, and theta's bulk ESS and R-hat over the kept draws
split into two halves (SEPIA runs one chain).

The problem is SEPIA's examples/Al_5083 (Walters et al. 2018, J. Appl.
Phys., doi:10.1063/1.5051442) on the runs of case_studies/al5083/runs_subset.csv
(make_subset.py: 100 of the 1,000 runs, seed 20261126), with the config's
theta box as both tools' uniform prior. Both follow Higdon et al. (2008,
JASA 103): principal components of the runs' features, one GP per
component's weight; stancal's stage 2 is modular (Liu, Bayarri & Berger
2009, Bayesian Analysis 4), SEPIA samples the emulator's hyperparameters
with theta. Per theta: |mean difference| / SEPIA's sd and the ratio of the
sds. Writes the "stancal" entry of the JSON and, under --out, shots.png.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import arviz_stats as ast
import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "case_studies" / "al5083"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(CASE))

from compare import plot_shots, theta_table  # noqa: E402

from stancal.fitting.vector_calibrate import calibrate_vector  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402

RECORD = ROOT / "benchmarks" / "al5083_sepia.json"
sys.path.insert(0, str(ROOT / "benchmarks"))
from al5083_sepia_run import BOX  # noqa: E402  (the config's theta box; that module imports SEPIA only to run it)

SEPIA_COMMIT = "309890423a121919dc09a678c65a21748bbefb4b"  # github.com/lanl/SEPIA, 2 Oct 2023 (SEPIA 1.2)
SEPIA_COMMAND = ("OPENBLAS_NUM_THREADS=1 nice -n 5 python benchmarks/al5083_sepia_run.py "
                 "--data SEPIA/examples/Al_5083/data --subset case_studies/al5083/runs_subset.csv "
                 "--iterations 5000 --seed SEED --out al5083_sepia_SEED.json")  # SEED = 1, 2, ...


def record_sepia(paths: list[Path]) -> None:
    """SEPIA's runs (one chain each, same settings, their own seeds) as the
    record's "sepia" entry: where and how they ran, theta's mean and sd over
    all kept draws, its bulk ESS and R-hat (with one chain, its kept draws
    as two halves) and the Monte Carlo error of the mean."""
    runs = [json.loads(p.read_text()) for p in paths]
    draws = [np.load(p.with_suffix(".theta.npy")) for p in paths]
    if len(draws) == 1:
        half = len(draws[0]) // 2
        draws = [draws[0][:half], draws[0][half: 2 * half]]
    chains = np.stack([d[: min(len(d) for d in draws)] for d in draws])  # (chain, draw, theta), unit scale
    names, mcmc_s = list(runs[0]["theta"]), sum(r["mcmc_s"] for r in runs)
    theta = {}
    for q, name in enumerate(names):  # in the design's column order, as SEPIA's theta
        lo, hi = BOX[name]
        u = chains[..., q].ravel()
        ess = float(ast.ess(chains[..., q], method="bulk"))
        theta[name] = {"mean_unit": float(u.mean()), "sd_unit": float(u.std(ddof=1)),
                       "mean": float(lo + (hi - lo) * u.mean()), "sd": float((hi - lo) * u.std(ddof=1)),
                       "sd_over_prior_sd": float(u.std(ddof=1) * np.sqrt(12)), "ess_bulk": ess,
                       "rhat": float(ast.rhat(chains[..., q])), "mcse_mean_over_sd": 1 / np.sqrt(ess),
                       "ess_per_s": ess / mcmc_s}
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    if "stancal" in record:  # stancal's fit compared again, with the new reference
        compare_with(record["stancal"], theta)
    record["sepia"] = {"commit": SEPIA_COMMIT, "command": SEPIA_COMMAND, "chains": len(runs),
                       "seeds": [r["seed"] for r in runs], "runs": runs[0]["runs"],
                       "iterations": runs[0]["iterations"], "burn": runs[0]["burn"],
                       "tune_s": [r["tune_s"] for r in runs], "mcmc_s": [r["mcmc_s"] for r in runs],
                       "s_per_iteration": [r["s_per_iteration"] for r in runs], "theta": theta}
    RECORD.write_text(json.dumps(record, indent=2) + "\n")


def compare_with(stancal: dict, sepia: dict) -> None:
    """stancal's recorded theta against SEPIA's: the mean's gap in SEPIA's
    sds and the ratio of the sds (as compare.theta_table has them)."""
    for name, entry in stancal["theta"].items():
        ref = sepia[name]
        gap = (entry["mean"] - ref["mean"]) / ref["sd"]
        entry |= {"reference_mean": ref["mean"], "reference_sd": ref["sd"], "gap_in_reference_sds": gap,
                  "sd_ratio": entry["sd"] / ref["sd"], "abs_gap_in_sepia_sds": abs(gap)}
    stancal["max_abs_gap_in_sepia_sds"] = max(e["abs_gap_in_sepia_sds"] for e in stancal["theta"].values())


def sepia_reference(record: dict) -> pd.DataFrame:
    """SEPIA's posterior mean and sd per theta, in the config's units."""
    theta = record["sepia"]["theta"]
    return pd.DataFrame([{"name": p, "mean": v["mean"], "sd": v["sd"]} for p, v in theta.items()]).set_index("name")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("out/al5083-subset"))
    parser.add_argument("--sepia", type=Path, nargs="+",
                        help="record these SEPIA runs (al5083_sepia_run.py's JSONs, one chain each) and stop")
    args = parser.parse_args()
    if args.sepia:
        return record_sepia(args.sepia)
    logging.basicConfig(format="%(name)s: %(message)s")
    logging.getLogger("stancal").setLevel(logging.INFO)
    record = json.loads(RECORD.read_text())
    problem = load_config(CASE / "config_subset.toml")
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    result = calibrate_vector(problem.data, chains=args.chains, warmup=args.warmup, draws=args.draws,
                              seed=args.seed, out_dir=args.out, **problem.model)
    wall = time.perf_counter() - started
    table = theta_table(result, sepia_reference(record))
    table["abs_gap_in_sepia_sds"] = table["gap_in_reference_sds"].abs()
    sample_s = result.timing["sample_s"]
    record["stancal"] = {
        "command": " ".join(["python benchmarks/al5083_sepia.py", *sys.argv[1:]]),
        "method": result.method, "chains": args.chains, "warmup": args.warmup, "draws": args.draws,
        "seed": args.seed, "wall_s": wall, "timing": result.timing, "max_rhat": result.diagnostics.max_rhat,
        "divergences": result.diagnostics.divergences,
        "theta_ess_bulk_min": float(table["ess_bulk"].min()),
        "theta_min_ess_per_s_sampling": float(table["ess_bulk"].min() / sample_s),
        "theta_min_ess_per_s_wall": float(table["ess_bulk"].min() / wall),
        "max_abs_gap_in_sepia_sds": float(table["abs_gap_in_sepia_sds"].max()),
        "theta": json.loads(table.to_json(orient="index")),
    }
    RECORD.write_text(json.dumps(record, indent=2) + "\n")
    plot_shots(result, args.out / "shots.png")
    with pd.option_context("display.width", 200, "display.float_format", "{:.4g}".format):
        print(table[["mean", "sd", "reference_mean", "reference_sd", "gap_in_reference_sds", "sd_ratio",
                     "sd_over_prior_sd", "ess_bulk", "rhat"]])
    print(f"{wall:.0f} s in all, {sample_s:.0f} s sampling; R-hat {result.diagnostics.max_rhat:.3f}; "
          f"max |gap| {record['stancal']['max_abs_gap_in_sepia_sds']:.2f} SEPIA sds")


if __name__ == "__main__":
    main()
