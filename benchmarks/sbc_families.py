"""Simulation-based calibration of stancal's program families, one table
row each: S simulations, L draws per fit, each parameter's p-value, wall
time on the local Dask cluster (or --scheduler).

    python benchmarks/sbc_families.py [--family koh koh_none] [--sims 200]

Writes benchmarks/sbc.json (merged with earlier rows) and prints the table.
The Gaussian families run on the cooling design (24 points; the shipped
runs for the emulator families): koh with a GP, no, orthogonal or scaled
discrepancy; modular; koh_emulator. The latent families (koh_latent) run on
their test designs: Poisson counts (the detector, 35 points), binomial
successes (the decay survival, 16 points), censored concentrations (the
detection-limit lab, every third of its 90 points, censored by the lab's
two limits) and a functional theta(x) (the beam's E(temperature), 45 points);
modular with two fidelities runs on case_studies/cooling_fidelity (28
points, 150 cheap and 15 expensive runs, no discrepancy); with a cheap
simulator's own theta_l (Goh et al. 2013) on tests/test_multifidelity_theta's
design (12 points, 30 cheap runs over (t, a), 8 expensive over (t, k)); koh_emulator with two
fidelities, every level's GP sampled with theta, on tests/test_multifidelity's design (12 points, 40
cheap and 6 expensive runs: the case study's 193 rows cost too much per gradient for 200 fits).
The noise families (docs/noise.md) run on the cooling design with two
instruments alternating over its rows (one noise sd each), with a known sd
per row rising from 0.1 to 1 degC, or with Student-t noise (its mixture
weights sampled beside a GP, its density used as it is without one).
Heteroscedastic noise runs on case_studies/hetero_noise (80 readings, 4
replicates at each of 20 settings; the cooling runs for modular), its log sd
a GP over t. A stochastic simulator (stochastic kriging) runs on
case_studies/stochastic_cooling, shrunk to keep each fit cheap: every other
reading (20) and 4 of the 5 replicated runs at 31 of its 60 settings, spread over t (124
runs), so its intrinsic variance surface is still fitted (>= 4 replicated
settings). Biased sources: the two instruments, the camera with a bias GP
of its own (koh with and without a discrepancy, modular). A vector output
(calibrate_vector) runs on tests/test_vector_multifidelity's cooling curves,
shrunk so a fit takes seconds: three cool-downs of 8 readings (24 values,
known sd 0.4 degC), 8 expensive curves over 31 times (3 basis components),
and for modular_vector_multifidelity 24 cheap curves too; koh_vector on
tests/test_vector_koh's ragged cool-downs (4 experiments, 44 readings, known
sd 0.3 degC) with cooling_wind's Newton's law in Stan, theta = (k, Ta); each a
GP discrepancy over (T0, t).
"""

from __future__ import annotations

import argparse
import collections
import fcntl
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import pandas as pd  # noqa: E402
from conftest import COOLING, cooling_data  # noqa: E402
from test_latent import BEAM, CENSORED, COUNTS, beam_data, censored_data, exact_counts  # noqa: E402
from test_multifidelity import problem as fidelity_design  # noqa: E402
from test_multifidelity_theta import problem as theta_low_design  # noqa: E402
from test_vector_koh import THETA as VECTOR_THETA  # noqa: E402
from test_vector_koh import WIND  # noqa: E402
from test_vector_multifidelity import problem as vector_fidelity_design  # noqa: E402
from test_vector_outputs import long_experiments  # noqa: E402
from test_vector_sbc import design as vector_design  # noqa: E402

import stancal  # noqa: E402
from stancal.diagnosing.sbc import simulation_based_calibration  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.problem.data import bounds_of  # noqa: E402
from stancal.problem.vector_data import VectorCalibrationData  # noqa: E402

SIMULATOR = COOLING / "simulator.stan"


def binomial_design() -> stancal.CalibrationData:
    t = np.linspace(0.5, 14, 16)
    physical = pd.DataFrame({"t": t, "c0": 0.9, "n": 30, "alive": 0})
    return stancal.CalibrationData(physical, ["t", "c0"], "alive", {"k": (0.01, 0.5)},
                                   likelihood="binomial", trials="n")


def censored_design() -> stancal.CalibrationData:
    return censored_data(pd.read_csv(CENSORED / "physical.csv").iloc[::3].reset_index(drop=True))


def hetero_design() -> stancal.CalibrationData:
    """The hetero_noise case's replicated readings, with the cooling runs (they span its t and T0)."""
    data = load_config(ROOT / "case_studies" / "hetero_noise" / "config.toml").data
    return stancal.CalibrationData(data.source, data.inputs, data.output, bounds_of(data.parameters),
                                   runs=pd.read_csv(COOLING / "runs.csv"))


def noise_design(**columns) -> stancal.CalibrationData:
    """The cooling design, with runs, and the noise columns: instrument (two
    sources, alternating) and sd (a known sd per row, 0.1 to 1 degC)."""
    base = cooling_data(seed=7)
    physical = base.source.assign(instrument=np.where(np.arange(len(base.source)) % 2, "camera", "probe"),
                                  sd=np.linspace(0.1, 1.0, len(base.source)))
    return stancal.CalibrationData(physical, base.inputs, base.output, bounds_of(base.parameters), runs=base.runs,
                                   **columns)


def stochastic_design() -> stancal.CalibrationData:
    """stochastic_cooling's readings and replicated runs, shrunk (the module docstring)."""
    problem = load_config(ROOT / "case_studies" / "stochastic_cooling" / "config.toml")
    data = problem.data
    # settings ranked by t: every other one, and the last, so the runs still span the readings' t
    rank = data.runs.groupby(["t", "T0", "k"]).ngroup()
    kept = (rank % 2 == 0) | (rank == rank.max())
    runs = data.runs[kept].groupby(rank[kept]).head(4).reset_index(drop=True)
    return stancal.CalibrationData(data.source.iloc[::2].reset_index(drop=True), data.inputs, data.output,
                                   bounds_of(data.parameters), runs=runs)


VECTOR_RUNS, VECTOR_CHEAP_RUNS = 8, 24  # expensive and cheap curves of the vector designs


def vector_koh_design() -> VectorCalibrationData:
    """tests/test_vector_koh's ragged cool-downs: 4 experiments, 44 readings (known sd 0.3 degC), no runs."""
    return VectorCalibrationData(long_experiments(1), "exp", ["T0"], "T", "t", VECTOR_THETA, noise_sd="sd")


DESIGNS = {"counts": lambda: exact_counts("poisson", seed=1), "binomial": binomial_design,
           "censored": censored_design, "beam": beam_data,
           "two_sources": lambda: noise_design(source="instrument"), "known_sd": lambda: noise_design(noise_sd="sd"),
           "cooling": lambda: cooling_data(seed=7), "hetero_noise": hetero_design,
           "theta_low": theta_low_design, "stochastic_cooling": stochastic_design,
           "cooling_fidelity": lambda: load_config(ROOT / "case_studies" / "cooling_fidelity" / "config.toml").data,
           "fidelity_small": fidelity_design, "vector_cooling": lambda: vector_design(VECTOR_RUNS),
           "vector_fidelity": lambda: vector_fidelity_design(low=VECTOR_CHEAP_RUNS, high=VECTOR_RUNS),
           "vector_ragged": vector_koh_design}
LATENT = {
    "koh_latent_poisson": ("counts", {"simulator": COUNTS / "simulator.stan", "method": "koh", "discrepancy": "gp"}),
    "koh_latent_binomial": ("binomial", {"simulator": CENSORED / "simulator.stan", "method": "koh",
                                             "discrepancy": "gp"}),
    "koh_latent_censored": ("censored", {"simulator": CENSORED / "simulator.stan", "method": "koh",
                                             "discrepancy": "none"}),
    "koh_latent_functional": ("beam", {"simulator": BEAM / "simulator.stan", "method": "koh", "discrepancy": "none",
                                           "functional": ["E"], "functional_inputs": ["temperature"]}),
}
NOISE = {
    "koh_per_source": ("two_sources", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "gp",
                                       "noise": "per_source"}),
    "koh_known_sd": ("known_sd", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "gp"}),
    "koh_student_t": ("cooling", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "gp", "noise": "student_t"}),
    "koh_none_student_t": ("cooling", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "none",
                                       "noise": "student_t"}),
    "modular_per_source": ("two_sources", {"method": "modular", "discrepancy": "gp", "noise": "per_source"}),
    "modular_student_t": ("cooling", {"method": "modular", "discrepancy": "gp", "noise": "student_t"}),
    "koh_emulator_known_sd": ("known_sd", {"method": "koh_emulator", "discrepancy": "gp"}),
    **{f"{method}_heteroscedastic": ("hetero_noise", {**({"simulator": SIMULATOR} if method == "koh" else {}),
                                                      "method": method, "discrepancy": "gp",
                                                      "noise": "heteroscedastic", "noise_inputs": ["t"]})
       for method in ("koh", "modular")},
    "koh_none_heteroscedastic": ("hetero_noise", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "none",
                                                  "noise": "heteroscedastic", "noise_inputs": ["t"]}),
    "modular_stochastic": ("stochastic_cooling", {"method": "modular", "discrepancy": "gp", "stochastic": True}),
    # one of the two instruments biased, a GP of its own beside the discrepancy (functions/source_bias.stan)
    **{f"{name}_biased_source": ("two_sources", {**options, "noise": "per_source", "biased_sources": ["camera"]})
       for name, options in (("koh", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "gp"}),
                             ("koh_none", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "none"}),
                             ("modular", {"method": "modular", "discrepancy": "gp"}))},
}
FIDELITY = {"modular_multifidelity": ("cooling_fidelity", {"method": "modular", "discrepancy": "none"}),
            "modular_multifidelity_theta_low": ("theta_low", {"method": "modular", "discrepancy": "none"}),
            # every level's GP sampled with theta (the joint path): the small two-level design, a fit a few seconds
            "koh_emulator_multifidelity": ("fidelity_small", {"method": "koh_emulator", "discrepancy": "none"})}
# a vector output (calibrate_vector): the cooling curves, known noise sd
VECTOR = {"modular_vector": ("vector_cooling", {"method": "modular", "discrepancy": "gp"}),
          "modular_vector_multifidelity": ("vector_fidelity", {"method": "modular", "discrepancy": "gp"}),
          "koh_vector": ("vector_ragged", {"simulator": WIND / "simulator.stan", "method": "koh", "discrepancy": "gp"})}
# every family: its design, then its calibrate() options
FAMILIES = {
    "koh": ("cooling", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "gp"}),
    "koh_none": ("cooling", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "none"}),
    "koh_orthogonal": ("cooling", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "orthogonal"}),
    "koh_scaled": ("cooling", {"simulator": SIMULATOR, "method": "koh", "discrepancy": "scaled"}),
    "modular": ("cooling", {"method": "modular", "discrepancy": "gp"}),
    "koh_emulator": ("cooling", {"method": "koh_emulator", "discrepancy": "gp"}),
} | LATENT | NOISE | FIDELITY | VECTOR


def add_row(name: str, row: dict) -> dict:
    """sbc.json with ``row`` added under ``name``: read, changed and written
    under a lock, so that runs of several families side by side keep each
    other's rows."""
    path = Path(__file__).parent / "sbc.json"
    with open(path.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        rows = json.loads(path.read_text()) if path.is_file() else {}
        rows[name] = row
        path.write_text(json.dumps(rows, indent=2))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--family", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    parser.add_argument("--sims", type=int, default=200)
    parser.add_argument("--draws-per-fit", type=int, default=100)
    parser.add_argument("--scheduler", default=None, help="a Dask address; default: a local cluster")
    parser.add_argument("--seed", type=int, default=1, help="the SBC's seed (another seed: chance or a fault?)")
    parser.add_argument("--warmup", type=int, default=300, help="each fit's warm-up per chain")
    parser.add_argument("--draws", type=int, default=None,
                        help="each fit's draws per chain (default: the SBC's, 2 x draws-per-fit over the chains); "
                             "longer fits: is a rejection the model's or short chains'?")
    parser.add_argument("--subset", type=int, default=None,
                        help="fit only this many of the simulations, numpy.random.default_rng(seed).choice(sims, "
                             "SUBSET, replace=False), each as in the whole run (with longer fits: sampler or model?)")
    parser.add_argument("--out", type=Path, default=None,
                        help="keep each simulation's fit, truth and ranked draws under OUT/FAMILY (resumable)")
    args = parser.parse_args()
    subset = None if args.subset is None else \
        sorted(np.random.default_rng(args.seed).choice(args.sims, args.subset, replace=False).tolist())
    for family in args.family:
        started = time.perf_counter()
        # the fits' warnings (sampler trouble in some simulations) are counted into the row, not hidden
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            design, options = FAMILIES[family]
            result = simulation_based_calibration(DESIGNS[design](), simulations=args.sims, scheduler=args.scheduler,
                                                  draws_per_fit=args.draws_per_fit, seed=args.seed,
                                                  warmup=args.warmup, draws=args.draws, subset=subset,
                                                  out_dir=args.out / family if args.out else None, **options)
        kinds = collections.Counter(type(w.message).__name__ for w in caught)  # SamplerWarning: a fit's trouble
        print(f"{family}: warnings {dict(kinds) or 'none'}")
        default_fits = args.warmup == parser.get_default("warmup") and args.draws is None
        longer = ("" if default_fits else f"_warmup{args.warmup}_draws{args.draws}") + \
            ("" if subset is None else f"_subset{args.subset}")
        rows = add_row(family + ("" if args.seed == 1 else f"_seed{args.seed}") + longer, {
            "simulations": result.simulations, "subset_of": None if subset is None else args.sims,
            "draws_per_fit": args.draws_per_fit, "seed": args.seed,
            "warmup": args.warmup, "draws": args.draws, "prior_run": result.prior_run,
            "fits_health": result.fits_health,
            "warnings": dict(kinds),
            "p_values": {n: t.p_value for n, t in result.tests.items()},
            "rejected": [n for n, t in result.tests.items() if t.rejected],
            "failed_simulations": len(result.failed), "seconds": time.perf_counter() - started})
    print("| family | S | L | p-values | rejected | wall time |")
    print("|---|---|---|---|---|---|")
    for family, r in rows.items():
        p = ", ".join(f"{n} {v:.2f}" for n, v in r["p_values"].items())
        print(f"| {family} | {r['simulations']} | {r['draws_per_fit']} | {p} | {', '.join(r['rejected']) or 'none'} "
              f"| {r['seconds']:.0f} s |")


if __name__ == "__main__":
    main()
