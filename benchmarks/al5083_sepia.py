"""stancal against SEPIA on the same 100 Al-5083 runs (docs/al5083.md):
stancal's side, run here, beside SEPIA's numbers, measured in a scratch
environment by benchmarks/al5083_sepia_run.py and recorded, with SEPIA's
commit and the command run, under "sepia" in benchmarks/al5083_sepia.json.

    nice -n 5 python benchmarks/al5083_sepia.py [--chains 2 --warmup 1000 --draws 1000 --seed 1]
    python benchmarks/al5083_sepia.py --sepia /tmp/al5083_sepia*.json   # record SEPIA's runs, then stop
    python benchmarks/al5083_sepia.py --sepia /tmp/fixed_1.json /tmp/fixed_2.json --key sepia_lamos_fixed

``--sepia``: the JSONs benchmarks/al5083_sepia_run.py wrote, one per chain
(each run is one chain; its draws beside it, .draws.npz, or .theta.npy from
before the script kept the hyperparameters), become the record's entry
``--key`` ("sepia": lamOs sampled, the recipe's; "sepia_lamos_fixed": lamOs
fixed at 1, run with --fix-lamos), with the SEPIA commit, the command, and
theta's bulk ESS and R-hat over the chains' kept draws (a single chain's
split into two halves). ``--cpu-s``: each chain's CPU seconds, tuning
included, when measured outside the script.

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
import os
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
SEPIA_FIXED_COMMAND = ("OPENBLAS_NUM_THREADS=1 nice -n 5 python benchmarks/al5083_sepia_run.py "
                       "--data SEPIA/examples/Al_5083/data --subset case_studies/al5083/runs_subset.csv "
                       "--iterations 10000 --burn 1000 --fix-lamos --deadline 07:41 --seed SEED "
                       "--out al5083_sepia_fixed_SEED.json")  # SEED = 1, 2, both at once
HYPER = ("betaU", "lamUz", "lamWs", "lamWOs", "lamOs")  # SEPIA's other sampled parameters


def chains_of(draws: list[np.ndarray]) -> np.ndarray:
    """(chain, draw, ...) from per-run draws cut to the shortest; one run's
    draws as two halves, so that R-hat has two chains to compare."""
    if len(draws) == 1:
        half = len(draws[0]) // 2
        draws = [draws[0][:half], draws[0][half: 2 * half]]
    return np.stack([d[: min(len(d) for d in draws)] for d in draws])


def summary(chains: np.ndarray) -> dict:
    """Mean, sd, bulk ESS and R-hat of one scalar's (chain, draw) draws."""
    ess = float(ast.ess(chains, method="bulk"))
    return {"mean": float(chains.mean()), "sd": float(chains.std(ddof=1)), "ess_bulk": ess,
            "rhat": float(ast.rhat(chains))}


def record_sepia(paths: list[Path], key: str = "sepia", cpu_s: list[float] | None = None) -> None:
    """SEPIA's runs (one chain each, same settings, their own seeds) as the
    record's entry ``key``: where and how they ran, theta's mean and sd over
    all kept draws, its bulk ESS and R-hat (with one chain, its kept draws
    as two halves) and the Monte Carlo error of the mean; with the
    hyperparameters' draws at hand (.draws.npz), their summaries too."""
    runs = [json.loads(p.read_text()) for p in paths]
    npz = [p.with_suffix(".draws.npz") for p in paths]
    if all(f.exists() for f in npz):
        loaded = [dict(np.load(f)) for f in npz]
        kept = [{k: v[r["burn"]: r["iterations"]] for k, v in d.items()} for d, r in zip(loaded, runs, strict=True)]
    else:
        kept = [{"theta": np.load(p.with_suffix(".theta.npy"))} for p in paths]
    chains = chains_of([k["theta"] for k in kept])  # (chain, draw, theta), unit scale
    names, mcmc_s = list(runs[0]["theta"]), sum(r["mcmc_s"] for r in runs)
    core_s = sum(r["tune_s"] + r["mcmc_s"] for r in runs)  # one process, one core per chain; tuning counted
    theta = {}
    for q, name in enumerate(names):  # in the design's column order, as SEPIA's theta
        lo, hi = BOX[name]
        u = chains[..., q].ravel()
        ess = float(ast.ess(chains[..., q], method="bulk"))
        theta[name] = {"mean_unit": float(u.mean()), "sd_unit": float(u.std(ddof=1)),
                       "mean": float(lo + (hi - lo) * u.mean()), "sd": float((hi - lo) * u.std(ddof=1)),
                       "sd_over_prior_sd": float(u.std(ddof=1) * np.sqrt(12)), "ess_bulk": ess,
                       "rhat": float(ast.rhat(chains[..., q])), "mcse_mean_over_sd": 1 / np.sqrt(ess),
                       "ess_per_s": ess / mcmc_s, "ess_per_core_s": ess / core_s}
        if cpu_s:
            theta[name]["ess_per_cpu_s"] = ess / sum(cpu_s)
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    if "stancal" in record and "core_s" not in record["stancal"]:
        add_core_seconds(record["stancal"], os.cpu_count() or 1)
    if key == "sepia" and "stancal" in record:  # stancal's fit compared again, with the new reference
        compare_with(record["stancal"], theta)
    elif "stancal" in record:  # the comparison with this run kept beside it
        for name, entry in theta.items():
            st = record["stancal"]["theta"][name]
            entry |= {"stancal_gap_in_sds": (st["mean"] - entry["mean"]) / entry["sd"],
                      "stancal_sd_ratio": st["sd"] / entry["sd"]}
    entry = {"commit": SEPIA_COMMIT, "command": SEPIA_COMMAND if key == "sepia" else SEPIA_FIXED_COMMAND,
             "lamOs": runs[0].get("lamOs", "sampled"), "chains": len(runs),
             "seeds": [r["seed"] for r in runs], "runs": runs[0]["runs"],
             "iterations": [r["iterations"] for r in runs] if key != "sepia" else runs[0]["iterations"],
             "burn": runs[0]["burn"], "kept_per_chain": int(chains.shape[1]),
             "tune_s": [r["tune_s"] for r in runs], "mcmc_s": [r["mcmc_s"] for r in runs],
             "s_per_iteration": [r["s_per_iteration"] for r in runs], "core_s": core_s}
    if cpu_s:
        entry["cpu_s"] = cpu_s
    entry["theta"] = theta
    if "lamUz" in kept[0]:
        hyper = {}
        for name in HYPER:
            c = chains_of([k[name] for k in kept])  # (chain, draw, component)
            hyper[name] = [summary(c[..., j]) if np.ptp(c[..., j]) > 0 else {"fixed": float(c[..., j].flat[0])}
                           for j in range(c.shape[-1])]
        ratio = chains_of([np.sqrt(k["lamUz"] / k["lamWs"]) for k in kept])
        hyper["nugget_sd_over_gp_sd"] = [summary(ratio[..., j]) | {"q95": float(np.quantile(ratio[..., j], 0.95))}
                                         for j in range(ratio.shape[-1])]  # sqrt(lamUz / lamWs) per component
        entry["hyperparameters"] = hyper
    record[key] = entry
    RECORD.write_text(json.dumps(record, indent=2) + "\n")


def add_core_seconds(stancal: dict, cores: int) -> None:
    """stancal's core-seconds: its wall time (stage 1, warm-up and draws) times
    the cores its chains shared, the most CPU it could have had; theta's bulk
    ESS per core-second beside SEPIA's per chain-process second."""
    stancal |= {"cores": cores, "core_s": cores * stancal["wall_s"]}
    for entry in stancal["theta"].values():
        entry["ess_per_core_s"] = entry["ess_bulk"] / stancal["core_s"]


def compare_with(stancal: dict, sepia: dict) -> None:
    """stancal's recorded theta against SEPIA's: the mean's gap in SEPIA's
    sds and the ratio of the sds (as compare.theta_table has them)."""
    for name, entry in stancal["theta"].items():
        ref = sepia[name]
        gap = (entry["mean"] - ref["mean"]) / ref["sd"]
        entry |= {"reference_mean": ref["mean"], "reference_sd": ref["sd"], "gap_in_reference_sds": gap,
                  "sd_ratio": entry["sd"] / ref["sd"], "abs_gap_in_sepia_sds": abs(gap)}
    stancal["max_abs_gap_in_sepia_sds"] = max(e["abs_gap_in_sepia_sds"] for e in stancal["theta"].values())


INFORMATIVE = ("a", "vel1", "vel2", "vel3", "delta3")  # posterior sd well below the prior's in both tools


def three_way_table(record: dict) -> str:
    """Markdown: per theta, stancal against SEPIA with lamOs fixed at 1 and
    with lamOs sampled, |mean difference| / SEPIA's sd and the sd ratio
    (stancal / SEPIA), with SEPIA's R-hat and bulk ESS; a SEPIA R-hat above
    1.01 marks the comparison inconclusive (†)."""
    st, runs = record["stancal"]["theta"], [("sepia_lamos_fixed", "lamOs fixed"), ("sepia", "lamOs sampled")]
    head = ["θ", "stancal sd / prior sd"]
    for _, label in runs:
        head += [f"SEPIA ({label}) R-hat, ESS", "\\|mean diff.\\| / SEPIA sd", "sd ratio"]
    head += ["SEPIA sd, fixed / sampled"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, entry in st.items():
        row = [f"**{name}**" if name in INFORMATIVE else name, f"{entry['sd_over_prior_sd']:.2f}"]
        for key, _ in runs:
            ref = record[key]["theta"][name]
            mark = " †" if ref["rhat"] > 1.01 else ""
            gap = abs(entry["mean"] - ref["mean"]) / ref["sd"]
            row += [f"{ref['rhat']:.3f}, {ref['ess_bulk']:.0f}{mark}", f"{gap:.2f}", f"{entry['sd'] / ref['sd']:.2f}"]
        row.append(f"{record['sepia_lamos_fixed']['theta'][name]['sd'] / record['sepia']['theta'][name]['sd']:.2f}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


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
    parser.add_argument("--key", default="sepia", help="the record's entry for --sepia (sepia, sepia_lamos_fixed)")
    parser.add_argument("--cpu-s", type=float, nargs="+", help="with --sepia: each chain's CPU seconds")
    parser.add_argument("--table", action="store_true", help="print the three-way table of the record and stop")
    args = parser.parse_args()
    if args.table:
        return print(three_way_table(json.loads(RECORD.read_text())))
    if args.sepia:
        return record_sepia(args.sepia, args.key, args.cpu_s)
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
    add_core_seconds(record["stancal"], os.cpu_count() or 1)
    RECORD.write_text(json.dumps(record, indent=2) + "\n")
    plot_shots(result, args.out / "shots.png")
    with pd.option_context("display.width", 200, "display.float_format", "{:.4g}".format):
        print(table[["mean", "sd", "reference_mean", "reference_sd", "gap_in_reference_sds", "sd_ratio",
                     "sd_over_prior_sd", "ess_bulk", "rhat"]])
    print(f"{wall:.0f} s in all, {sample_s:.0f} s sampling; R-hat {result.diagnostics.max_rhat:.3f}; "
          f"max |gap| {record['stancal']['max_abs_gap_in_sepia_sds']:.2f} SEPIA sds")


if __name__ == "__main__":
    main()
