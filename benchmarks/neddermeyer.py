"""Where theta's information goes on SEPIA's Neddermeyer implosion
(case_studies/neddermeyer; Higdon et al. 2008, JASA 103): stancal's
modular fit from the 36 runs, then the same fit with one suspect changed at
a time, each as theta's posterior sd over its prior sd, beside the
near-exact reference (case_studies/neddermeyer/reference.py: the physics
itself, by quadrature, no discrepancy).

    python benchmarks/neddermeyer.py [--chains 2 --warmup 300 --draws 300] [--only NAME ...]

The ablations change the Stan data of one fit and nothing else:
- no_discrepancy: the discrepancy GP left out (use_discrepancy = 0);
- no_truncation: the basis's independent variance (truncation, plus interpolation along time; the runs
  are constant in angle) left out of the likelihood;
- exact_basis: the mean curve and components at the measured indices
  computed from the runs' physics there, not interpolated from the grid;
- known_noise: the noise sd known (0.01 cm), not estimated;
- rescaled: the output standardised by a tenth of its sd (so the priors of
  the noise and the discrepancy, in standardised units, are ten times
  narrower in centimetres);
- joint: koh_emulator, the weight GPs' hyperparameters sampled with theta
  instead of fixed at stage 1's mode (its chains start as calibrate_vector's do);
- physics: koh with the physics itself in Stan (simulator.stan), no
  emulator: the same discrepancy model's near-exact posterior.
``--centre``: every chain starts theta at its box's centre instead of spread
over the box (one chain per stratum), recorded as NAME_centre: without a
discrepancy, chains spread over the box fall into local modes in its
corners (docs/neddermeyer.md), and this measures the main mode alone.
Writes benchmarks/neddermeyer_{config,share995}_basis.json (``--basis``) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import arviz_stats as ast
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "case_studies" / "neddermeyer"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(CASE))

from reference import make_data, reference_posterior  # noqa: E402

from stancal.fitting.plan import plan_vector  # noqa: E402
from stancal.fitting.stage_one import fit_vector_emulator  # noqa: E402
from stancal.fitting.vector_calibrate import chain_inits, prediction_rows  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.problem.data import bounds_of  # noqa: E402
from stancal.problem.options import VectorOptions  # noqa: E402
from stancal.problem.vector_data import VectorCalibrationData  # noqa: E402
from stancal.stan.backends import get_backend  # noqa: E402
from stancal.stan.standata import to_stan_json  # noqa: E402
from stancal.stan.vector_standata import build_vector_stan_data  # noqa: E402


def exact_basis(data, stan_data: dict) -> None:
    """The mean curve and components at the measured (time, angle) from the
    runs' own physics there: k(t) = standardised runs(t)' U / sqrt(m), the
    left singular vectors U of the runs on the grid."""
    basis, physical = data.basis, data.physical
    standardised = (data.run_outputs - basis.mean) / basis.scale
    left, _, _ = np.linalg.svd(standardised, full_matrices=False)
    runs = len(standardised)
    kept = left[:, :basis.count]
    if not np.allclose(standardised.T @ kept / np.sqrt(runs), basis.components, atol=1e-8):
        raise RuntimeError("the basis is not the runs' SVD")
    settings = data.run_settings
    at = make_data.inner_radius(physical["time"].to_numpy(), settings["mass_ratio"].to_numpy(),
                                settings["yield_stress"].to_numpy(), settings["he_energy"].to_numpy())
    mean = at.mean(axis=0)
    stan_data["components"] = ((at - mean) / basis.scale).T @ kept / np.sqrt(runs)
    stan_data["output_mean"] = mean
    stan_data["y"] = (physical[data.output].to_numpy() - mean) / basis.scale


def rescale(stan_data: dict, factor: float = 10.0) -> None:
    """Standardise by scale / factor: y, components and truncation variance in the new units."""
    stan_data["y"] = stan_data["y"] * factor
    stan_data["components"] = stan_data["components"] * factor
    stan_data["components_new"] = stan_data["components_new"] * factor
    stan_data["truncation_variance"] = stan_data["truncation_variance"] * factor**2
    stan_data["known_noise_sd"] = stan_data["known_noise_sd"] * factor
    stan_data["output_scale"] = stan_data["output_scale"] / factor


ABLATIONS = {
    "baseline": ("modular", "gp", lambda data, sd: None),
    "no_discrepancy": ("modular", "none", lambda data, sd: None),
    "no_truncation": ("modular", "gp", lambda data, sd: sd.update(truncation_variance=np.zeros(sd["N"]))),
    "exact_basis": ("modular", "gp", exact_basis),
    "known_noise": ("modular", "gp", lambda data, sd: sd.update(
        noise_mode=0, known_noise_sd=np.full(sd["N"], make_data.NOISE_SD / sd["output_scale"]))),
    "rescaled": ("modular", "gp", lambda data, sd: rescale(sd)),
    "joint": ("koh_emulator", "gp", lambda data, sd: None),
    "joint_no_discrepancy": ("koh_emulator", "none", lambda data, sd: None),
    "physics": ("koh", "gp", lambda data, sd: None),
    "physics_no_discrepancy": ("koh", "none", lambda data, sd: None),
}


def share_basis(data, share: float) -> VectorCalibrationData:
    """The same problem with the basis a variance share keeps (not the example's 3 components)."""
    return VectorCalibrationData(data.source, data.experiment, data.inputs, data.output, data.output_index,
                                 bounds_of(data.parameters), runs=data.runs, run=data.run, variance_share=share)


def fit(name: str, data, emulator, chains: int, warmup: int, draws: int, seed: int, centre: bool = False) -> dict:
    method, discrepancy, change = ABLATIONS[name]
    simulator = CASE / "simulator.stan" if method == "koh" else None
    plan = plan_vector(data, simulator, method, VectorOptions(discrepancy, "one"))
    flat, backend = plan.main_program(), get_backend(None)
    backend.compile([flat])
    new_rows = prediction_rows(data)
    stan_data = build_vector_stan_data(data, plan.program.data, plan.options, new_rows.iloc[:0], emulator)
    change(data, stan_data)
    searched = time.perf_counter()
    inits, start_modes = chain_inits(plan.program, backend, flat, stan_data, emulator, chains, seed)  # as calibrate's
    search_s = time.perf_counter() - searched  # modular's L-BFGS runs before sampling (fitting.inits.mode_inits)
    if centre:
        inits = [init | {"theta_unit": [0.5] * int(stan_data["Q"])} for init in inits]
    started = time.perf_counter()
    sample = backend.sample(flat, to_stan_json(stan_data), inits=inits, chains=chains, warmup=warmup,
                            draws=draws, seed=seed, adapt_delta=0.9, max_treedepth=10)
    seconds = time.perf_counter() - started
    theta = sample.draws["theta_unit"]  # (chain, draw, 2) on [0, 1]: prior sd 1 / sqrt(12)
    print(name, "chain means", theta.mean(axis=1).round(3).tolist(), "chain sds", theta.std(axis=1).round(4).tolist(),
          *(f"{k} {np.median(sample.draws[k], axis=(0, 1)).round(4).tolist()}" for k in
            ("noise_sd", "delta_sd", "delta_input_length_scale") if k in sample.draws and sample.draws[k].size))
    sd = theta.reshape(-1, theta.shape[-1]).std(axis=0) * np.sqrt(12)
    return {"ablation": name + ("_centre" if centre else ""), "method": method, "discrepancy": discrepancy,
            "components": data.basis.count,
            "sd_over_prior": sd.round(4).tolist(), "mean_unit": theta.mean(axis=(0, 1)).round(4).tolist(),
            "max_rhat_theta": float(max(ast.rhat(theta[..., q]) for q in range(theta.shape[-1]))),
            "min_ess_theta": float(min(ast.ess(theta[..., q], method="bulk") for q in range(theta.shape[-1]))),
            "divergences": int(sample.sample_stats["diverging"].sum()), "seconds": round(seconds, 1),
            "start_search_s": round(search_s, 1), "start_modes": [
                {"theta_unit": np.round(m.theta_unit, 3).tolist(), "below_best": round(m.below_best, 1),
                 "mass_below_best": round(m.mass_below_best, 1), "starts": m.starts, "chains": list(m.chains)}
                for m in start_modes]}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--draws", type=int, default=300)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--only", nargs="+", choices=list(ABLATIONS), default=list(ABLATIONS))
    parser.add_argument("--basis", choices=["config", "share995"], default="config",
                        help="the example's 3 components (config.toml), or those a 99.5 %% variance share keeps "
                             "(1: stancal's default before this study)")
    parser.add_argument("--centre", action="store_true", help="start every chain at theta's box centre")
    args = parser.parse_args()
    data = load_config(CASE / "config.toml").data
    if args.basis == "share995":
        data = share_basis(data, 0.995)
    ref = reference_posterior(data.physical)
    emulator = fit_vector_emulator(data, args.seed)
    out = ROOT / "benchmarks" / f"neddermeyer_{args.basis}_basis.json"
    rows = json.loads(out.read_text()) if out.exists() else {}
    rows["reference"] = {"sd_over_prior": ref.sd_over_prior.round(4).tolist(), "correlation": ref.correlation}
    for name in args.only:
        row = fit(name, data, emulator, args.chains, args.warmup, args.draws, args.seed, args.centre)
        rows[row["ablation"]] = row
        print(json.dumps(row), flush=True)
        out.write_text(json.dumps(rows, indent=2))
    print("| fit | yield stress sd / prior sd | HE energy sd / prior sd | R-hat | divergences | sampling (s) |")
    print("|---|---|---|---|---|---|")
    print(f"| reference (physics, quadrature) | {ref.sd_over_prior[0]:.3f} | {ref.sd_over_prior[1]:.3f} | | | |")
    for name, r in rows.items():
        if name != "reference":
            print(f"| {name} | {r['sd_over_prior'][0]:.3f} | {r['sd_over_prior'][1]:.3f} | "
                  f"{r['max_rhat_theta']:.3f} | {r['divergences']} | {r['seconds']:.0f} |")


if __name__ == "__main__":
    main()
