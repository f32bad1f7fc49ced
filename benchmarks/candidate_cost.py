"""What a gap candidate's fit costs, and what it gives, by how it is run
(issue 30, target 2): on the counts case (case_studies/source_shield), after
one baseline fit, each candidate is fitted

- ``cold``: as the gap fits it today (Stan's inits, the baseline's warm-up
  and draws);
- ``half``: cold, with half the post-warm-up draws;
- ``warm``: started from the baseline's draws and step size, with the
  shorter warm-up of stancal.fitting.warm_start (candidate_warmup) and half
  the draws;

alternated (cold, half, warm, cold, half, warm) in this one process, each
timed as a ratio to the baseline fit run first in it. For each fit: its
PSIS-LOO ELPD difference to the baseline and its se, the Monte Carlo se of
that difference (the self-normalised importance sampling variance of each
point's p(y_i | y_-i), delta method to the log, draws taken as independent:
Vehtari, Gelman & Gabry 2017, section 2.1; Vehtari et al. 2024 for PSIS), and
the points with Pareto k above 0.7 (those moment matching or a refit must
score: fewer draws make k noisier).

    .venv/bin/python benchmarks/candidate_cost.py [--chains 2] [--warmup 500] [--draws 500]
        [--candidates buildup operator] [--repeats 2] [--seed 1] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.special import logsumexp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import stancal  # noqa: E402
from stancal.diagnosing.scoring import PARETO_K_LIMIT, psis_score  # noqa: E402
from stancal.fitting.warm_start import warm_candidate_options  # noqa: E402
from stancal.problem.candidates import variant_data  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.problem.data import bounds_of  # noqa: E402

CASE = ROOT / "case_studies" / "source_shield" / "config.toml"
MODES = ("cold", "half", "warm")


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--candidates", nargs="+", default=["buildup", "operator"])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None)
    return parser.parse_args()


def mc_variance(result) -> np.ndarray:
    """Each point's Monte Carlo variance of its PSIS log p(y_i | y_-i):
    the self-normalised importance sampling variance of the density's
    estimate, sum_s w_s^2 (p_is - p_i)^2, over p_i^2 (the delta method)."""
    import arviz_stats as ast

    loo = ast.loo(result.idata, pointwise=True, var_name="y")
    log_w = np.asarray(loo.log_weights.transpose("chain", "draw", "obs")).reshape(-1, loo.n_data_points)
    w = np.exp(log_w - logsumexp(log_w, axis=0))
    p = np.exp(np.asarray(result.idata["log_likelihood"]["y"]).reshape(-1, loo.n_data_points))
    estimate = (w * p).sum(0)
    return (w**2 * (p - estimate) ** 2).sum(0) / estimate**2


def figures(candidate, base_score, base_mc, seconds: float, baseline_s: float) -> dict:
    score = psis_score(candidate)
    diff = score.elpd_i - base_score.elpd_i
    d = candidate.diagnostics
    return {"s": round(seconds, 1), "ratio": round(seconds / baseline_s, 3),
            "elpd_diff": round(float(diff.sum()), 3), "se": round(float(np.sqrt(len(diff) * np.var(diff))), 3),
            "mc_se": round(float(np.sqrt((mc_variance(candidate) + base_mc).sum())), 3),
            "high_k": int((score.pareto_k > PARETO_K_LIMIT).sum()),
            "max_rhat": round(d.max_rhat, 3), "min_ess_bulk": round(d.min_ess_bulk), "divergences": d.divergences,
            "draws": d.draws}


def main() -> None:
    args = arguments()
    problem = load_config(CASE)
    data = problem.data
    sampling = {"chains": args.chains, "warmup": args.warmup, "draws": args.draws}
    started = time.perf_counter()
    baseline = stancal.calibrate(data, simulator=problem.simulator, mean_intercept=True, seed=args.seed,
                                 new_points=data.source.reset_index(drop=True), **sampling)
    baseline_s = time.perf_counter() - started
    base_score = psis_score(baseline)
    base_mc = mc_variance(baseline)
    out = {"sampling": sampling, "baseline_s": round(baseline_s, 1),
           "baseline_high_k": int((base_score.pareto_k > PARETO_K_LIMIT).sum()), "fits": []}
    print(json.dumps(out), flush=True)
    candidates = {c.name: c for c in problem.candidates}
    for repeat in range(args.repeats):
        for name in args.candidates:
            c = candidates[name]
            fitted = variant_data(data, c) if c.kind == "variant" else data
            model = ({"simulator": c.stan} if c.kind == "variant"
                     else {"simulator": problem.simulator, "mean_formula": c.formula})
            for mode in MODES:
                seed = args.seed + 100 * (repeat + 1)
                options = dict(sampling)
                if mode != "cold":
                    options["draws"] = args.draws // 2
                started = time.perf_counter()
                if mode == "warm":
                    options.update(warm_candidate_options(baseline, bounds_of(fitted.parameters), sampling, seed))
                fit = stancal.calibrate(fitted, mean_intercept=True, seed=seed,
                                        new_points=fitted.source.reset_index(drop=True), **model, **options)
                row = {"candidate": name, "mode": mode, "repeat": repeat,
                       **figures(fit, base_score, base_mc, time.perf_counter() - started, baseline_s)}
                out["fits"].append(row)
                print(json.dumps(row), flush=True)
                if args.json:
                    args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
