"""The rate k on case_studies/cooling_fidelity (150 cheap and 15 expensive
runs, 28 readings) from the two multi-fidelity paths, with
case_studies/cooling_fidelity/compare.py's sampler settings (4 x (500 +
1,000), seed 7): modular (every level's hyperparameters from stage 1, the
top level's variance scaled for their uncertainty) and koh_emulator (every
level's GP and the scale sampled with k: the joint path), each fit's 90 %
interval, its width against modular's, R-hat, divergences and times
(docs/multifidelity.md).

    STANCAL_CACHE=/work/clangstore nice -n 10 .venv/bin/python benchmarks/joint_fidelity_case_study.py \
        [--methods ...] [--chains 4 --warmup 500 --draws 1000]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "case_studies" / "cooling_fidelity"))
from compare import SAMPLING  # noqa: E402
from make_data import K_TRUE  # noqa: E402

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402


def row(method: str, data: stancal.CalibrationData, sampling: dict) -> dict:
    result = stancal.calibrate(data, method=method, discrepancy="none", **sampling)
    k = np.asarray(result.idata["posterior"]["theta"]).reshape(-1)
    low, high = np.quantile(k, [0.05, 0.95])
    d = result.diagnostics
    return {"method": method, "mean": float(k.mean()), "q05": float(low), "q95": float(high),
            "width_90": float(high - low), "covers_truth": bool(low <= K_TRUE <= high), "max_rhat": d.max_rhat,
            "worst_rhat": d.worst_rhat, "divergences": d.divergences, **result.timing}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", nargs="+", default=["modular", "koh_emulator"])
    for name in ("chains", "warmup", "draws"):  # fewer than compare.py's: the joint fit's hour, shortened
        parser.add_argument(f"--{name}", type=int, default=SAMPLING[name])
    args = parser.parse_args()
    sampling = {**SAMPLING, "chains": args.chains, "warmup": args.warmup, "draws": args.draws}
    data = load_config(ROOT / "case_studies" / "cooling_fidelity" / "config.toml").data
    rows = []
    for method in args.methods:
        rows.append(row(method, data, sampling))
        print(json.dumps(rows[-1]), flush=True)
    widths = {r["method"]: r["width_90"] for r in rows}
    if {"modular", "koh_emulator"} <= set(widths):
        print(f"90 % width, koh_emulator / modular: {widths['koh_emulator'] / widths['modular']:.3f}")


if __name__ == "__main__":
    main()
