"""Checks of an approximation after the fit: the Hilbert-space basis
against the fitted length scales (Riutort-Mayol et al. 2023), and the
scalable emulator's covariance taken at one theta against posterior draws."""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np

from stancal.numerics.hsgp import BasisTooLargeError, HSGPBasis, basis_problems, refined_basis
from stancal.numerics.scalable_emulator import MAX_ERROR_RANK
from stancal.problem.data import CalibrationData
from stancal.problem.options import ModelOptions
from stancal.stan.standata import scalable_emulator_of

logger = logging.getLogger("stancal")

# a discrepancy below this fraction of the noise sd is not checked against its basis
NEGLIGIBLE_DISCREPANCY = 0.1
VARIANCE_TOLERANCE = 0.05  # relative change of the observations' predictive sd worth telling


def check_emulator_variance(tree, data: CalibrationData, emulator: dict[str, Any],
                             stan_json: dict[str, Any]) -> list[str]:
    """The emulator's covariance entered the fit at one theta (its basis
    columns, plus the rest as one variance averaged over the points): how
    far each observation's predictive sd is from the one the fit gave it, at
    posterior draws of theta; told when it matters."""
    theta_unit = (np.asarray(tree["posterior"]["theta"]).reshape(-1, len(data.parameters))
                  - data.theta_lower) / (data.theta_upper - data.theta_lower)
    state = scalable_emulator_of(data, emulator["hyperparameters"])
    x = data.scaling.to_unit(data.physical, data.inputs)
    noise_var = (float(np.median(np.asarray(tree["posterior"]["noise_sd"]))) / data.scaling.y_scale) ** 2
    columns = np.asarray(stan_json["emulator_error_basis"]).reshape(len(x), -1)
    plug_in = noise_var + (columns**2).sum(1) + float(stan_json["emulator_variance"])
    rng = np.random.default_rng(0)
    variances = [state.variance(x, theta) for theta in theta_unit[rng.choice(len(theta_unit), 8, replace=False)]]
    # the sd each observation should have had, against the one the fit gave it
    moved = max(float(np.max(np.abs(np.sqrt((noise_var + v) / plug_in) - 1))) for v in variances)
    emulator["variance_check"] = {
        "max_relative_change_of_sd": moved,
        "max_emulator_sd_over_noise_sd": float(np.sqrt(max(v.max() for v in variances) / noise_var)),
        "error_basis_rank": columns.shape[1]}
    messages = [] if columns.shape[1] < MAX_ERROR_RANK else [
        (f"the emulator's error at the points entered the fit through its {MAX_ERROR_RANK} leading "
        f"eigenvectors, the most stancal takes; the rest was treated as independent between points, "
        f"which narrows theta's band if it is large: more runs would shrink it")]
    if moved <= VARIANCE_TOLERANCE:
        return messages
    return messages + [
        (f"the emulator's covariance entered the fit at theta's least-squares fit; at posterior draws of theta "
        f"an observation's predictive sd differs from the one used by up to {moved:.0%}: theta's band may be "
        f"off by about as much. More runs where the posterior lies, or approximation = 'exact' on a "
        f"subsample, would settle it")]


def _with_basis(options: ModelOptions, basis: HSGPBasis) -> ModelOptions:
    return replace(options, basis_functions=basis.counts, boundary_factor=basis.boundary_factors)


def check_basis(tree, data: CalibrationData, options: ModelOptions,
                 chosen_by_user: bool) -> tuple[ModelOptions, bool, list[str]]:
    """Riutort-Mayol et al.'s check of the basis against the fitted length
    scales; a basis stancal chose is rebuilt from them once (refit = True)."""
    posterior = tree["posterior"]
    if np.median(posterior["delta_sd"]) < NEGLIGIBLE_DISCREPANCY * np.median(posterior["noise_sd"]):
        return options, False, []  # no shape worth representing: its length scales are the prior's
    widths = np.array([data.scaling.width[c] for c in data.discrepancy_inputs])
    fitted = np.asarray(posterior["delta_length_scale"]).reshape(-1, len(widths)) / widths
    basis = HSGPBasis(options.basis_functions, options.boundary_factor)
    problems = basis_problems(basis, options.kernel, fitted, data.discrepancy_inputs)
    if not problems:
        return options, False, []
    advice = "set basis_functions and boundary_factor per input to change it"
    if not chosen_by_user:
        try:
            better = refined_basis(options.kernel, basis, fitted, data.discrepancy_inputs)
        except BasisTooLargeError as err:
            advice = str(err)
        else:
            logger.info("Hilbert-space basis: %s; refitting with %s", "; ".join(problems), better.describe())
            return _with_basis(options, better), True, []
    return options, False, [(f"the Hilbert-space discrepancy's basis ({basis.describe()}) may be inadequate: "
                            f"{'; '.join(problems)}. {advice}")]
