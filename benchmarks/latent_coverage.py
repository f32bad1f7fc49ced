"""Frequentist checks of the latent-GP programs over noise seeds: how often
the 90 % interval holds the true theta (nominal 90 %), the posterior
predictive coverage of count data, and the censored likelihood against the
naive fits. Cheap simulators only; about a second a fit once compiled.

    .venv/bin/python benchmarks/latent_coverage.py [--seeds 20]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

sys.path.insert(0, str(ROOT / "tests"))

from conftest import case_study_module  # noqa: E402

import stancal  # noqa: E402

STUDIES = ROOT / "case_studies"


def case_study(name: str):
    return case_study_module(STUDIES / name)


def fit(data, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return stancal.calibrate(data, chains=2, warmup=500, draws=500, **options)


def counts(seeds: int) -> dict:
    detector = case_study("detector_counts")
    inside, coverage = [], []
    for seed in range(seeds):
        rng = np.random.default_rng(1000 + seed)
        d, s = (a.ravel() for a in np.meshgrid([0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0], [0.0, 1.0, 2.5, 4.0, 5.0]))
        frame = pd.DataFrame({"d": d, "s": s, "counts": rng.poisson(detector.simulator(d, s, detector.MU_TRUE))})
        data = stancal.CalibrationData(frame, ["d", "s"], "counts", {"mu": (0.05, 1.0)}, likelihood="poisson")
        result = fit(data, simulator=STUDIES / "detector_counts" / "simulator.stan", seed=seed)
        mu = result.theta_summary()["mu"]
        inside.append(mu["q05"] < detector.MU_TRUE < mu["q95"])
        y_rep = np.asarray(result.idata["posterior_predictive"]["y"]).reshape(-1, len(frame))
        low, high = np.quantile(y_rep, [0.05, 0.95], axis=0)
        coverage.append(np.mean((frame.counts >= low) & (frame.counts <= high)))
    return {"study": "Poisson + GP discrepancy, exact simulator", "fits": seeds,
            "truth in 90 % interval": f"{np.mean(inside):.0%}",
            "predictive coverage of the counts": f"{np.mean(coverage):.0%}"}


def censoring(seeds: int) -> dict:
    decay = case_study("detection_limit")
    errors = {"censored": [], "drop": [], "impute": []}
    inside = []
    options = {"simulator": STUDIES / "detection_limit" / "simulator.stan", "method": "koh_latent",
                   "discrepancy": "none"}
    for seed in range(seeds):
        frame = decay.measurements(seed=2000 + seed)
        frames = {"censored": frame, **decay.naive_frames(frame)}
        for name, table in frames.items():
            bounds = {"lower": "lower", "upper": "upper"} if name == "censored" else {}
            data = stancal.CalibrationData(table, ["t", "c0"], "concentration", {"k": (0.01, 0.5)}, **bounds)
            k = fit(data, seed=seed, **options).theta_summary()["k"]
            errors[name].append(abs(k["q50"] - decay.K_TRUE))
            if name == "censored":
                inside.append(k["q05"] < decay.K_TRUE < k["q95"])
    best = np.mean([c < d and c < i for c, d, i in zip(*errors.values(), strict=False)])
    return {"study": "censored decay (37 % censored)", "fits": 3 * seeds,
            "truth in 90 % interval": f"{np.mean(inside):.0%}",
            "mean abs error: censored / drop / impute": " / ".join(f"{np.mean(e):.4f}" for e in errors.values()),
            "censored closest": f"{best:.0%}"}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    rows = [counts(args.seeds), censoring(args.seeds)]
    for row in rows:
        print("\n".join(f"- {k}: {v}" for k, v in row.items()), end="\n\n")


if __name__ == "__main__":
    main()
