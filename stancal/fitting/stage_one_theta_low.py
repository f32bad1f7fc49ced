"""Stage 1 when the cheap simulator has its own calibration parameters
theta_l (Goh et al. 2013, Technometrics 55(4); stancal.numerics.
multifidelity_theta): the two levels' hyperparameters and theta_l's stage-1
estimate, level by level (Le Gratiet & Garnier 2014); the cheap runs'
leave-one-out value as for any multi-fidelity emulator. Stage 2
(modular.stan) samples theta_l with theta.

The top level's variance is not scaled for its hyperparameters'
uncertainty here (stancal.numerics.multifidelity_variance scales it with
theta shared): its Metropolis chain would have to hold theta_l's inactive
length scales, which it does not yet; the log says so.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from stancal.numerics.multifidelity import cheap_runs_value
from stancal.numerics.multifidelity_theta import fit_levels_theta_low
from stancal.problem.data import CalibrationData
from stancal.stan.standata import theta_low_runs

logger = logging.getLogger("stancal")


def fit_theta_low_emulator(data: CalibrationData, seed: int) -> dict[str, Any]:
    """Stage 1 of a two-level emulator whose cheap level has its own theta_l:
    what fit_fidelity_emulator gives, and theta_l's estimate (unit cube in
    the top level's entry, original units in ``theta_low_stage1``)."""
    started = time.perf_counter()
    q = len(data.theta_names)
    runs = theta_low_runs(data)
    levels, theta_low = fit_levels_theta_low(
        [r["x_sim"] for r in runs], [runs[0]["theta_sim"][:, q:], runs[1]["theta_sim"][:, :q]],
        [r["y_sim"] for r in runs], seed)
    value = cheap_runs_value(levels, seed)
    seconds = time.perf_counter() - started
    lower = np.array([p.lower for p in data.low_parameters])
    upper = np.array([p.upper for p in data.low_parameters])
    estimate = dict(zip(data.theta_low_names, (lower + (upper - lower) * theta_low).tolist(), strict=True))
    logger.info("stage 1: 2 levels of fidelity (%d + %d runs), the cheap one with its own theta_l (Goh et al. "
                "2013) at %s by stage 1 (stage 2 samples it), scale on it %.3g; leave-one-out error at the "
                "calibrated simulator's runs %.3g with the cheap runs, %.3g without (standardised units); the top "
                "level's variance is not scaled for its hyperparameters' uncertainty with theta_l",
                runs[0]["M"], runs[1]["M"], ", ".join(f"{k} = {v:.4g}" for k, v in estimate.items()), value.rho[0],
                value.loo_with, value.loo_without)
    if value.warning():
        logger.warning("%s", value.warning())
    per_level = [{**lv.hyperparameters.as_stan(), "rho": lv.rho} for lv in levels]
    per_level[-1]["theta_low_unit"] = theta_low.tolist()  # where the expensive runs' cheap part sits in stage 1
    return {
        "hyperparameters": {"levels": per_level},
        "loo_rmse": value.loo_with,
        "loo_rmse_without_low_fidelity": value.loo_without,
        "level_rho": value.rho,
        "theta_low_stage1": estimate,
        "warning": value.warning(),
        "runs_sd": float(data.runs_on_link_scale().std(ddof=1)),
        "stage1": ("multi-fidelity: 2 levels, the cheap one with its own theta_l (Goh et al. 2013), "
                   "hyperparameters and theta_l level by level at their posterior mode (scipy L-BFGS), "
                   "co-kriging given every level's runs"),
        "fit_s": seconds,
    }
