"""Stage 1's view of the runs' own scatter: the replicated runs found and
reported for every emulator, and, for a stochastic simulator
(``stochastic = True``), its intrinsic variance surface
(stancal.numerics.intrinsic_variance; stochastic kriging, Ankenman, Nelson &
Staum 2010), which the emulator then carries on its runs' diagonal only."""

from __future__ import annotations

import logging

import numpy as np

from stancal.numerics.intrinsic_variance import MIN_SETTINGS, IntrinsicVariance
from stancal.problem.advice import config_key
from stancal.problem.data import CalibrationData
from stancal.problem.run_replicates import RunReplicates, describe
from stancal.stan.standata import emulator_run_data

logger = logging.getLogger("stancal")


def run_replicates(data: CalibrationData) -> RunReplicates:
    """The calibrated simulator's runs grouped by setting, standardised outputs."""
    runs = emulator_run_data(data)
    return RunReplicates.of(np.hstack([runs["x_sim"], runs["theta_sim"]]), runs["y_sim"])


def require_replicates(replicates: RunReplicates) -> None:
    """A stochastic simulator's runs must repeat some setting: its own variance is estimated there."""
    if not replicates.replicated.any():
        raise ValueError(f"{config_key('simulator', 'stochastic', True)} needs replicated runs (equal inputs and "
                         "theta) to estimate the simulator's own variance; the runs have none")


def intrinsic_variance(data: CalibrationData, stochastic: bool, seed: int) -> tuple[IntrinsicVariance | None, dict]:
    """The replicated runs' summary (output units, logged), and for a
    stochastic simulator its intrinsic variance surface (standardised units);
    None for a deterministic one, whose replicates that disagree are warned about."""
    replicates = run_replicates(data)
    summary = {**replicates.summary(data.scaling.y_scale), "stochastic": stochastic}
    logger.info("the runs: %s", describe(summary))
    pooled = summary["pooled_within_replicate_sd"]
    if not stochastic:
        if pooled:
            logger.warning("the simulator's replicated runs disagree (pooled within-replicate sd %.3g): the "
                           "emulator's one nugget takes that scatter as the same everywhere; if the simulator is "
                           "stochastic, set %s", pooled, config_key("simulator", "stochastic", True))
        return None, summary
    require_replicates(replicates)
    chosen = replicates.replicated
    xt = replicates.settings[chosen]
    surface = IntrinsicVariance.fit(xt, replicates.counts[chosen], replicates.variances[chosen], seed)
    sd = np.sqrt(surface.at(xt)) * data.scaling.y_scale
    summary["intrinsic_sd_range"] = [float(sd.min()), float(sd.max())]
    summary["intrinsic_variance_model"] = (
        "GP on the replicated settings' log sample variances (Ankenman, Nelson & Staum 2010)"
        if surface.hyperparameters is not None else
        f"the pooled variance (fewer than {MIN_SETTINGS} replicated settings with scatter)")
    logger.info("stage 1: the simulator's intrinsic sd, %s, from %.3g to %.3g at the replicated settings",
                summary["intrinsic_variance_model"], *summary["intrinsic_sd_range"])
    return surface, summary


def with_replicated_runs(emulator: dict, data: CalibrationData, emulates_runs: bool) -> dict:
    """Stage 1's results with the replicated runs' summary on every program
    that emulates one simulator's runs: koh_emulator, which samples its
    emulator with theta, has no stage 1 to find them. Cheaper simulators'
    runs (multi-fidelity) are not examined: stochastic is not built there."""
    if not emulates_runs or data.runs is None or data.fidelities > 1 or "replicated_runs" in emulator:
        return emulator
    return {**emulator, "replicated_runs": intrinsic_variance(data, stochastic=False, seed=0)[1]}
