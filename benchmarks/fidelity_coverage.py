"""The slow coverage study of theta on the two-level cooling problem
(tests/test_multifidelity.py: 40 cheap and 6 expensive runs, 12 readings,
k = 1.2): over seeds of the runs, the readings and the sampler, how often
theta's 90 % interval covers the truth, with each fit's health and modes
(docs/multifidelity.md).

    python benchmarks/fidelity_coverage.py [--seeds 20] [--chains 4]

Writes benchmarks/fidelity_coverage.json and prints the table.
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
from conftest import fit  # noqa: E402


def one_seed(seed: int, chains: int) -> dict:
    """One fit of the problem at ``seed`` (sampler seed + 1): theta's interval, health and modes."""
    started = time.perf_counter()
    result = fit(two_level.problem(seed=seed), method="modular", discrepancy="none", chains=chains, warmup=500,
                 draws=1000, seed=seed + 1)
    theta = np.asarray(result.idata["posterior"]["theta"])[..., 0]
    low, high = np.quantile(theta.reshape(-1), [0.05, 0.95])
    d = result.diagnostics
    return {"seed": seed, "q05": float(low), "q95": float(high), "covered": bool(low <= two_level.K_TRUE <= high),
            "max_rhat": float(d.max_rhat), "divergences": int(d.divergences),
            "chain_means": theta.mean(axis=1).round(4).tolist(),
            "modes": [{"chains": m.chains, "weight": m.weight, "k_mean": m.theta_mean["k"]} for m in result.modes],
            "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--chains", type=int, default=4)
    args = parser.parse_args()
    rows = []
    for seed in range(args.seeds):
        rows.append(one_seed(seed, args.chains))
        r = rows[-1]
        print(f"| {seed} | [{r['q05']:.4f}, {r['q95']:.4f}] | {'yes' if r['covered'] else 'no'} | {r['max_rhat']:.3f} "
              f"| {r['divergences']} | {len(r['modes']) or 1} | {r['chain_means']} | {r['seconds']:.0f} s |",
              flush=True)
        (Path(__file__).parent / "fidelity_coverage.json").write_text(json.dumps(rows, indent=2))
    print(f"covered in {sum(r['covered'] for r in rows)} of {len(rows)}")


if __name__ == "__main__":
    main()
