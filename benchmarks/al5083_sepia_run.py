"""SEPIA's own Al-5083 recipe on a subset of its runs: the reference posterior
for benchmarks/al5083_sepia.py. Runs in a scratch environment with SEPIA
installed (github.com/lanl/SEPIA; Gattiker et al. 2020, the SEPIA software,
LA-UR-20-23691; the model is Higdon et al. 2008, JASA 103), never in stancal's:

    OPENBLAS_NUM_THREADS=1 nice -n 5 /tmp/sepia-venv/bin/python benchmarks/al5083_sepia_run.py \
        --data /tmp/sepia-src/examples/Al_5083/data --subset case_studies/al5083/runs_subset.csv \
        --iterations 4000 --out /tmp/al5083_sepia.json

The settings are those of SEPIA's examples/Al_5083/Al_5083_calibration.py
(velocities V4, V6, V8, V10 of each shot scaled by 10,000; Sigy = diag(0.01 y);
standardize_y(); transform_xt(); 11 principal components; no discrepancy;
lamWs' prior Gamma(1, 0) without an upper bound, "to match Matlab"; lamOs
sampled with SEPIA's default prior; tune_step_sizes(100, 25); then
do_mcmc). Two changes, both stated in docs/al5083.md: only the subset's runs,
and theta scaled to [0, 1] over the config's box (t_range) rather than over
the subset's own range, so that both tools share one prior box. The first
half of the iterations is dropped as burn-in unless --burn says otherwise.

--fix-lamos fixes SEPIA's observation-precision scale lamOs at 1 (SEPIA's
SepiaModel.set_param('lamOs', fix=1)), so the observation covariance is Sigy
itself: the known-noise model stancal fits with noise = "known". --deadline
(UTC, HH:MM) stops sampling at the first checkpoint (every --chunk
iterations) past it; every checkpoint rewrites the record and an .npz with the
draws of theta and of every hyperparameter, so a run cut short still leaves
its draws."""

from __future__ import annotations

import argparse
import json
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

SHOTS = ("104S", "105S", "106S")
SELECTED = [3, 5, 7, 9]  # the example's sel_features: V4, V6, V8, V10
BOX = {"a": (0.0005, 0.01), "b": (0.0005, 0.01), "c": (0.0, 0.03), "x_n": (0.0, 1.5), "x_m": (0.0, 3.0),
       "vel1": (0.0192, 0.0216), "vel2": (0.0334, 0.0376), "vel3": (0.0455, 0.0513), "G1": (0.2, 0.5),
       "delta2": (0.0, 0.1), "delta3": (0.0, 0.2)}  # case_studies/al5083/config.toml's [simulator.theta]


def load(data: Path, runs: np.ndarray):
    """The example's arrays, restricted to the subset's runs."""
    sim = [np.genfromtxt(data / f"features_cdf{s}.csv", delimiter=",", skip_header=1) for s in SHOTS]
    obs = [np.genfromtxt(data / f"features_cdf_obs{s}.csv", delimiter=",", skip_header=1) for s in SHOTS]
    design = np.loadtxt(data / "Al.trial5.design.txt", skiprows=1)
    names = (data / "Al.trial5.design.txt").read_text().split("\n")[0].split()
    y_sim = 10000 * np.concatenate([s[:, SELECTED] for s in sim], axis=1)
    y_obs = np.concatenate([o[SELECTED] for o in obs])[None, :]
    return design[runs], y_sim[runs], y_obs, names


def model_for(design, y_sim, y_obs, names):
    from sepia.SepiaData import SepiaData
    from sepia.SepiaModel import SepiaModel
    n = y_obs.shape[1]
    y_ind = np.arange(1, n + 1)
    data = SepiaData(t_sim=design, y_sim=y_sim, y_ind_sim=y_ind, y_obs=y_obs, y_ind_obs=y_ind,
                     Sigy=np.diag(0.01 * y_obs[0]))
    data.standardize_y()
    data.transform_xt(t_range=np.array([[BOX[p][k] for p in names] for k in (0, 1)]))
    data.create_K_basis(n - 1)
    model = SepiaModel(data)
    model.params.lamWs.prior.bounds[1] = np.inf
    model.params.lamWs.prior.params = [np.ones((1, 11)), np.zeros((1, 11))]
    return model


def summarise(theta: np.ndarray, names: list[str]) -> dict:
    """Mean and sd per theta, on SEPIA's [0, 1] scale and in the data's units."""
    out = {}
    for j, p in enumerate(names):
        lo, hi = BOX[p]
        u = theta[:, j]
        out[p] = {"mean_unit": float(u.mean()), "sd_unit": float(u.std(ddof=1)),
                  "mean": float(lo + (hi - lo) * u.mean()), "sd": float((hi - lo) * u.std(ddof=1)),
                  "sd_over_prior_sd": float(u.std(ddof=1) * np.sqrt(12))}
    return out


def save(model, args, record: dict, burn: int, names: list[str]) -> None:
    """Rewrite the record and the draws (all iterations, burn-in included) from the model's samples so far."""
    draws = model.get_samples(numsamples=None, nburn=0)
    np.savez(args.out.with_suffix(".draws.npz"), **{k: np.asarray(v) for k, v in draws.items()})
    done = draws["theta"].shape[0]
    theta = draws["theta"][burn:]
    record.update({"iterations": int(done), "burn": int(burn), "kept": int(theta.shape[0]),
                   "theta": summarise(theta, names) if theta.shape[0] > 1 else {}})
    args.out.write_text(json.dumps(record, indent=2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--subset", type=Path, required=True)
    parser.add_argument("--iterations", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--burn", type=int, default=None, help="iterations dropped (default: half)")
    parser.add_argument("--fix-lamos", action="store_true", help="fix lamOs at 1 (known noise)")
    parser.add_argument("--deadline", default=None, help="UTC HH:MM: stop at the first checkpoint past it")
    parser.add_argument("--chunk", type=int, default=100, help="iterations between checkpoints")
    args = parser.parse_args()
    runs = np.unique(np.loadtxt(args.subset, delimiter=",", skiprows=1, usecols=0).astype(int))
    design, y_sim, y_obs, names = load(args.data, runs)
    np.random.seed(args.seed)  # SEPIA draws from numpy's global generator
    model = model_for(design, y_sim, y_obs, names)
    if args.fix_lamos:
        model.set_param("lamOs", fix=1.0)
    burn = args.iterations // 2 if args.burn is None else args.burn
    stop = None
    if args.deadline:
        hh, mm = (int(v) for v in args.deadline.split(":"))
        stop = datetime.now(UTC).replace(hour=hh, minute=mm, second=0, microsecond=0).timestamp()
    started = time.perf_counter()
    model.tune_step_sizes(100, 25)
    tuned = time.perf_counter()
    record = {"runs": int(len(runs)), "planned_iterations": args.iterations, "seed": args.seed,
              "lamOs": "fixed at 1" if args.fix_lamos else "sampled", "tune_s": tuned - started}
    done = 0
    while done < args.iterations:
        step = min(args.chunk, args.iterations - done)
        model.do_mcmc(step, prog=False, no_init=done > 0)
        done += step
        record.update({"mcmc_s": time.perf_counter() - tuned,
                       "s_per_iteration": (time.perf_counter() - tuned) / done,
                       "stopped_at_deadline": False})
        if stop is not None and time.time() > stop and done < args.iterations:
            record["stopped_at_deadline"] = True
            save(model, args, record, burn, names)
            break
        save(model, args, record, burn, names)
        print(f"{done} iterations, {record['s_per_iteration']:.3f} s each", flush=True)
    print(json.dumps(record, indent=2))

if __name__ == "__main__":
    main()
