"""Does the stage-1 emulator's nugget belong at the physical points? The
emulator's error at the physical points (its mean against the simulator's
mean, Newton's law, at nine values of k across the box) against its
predictive sd there, without and with the nugget: rms z-score and the share
outside the 90 % band (0.10 when the sd is right). docs/noise.md quotes it.

    .venv/bin/python benchmarks/emulator_nugget.py case_studies/cooling/config.toml 0
    .venv/bin/python benchmarks/emulator_nugget.py case_studies/stochastic_cooling/config.toml 0   # deterministic
    .venv/bin/python benchmarks/emulator_nugget.py case_studies/stochastic_cooling/config.toml 1   # stochastic
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from stancal.fitting.plan import model_options, plan_scalar  # noqa: E402
from stancal.fitting.stage_one import emulator_mean_function, run_stage_one  # noqa: E402
from stancal.numerics.kernels import ard_cross_cov  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.stan.backends import get_backend  # noqa: E402
from stancal.stan.standata import run_intrinsic_variance  # noqa: E402


def newton(t, T0, k):
    """Both case studies' simulator mean (ambient 20 deg C)."""
    return 20 + (T0 - 20) * np.exp(-k * t)


def main(config: str, stochastic: bool) -> None:
    data = load_config(config).data
    plan = plan_scalar(data, None, "modular", model_options(stochastic=stochastic))
    emulator = run_stage_one(plan.stage_one, data, plan.options, plan.stan_programs(), backend=get_backend(None),
                             seed=1)
    h, s = emulator["hyperparameters"], data.scaling
    mean_at = emulator_mean_function(data, h, 1)
    runs = np.hstack([s.to_unit(data.runs, data.inputs), s.to_unit(data.runs, data.theta_names)])
    length, sd, nugget = np.asarray(h["emulator_length_scale"]), h["emulator_sd"], h["emulator_nugget"]
    K = ard_cross_cov(runs, runs, 1, sd, length)
    K[np.diag_indices_from(K)] += nugget**2 + run_intrinsic_variance(data, h)
    z_without, z_with, share = [], [], []
    low, high = data.theta_lower[0], data.theta_upper[0]
    x = s.to_unit(data.physical, data.inputs)
    for k in np.linspace(low + 0.1 * (high - low), high - 0.1 * (high - low), 9):
        theta = s.to_unit(pd.DataFrame({data.theta_names[0]: [k]}), data.theta_names)
        cross = ard_cross_cov(np.hstack([x, np.full((len(x), 1), theta[0, 0])]), runs, 1, sd, length)
        variance = sd**2 - np.einsum("ij,ji->i", cross, np.linalg.solve(K, cross.T))
        error = (mean_at(data.physical, theta)[0] - newton(data.physical["t"].to_numpy(),
                                                           data.physical["T0"].to_numpy(), k)) / s.y_scale
        z_without += list(error / np.sqrt(variance))
        z_with += list(error / np.sqrt(variance + nugget**2))
        share += list(nugget**2 / (variance + nugget**2))
    z_without, z_with = np.array(z_without), np.array(z_with)
    print(f"{config} {'stochastic' if stochastic else 'deterministic'}: nugget {nugget * s.y_scale:.3g}, "
          f"rms z without it {np.sqrt(np.mean(z_without**2)):.2f} ({np.mean(abs(z_without) > 1.645):.2f} outside the "
          f"90 % band), with it {np.sqrt(np.mean(z_with**2)):.2f} ({np.mean(abs(z_with) > 1.645):.2f}); "
          f"the nugget's median share of the variance at the points {np.median(share):.2f}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] == "1")
