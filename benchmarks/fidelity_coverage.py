"""The slow coverage study of theta with two fidelities: over seeds of the
runs, the readings and the sampler, how often theta's 90 % interval covers
the truth, with each fit's health and modes (docs/multifidelity.md).

- ``--case two_level``: tests/test_multifidelity.py's problem (40 cheap and
  6 expensive runs, 12 readings, k = 1.2), 4 x (500 + 1000);
- ``--case two_level_centred``: the same with the expensive runs at their
  strata's centres (the slow test's design: none leaves the top of k's box
  to the emulator's extrapolation, as seed 13's scrambled design did);
- ``--case cooling_fidelity``: the case study's simulators (150 cheap and
  15 expensive runs from fresh Latin hypercubes, the shipped ones at seed 0;
  28 readings with fresh noise; k = 0.05), 4 x (300 + 500).

    python benchmarks/fidelity_coverage.py [--case two_level] [--seeds 20] [--chains 4]

Writes benchmarks/fidelity_coverage_CASE.json and prints the table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import test_multifidelity as two_level  # noqa: E402
from conftest import case_study_module, fit  # noqa: E402

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402

CASE = ROOT / "case_studies" / "cooling_fidelity"


def cooling_fidelity(seed: int) -> stancal.CalibrationData:
    """The case study's readings with fresh noise, and fresh runs (seed 0: the shipped runs)."""
    case = case_study_module(CASE)
    shipped = load_config(CASE / "config.toml").data
    physical = shipped.source.copy()
    rng = np.random.default_rng(seed)
    truth = case.with_loss(physical["t"], physical["T0"], case.K_TRUE)
    physical["temperature"] = truth + rng.normal(0, case.NOISE_SD, len(physical))
    runs = shipped.runs_by_fidelity() if seed == 0 else [case.runs(case.newton, 150, 10 * seed + 1),
                                                         case.runs(case.with_loss, 15, 10 * seed + 2)]
    return stancal.CalibrationData(physical, shipped.inputs, shipped.output, {"k": case.K_BOUNDS}, runs=runs)


CASES = {"two_level": (lambda seed: two_level.problem(seed=seed), two_level.K_TRUE, 500, 1000),
         "two_level_centred": (lambda seed: two_level.problem(seed=seed, centred=True), two_level.K_TRUE, 500, 1000),
         "cooling_fidelity": (cooling_fidelity, 0.05, 300, 500)}


def one_seed(case: str, seed: int, chains: int) -> dict:
    """One fit of the problem at ``seed`` (sampler seed + 1): theta's interval, health and modes."""
    started = time.perf_counter()
    problem, truth, warmup, draws = CASES[case]
    result = fit(problem(seed), method="modular", discrepancy="none", chains=chains, warmup=warmup, draws=draws,
                 seed=seed + 1)
    theta = np.asarray(result.idata["posterior"]["theta"])[..., 0]
    low, high = np.quantile(theta.reshape(-1), [0.05, 0.95])  # every chain alike, whatever mode it is in
    k = result.theta_summary()["k"]  # several modes: their mixture, each weighted by its mass (stancal)
    d = result.diagnostics
    return {"seed": seed, "q05": k["q05"], "q95": k["q95"], "covered": bool(k["q05"] <= truth <= k["q95"]),
            "pooled_q05": float(low), "pooled_q95": float(high), "rhat_within_modes": k["rhat"],
            "max_rhat": float(d.max_rhat), "divergences": int(d.divergences),
            "chain_means": theta.mean(axis=1).round(4).tolist(),
            "modes": [{"chains": m.chains, "weight": m.weight, "k_mean": m.theta_mean["k"]} for m in result.modes],
            "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--case", default="two_level", choices=list(CASES))
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--chains", type=int, default=4)
    args = parser.parse_args()
    rows = []
    for seed in range(args.seeds):
        rows.append(one_seed(args.case, seed, args.chains))
        r = rows[-1]
        print(f"| {seed} | [{r['q05']:.4f}, {r['q95']:.4f}] | {'yes' if r['covered'] else 'no'} | {r['max_rhat']:.3f} "
              f"({r['rhat_within_modes']:.3f} within modes) "
              f"| {r['divergences']} | {len(r['modes']) or 1} | {r['chain_means']} | {r['seconds']:.0f} s |",
              flush=True)
        (Path(__file__).parent / f"fidelity_coverage_{args.case}.json").write_text(json.dumps(rows, indent=2))
    print(f"covered in {sum(r['covered'] for r in rows)} of {len(rows)}")


if __name__ == "__main__":
    main()
