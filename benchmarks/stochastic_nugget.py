"""Where the stochastic_cooling emulator's nugget per setting (0.29 degC,
stage 1) comes from, by numpy stage 1 alone (scalable_emulator's
fit_hyperparameters: emulator.stan's posterior mode, its Jacobian included).
For the case study's runs and runs made again by make_data.runs (seeds 1-3):
(a) every run, the TRUE intrinsic variance V given; (b) V estimated as
stancal does (run_variance.intrinsic_variance); (d) the settings' averages
with V / 5 (stochastic kriging on averages: equal to (a) if the shared
nugget is right); (c) Newton's law itself at the settings, no scatter, one
run each, no V (the stationary GP's misfit); (e) the same with V / 5 on the
diagonal; (a)'s mode without the log nugget's Jacobian, and the log
posterior's drop from it to a nugget of 0. Then the case's settings with fresh scatter (seeds 1-6), V given.
docs/noise.md quotes it.

    .venv/bin/python benchmarks/stochastic_nugget.py
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from scipy import optimize  # noqa: E402

import stancal  # noqa: E402
from stancal.fitting.run_variance import intrinsic_variance  # noqa: E402
from stancal.numerics.scalable_emulator import fit_hyperparameters, negative_log_posterior, pack  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.problem.run_replicates import RunReplicates  # noqa: E402
from stancal.stan.standata import emulator_run_data  # noqa: E402

CASE = ROOT / "case_studies" / "stochastic_cooling"
_spec = importlib.util.spec_from_file_location("make_data", CASE / "make_data.py")
make_data = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_data)


def nugget_degc(xt: np.ndarray, y: np.ndarray, scale: float, known: np.ndarray | None = None) -> float:
    return fit_hyperparameters(xt, y, 1, known=known)[0].nugget * scale


def without_nugget_jacobian(u: np.ndarray, xt: np.ndarray, y: np.ndarray, known: np.ndarray):
    """negative_log_posterior without the log nugget's Jacobian: the mode on the nugget's own scale."""
    value, gradient = negative_log_posterior(u, xt, y, known)
    return value + u[-1], gradient + np.eye(len(u))[-1]


def jacobian_and_zero(xt: np.ndarray, y: np.ndarray, scale: float, known: np.ndarray) -> dict[str, float]:
    """(a)'s nugget without the Jacobian, and how far below its mode (log
    posterior, no Jacobian) a nugget of 1e-4 sd is, the others at (a)'s mode."""
    u = pack(fit_hyperparameters(xt, y, 1, known=known)[0])
    mode = optimize.minimize(without_nugget_jacobian, u, args=(xt, y, known), jac=True, method="L-BFGS-B")
    at_zero = without_nugget_jacobian(np.r_[u[:-1], np.log(1e-4)], xt, y, known)[0]
    return {"(a) no Jacobian": float(np.exp(mode.x[-1]) * scale), "log post drop at 0": at_zero - mode.fun}


def one_data_set(base: stancal.CalibrationData, runs) -> dict[str, float]:
    data = stancal.CalibrationData(base.physical, ["t", "T0"], "temperature", {"k": (0.02, 0.1)}, runs=runs)
    r = emulator_run_data(data)
    xt, y, scale = np.hstack([r["x_sim"], r["theta_sim"]]), np.asarray(r["y_sim"]), data.scaling.y_scale
    true_v = (make_data.intrinsic_sd(runs["t"].to_numpy()) / scale) ** 2
    surface, _ = intrinsic_variance(data, True, 1)
    exact = data.scaling.standardise(make_data.newton(runs["t"], runs["T0"], runs["k"]).to_numpy())
    settings = RunReplicates.of(xt, y)  # the runs grouped by setting, as stage 1 groups them
    mean = RunReplicates.of(xt, exact).means  # Newton's law at each setting
    v_mean = RunReplicates.of(xt, true_v).means / settings.counts  # the variance of a setting's average
    return {"(a) V true": nugget_degc(xt, y, scale, true_v),
            "(b) V estimated": nugget_degc(xt, y, scale, surface.at(xt)),
            "(d) averages, V/5": nugget_degc(settings.settings, settings.means, scale, v_mean),
            "(c) mean, no V": nugget_degc(settings.settings, mean, scale),
            "(e) mean, V/5": nugget_degc(settings.settings, mean, scale, v_mean),
            **jacobian_and_zero(xt, y, scale, true_v)}


def fresh_scatter(base: stancal.CalibrationData, seeds: range) -> list[float]:
    runs = base.runs
    r = emulator_run_data(base)
    xt, scale = np.hstack([r["x_sim"], r["theta_sim"]]), base.scaling.y_scale
    sd = make_data.intrinsic_sd(runs["t"].to_numpy())
    mean = make_data.newton(runs["t"], runs["T0"], runs["k"]).to_numpy()
    return [nugget_degc(xt, base.scaling.standardise(mean + sd * np.random.default_rng(s).standard_normal(len(sd))),
                        scale, (sd / scale) ** 2) for s in seeds]


def main() -> None:
    base = load_config(CASE / "config.toml").data
    for seed in ("case", 1, 2, 3):
        runs = base.runs if seed == "case" else make_data.runs(np.random.default_rng(seed))
        found = one_data_set(base, runs)
        print(f"runs {seed}: " + ", ".join(f"{k} {v:.3f}" for k, v in found.items())
              + " (degC; the drop in log units)", flush=True)
    print("the case's settings, fresh scatter (seeds 1-6), V true:",
          ", ".join(f"{v:.3f}" for v in fresh_scatter(base, range(1, 7))), "degC")


if __name__ == "__main__":
    main()
