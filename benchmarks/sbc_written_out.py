"""SBC of modular_heteroscedastic with data simulated by numpy from the written-out model, not by Stan.

simulation_based_calibration (stancal.diagnosing.sbc) simulates each data set
with the program itself (prior_only = 1, its y_rep, one chain thinned). The
family modular_heteroscedastic fails it at two seeds (docs/validation.md), yet
its likelihood and its y_rep are one law (tests/test_hetero_noise.py, against
numpy), its prior run's draws follow their priors, and fits four times longer
rank the truths as the short ones did. This script leaves Stan's prior run
out: each truth is drawn by numpy from the priors (priors.stan, noise.stan),
and each data set from the written-out model given it (the stage-1 emulator
given the runs, its nugget shared by a setting's replicates, delta's kernel,
each row's noise s_i = noise_sd exp(g[loc_i] - mean g), the jitter), then
fitted by stancal as SBC fits it (2 x (300 + 100), the same stage 1), and
each truth ranked among 100 thinned draws (Talts et al. 2018,
arXiv:1804.06788). Uniform here and rejected there: the prior run is at
fault; rejected here too: the fits.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/sbc_written_out.py --sims 200 --seed 2 --out DIR

The 200 simulations of seed 2 (finished 2026-11-29) are kept in
benchmarks/sbc_written_out_seed2.jsonl: copy it to DIR/ranks.jsonl for their
summary, or to extend them (every simulation's truth, data and fit seed follow
from --seed and its number); `sbc_heteroscedastic_check.py written` sets them
beside the exact reference.

Each simulation's ranks are a line of DIR/ranks.jsonl, written as it ends (a
rerun resumes); the summary is printed and written to DIR/summary.json
(`--summary-only`: of the simulations finished so far, fitting nothing).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))

import sbc_families  # noqa: E402  (the family's design and options, as its SBC ran them)

from stancal.diagnosing.sbc_ranks import fractional_ranks, rank_of, uniformity  # noqa: E402
from stancal.fitting.calibrate import calibrate  # noqa: E402
from stancal.fitting.plan import make_plan, model_keywords  # noqa: E402
from stancal.numerics.kernels import ard_cross_cov  # noqa: E402
from stancal.problem.codes import Kernel  # noqa: E402
from stancal.stan.standata import build_stan_data, to_stan_json  # noqa: E402

FAMILY = "modular_heteroscedastic"
DRAWS_PER_FIT = 100
JITTER = 1e-6  # add_jitter's share of the prior variance (functions/gp_kernels.stan)


def se(a: np.ndarray, b: np.ndarray, sd: float, length_scale) -> np.ndarray:
    return ard_cross_cov(np.asarray(a, float), np.asarray(b, float), Kernel.SE, sd, np.asarray(length_scale, float))


def prior_draw(d: dict, rng: np.random.Generator) -> dict:
    """One draw of the parameters from modular.stan's priors (standardised units)."""
    mu, sigma = d["noise_length_scale_prior"]
    return {"theta_unit": rng.uniform(size=1), "noise_sd": abs(rng.normal()), "noise_gp_sd": abs(rng.normal()),
            "noise_length_scale": np.exp(rng.normal(mu, sigma, size=d["D_noise"])),
            "noise_z": rng.standard_normal(d["N_loc"]), "delta_sd": abs(rng.normal(0, 0.5)),
            "delta_input_length_scale": stats.invgamma(3, scale=1).rvs(size=d["D"], random_state=rng)}


def law(d: dict, p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the standardised readings given the runs and p (modular.stan's model block)."""
    sd, ls = d["emulator_sd"][0], np.asarray(d["emulator_length_scale"][0])
    mean0, nugget, jitter = d["emulator_mean"][0], d["emulator_nugget"][0], JITTER * sd**2
    x = np.asarray(d["x"])
    xt_sim = np.column_stack([d["x_sim"], d["theta_sim"]])
    xt = np.column_stack([x, np.tile(p["theta_unit"], (len(x), 1))])
    runs = se(xt_sim, xt_sim, sd, ls) + (nugget**2 + jitter) * np.eye(len(xt_sim))
    cross = se(xt, xt_sim, sd, ls)
    mean = mean0 + cross @ np.linalg.solve(runs, np.asarray(d["y_sim"]) - mean0)
    same = (x[:, None, :] == x[None, :, :]).all(-1)
    x_noise, a = np.asarray(d["x_noise"]), p["noise_gp_sd"]
    g = np.linalg.cholesky(se(x_noise, x_noise, a, p["noise_length_scale"]) + JITTER * a**2 * np.eye(len(x_noise))) \
        @ p["noise_z"]
    noise = (p["noise_sd"] * np.exp(g[np.asarray(d["noise_loc"]) - 1] - g.mean())) ** 2
    cov = (se(xt, xt, sd, ls) - cross @ np.linalg.solve(runs, cross.T) + nugget**2 * same
           + se(d["x_delta"], d["x_delta"], p["delta_sd"], p["delta_input_length_scale"]) + np.diag(noise)
           + jitter * np.eye(len(x)))
    return mean, cov


def truths(d: dict, p: dict, theta_bounds: tuple[float, float]) -> dict[str, float]:
    """The ranked values as the fit's posterior reports them (original units)."""
    low, high = theta_bounds
    return {"theta[k]": low + (high - low) * float(p["theta_unit"][0]), "noise_sd": p["noise_sd"] * d["y_scale"],
            "delta_sd": p["delta_sd"] * d["y_scale"], "noise_gp_sd": p["noise_gp_sd"]}


def posterior_values(fit, name: str) -> np.ndarray:
    """A ranked value's draws, chain after chain (theta has one component, k)."""
    return np.asarray(fit.idata["posterior"]["theta" if name == "theta[k]" else name]).reshape(-1)


def setup(seed: int):
    """The family's design and plan with stage 1 from the runs (one short prior run), and the Stan data."""
    design_name, options = sbc_families.FAMILIES[FAMILY]
    data = sbc_families.DESIGNS[design_name]()
    options = dict(options)
    prior = calibrate(data, prior=True, chains=1, warmup=300, draws=100, seed=seed, **options)
    model = model_keywords(options, vector=False)
    plan = replace(make_plan(data, None, options.pop("method"), None, **model), stage_one_result=prior.emulator)
    d = to_stan_json(build_stan_data(data, plan.program.data, plan.options, data.physical.iloc[:2],
                                     emulator_hyperparameters=prior.emulator["hyperparameters"]))
    return data, plan, d


def check_against_stan(plan, d: dict, seed: int) -> float:
    """The written-out model's log likelihood against modular.stan's log density at two prior draws (their
    difference, the priors added by both; the constants cancel): this script simulates the fits' own model."""
    import stan

    from stancal.stan.backends.pystan_compile import compile_programs

    program = plan.main_program()
    compile_programs([program])
    model = stan.build(program.code, data=d, random_seed=1)
    rng, values = np.random.default_rng(seed), []
    for _ in range(2):
        p = prior_draw(d, rng)
        point = {"theta_unit": p["theta_unit"].tolist(), "noise_sd": [p["noise_sd"]], "noise_gp_sd": [p["noise_gp_sd"]],
                 "noise_length_scale": p["noise_length_scale"].tolist(), "noise_z": p["noise_z"].tolist(),
                 "delta_sd": [p["delta_sd"]], "delta_input_length_scale": p["delta_input_length_scale"].tolist()}
        mean, cov = law(d, p)
        mu, sigma = d["noise_length_scale_prior"]
        prior = (stats.norm().logpdf(p["noise_sd"]) + stats.norm().logpdf(p["noise_gp_sd"])
                 + stats.lognorm(sigma, scale=np.exp(mu)).logpdf(p["noise_length_scale"]).sum()
                 + stats.norm().logpdf(p["noise_z"]).sum() + stats.norm(0, 0.5).logpdf(p["delta_sd"])
                 + stats.invgamma(3, scale=1).logpdf(p["delta_input_length_scale"]).sum())
        values.append((model.log_prob(model.unconstrain_pars(point), adjust_transform=False),
                       stats.multivariate_normal(mean, cov).logpdf(d["y"]) + prior))
    return float(abs((values[1][0] - values[0][0]) - (values[1][1] - values[0][1])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sims", type=int, default=200)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--summary-only", action="store_true", help="no fits: the summary of those in OUT")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    lines = args.out / "ranks.jsonl"
    done = {json.loads(line)["simulation"]: json.loads(line) for line in lines.read_text().splitlines()} \
        if lines.exists() else {}
    if args.summary_only:
        return summary(done, args)
    data, plan, d = setup(args.seed)
    mismatch = check_against_stan(plan, d, args.seed)
    print(f"written-out model against modular.stan: log-density differences agree to {mismatch:.1e}")
    if mismatch > 1e-6:
        raise SystemExit("the written-out model is not modular.stan's: nothing simulated")
    theta_bounds = (float(d["theta_lower"][0]), float(d["theta_upper"][0]))
    for s in range(args.sims):
        if s in done:
            continue
        rng = np.random.default_rng([args.seed, s])
        p = prior_draw(d, rng)
        mean, cov = law(d, p)
        y = d["y_center"] + d["y_scale"] * (mean + np.linalg.cholesky(cov) @ rng.standard_normal(len(mean)))
        with warnings.catch_warnings(record=True) as caught:  # the short fits' sampler warnings: counted
            warnings.simplefilter("always")
            fit = calibrate(data.with_output(y), plan=plan, chains=2, warmup=300, draws=DRAWS_PER_FIT,
                            seed=1000 * args.seed + s)
        truth = truths(d, p, theta_bounds)
        record = {"simulation": s, "warnings": len(caught), "truth": truth,
                  "ranks": {name: rank_of(value, posterior_values(fit, name)[::2]) for name, value in truth.items()}}
        with lines.open("a") as handle:
            handle.write(json.dumps(record) + "\n")
        done[s] = record
        print(f"simulation {s}: {record['ranks']}", flush=True)
    summary(done, args)


def summary(done: dict, args: argparse.Namespace) -> None:
    rng = np.random.default_rng(args.seed)
    report = {"simulations": len(done), "draws_per_fit": DRAWS_PER_FIT, "parameters": {}}
    for name in next(iter(done.values()))["ranks"]:
        ranks = np.array([r["ranks"][name] for _, r in sorted(done.items())])
        frac = fractional_ranks(ranks, DRAWS_PER_FIT, rng)
        report["parameters"][name] = {"gamma_p": uniformity(frac, 0.95, args.seed).p_value,
                                      "tenths": np.histogram(frac, bins=10, range=(0, 1))[0].tolist(),
                                      "mean_rank": float(np.mean(ranks) / DRAWS_PER_FIT)}
        print(name, report["parameters"][name])
    (args.out / "summary.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
