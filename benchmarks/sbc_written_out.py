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
each row's noise s_i = noise_sd exp(g[loc_i] - mean g), the jitter;
tests/test_hetero_noise.py's modular_law, which its tests check against
modular.stan's log density and simulated readings), then
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
from test_hetero_noise import modular_law, numpy_modular_log_density  # noqa: E402  (the written-out model)

from stancal.diagnosing.sbc_ranks import fractional_ranks, rank_of, uniformity  # noqa: E402
from stancal.fitting.calibrate import calibrate  # noqa: E402
from stancal.fitting.plan import make_plan, model_keywords  # noqa: E402
from stancal.stan.standata import build_stan_data, to_stan_json  # noqa: E402

FAMILY = "modular_heteroscedastic"
DRAWS_PER_FIT = 100


def prior_draw(d: dict, rng: np.random.Generator) -> dict:
    """One draw of the parameters from modular.stan's priors (standardised units; Stan's names and shapes)."""
    mu, sigma = d["noise_length_scale_prior"]
    return {"theta_unit": rng.uniform(size=1), "noise_sd": np.abs(rng.normal(size=1)),
            "noise_gp_sd": np.abs(rng.normal(size=1)),
            "noise_length_scale": np.exp(rng.normal(mu, sigma, size=d["D_noise"])),
            "noise_z": rng.standard_normal(d["N_loc"]), "delta_sd": np.abs(rng.normal(0, 0.5, size=1)),
            "delta_input_length_scale": stats.invgamma(3, scale=1).rvs(size=d["D"], random_state=rng)}


def simulation(d: dict, seed: int, s: int) -> tuple[dict, np.ndarray]:
    """Simulation s of the run with --seed seed: its truth (prior_draw) and its standardised readings drawn
    from modular_law given it, from one generator seeded by (seed, s), so that any one can be drawn again."""
    rng = np.random.default_rng([seed, s])
    p = prior_draw(d, rng)
    mean, cov = modular_law(d, p)
    return p, mean + np.linalg.cholesky(cov) @ rng.standard_normal(len(mean))


def truths(d: dict, p: dict, theta_bounds: tuple[float, float]) -> dict[str, float]:
    """The ranked values as the fit's posterior reports them (original units)."""
    low, high = theta_bounds
    return {"theta[k]": low + (high - low) * float(p["theta_unit"][0]),
            "noise_sd": float(p["noise_sd"][0]) * d["y_scale"], "delta_sd": float(p["delta_sd"][0]) * d["y_scale"],
            "noise_gp_sd": float(p["noise_gp_sd"][0])}


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
        point = {name: np.asarray(value).tolist() for name, value in p.items()}
        values.append((model.log_prob(model.unconstrain_pars(point), adjust_transform=False),
                       numpy_modular_log_density(d, p)))
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
        p, y_std = simulation(d, args.seed, s)
        y = d["y_center"] + d["y_scale"] * y_std
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
