"""Stan data of the vector-output programs (koh_vector.stan, modular_vector.stan),
built from a VectorCalibrationData; the registry names which parts a program takes."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from stancal.numerics.vector_emulator import VectorEmulator, same_point
from stancal.problem.codes import NOISE_MODES
from stancal.problem.mean_terms import MeanTerms, build_mean_terms
from stancal.problem.options import VectorOptions
from stancal.problem.vector_data import VectorCalibrationData


@dataclass(frozen=True)
class VectorStanInputs:
    """What every part of a vector program's Stan data is built from."""

    data: VectorCalibrationData
    options: VectorOptions
    new_rows: pd.DataFrame  # where f, delta and zeta are drawn
    emulator: VectorEmulator | None  # stage 1, for the programs from runs


def build_vector_stan_data(data: VectorCalibrationData, parts, options: VectorOptions, new_rows: pd.DataFrame,
                           emulator: VectorEmulator | None = None) -> dict[str, Any]:
    """A vector program's Stan data: the registry row's ``parts``, merged in order."""
    inputs = VectorStanInputs(data, options, new_rows, emulator)
    out: dict[str, Any] = {}
    for part in parts:
        out.update(part(inputs))
    return out


def simulator_at_values(inputs: VectorStanInputs) -> dict[str, Any]:
    """koh_vector.stan: the Stan simulator at every measured value."""
    return koh_vector_data(inputs.data, inputs.options, mean_terms(inputs.data, inputs.options), inputs.new_rows)


def basis_emulator(inputs: VectorStanInputs) -> dict[str, Any]:
    """modular_vector.stan: the runs' basis and stage 1's emulator."""
    if inputs.emulator is None:
        raise ValueError("this program needs the stage-1 basis emulator")
    return modular_vector_data(inputs.data, inputs.options, inputs.emulator, inputs.new_rows,
                               mean_terms(inputs.data, inputs.options))


def modular_weights(inputs: VectorStanInputs) -> dict[str, Any]:
    """The weight GPs fixed at stage 1 (modular)."""
    return {"joint": 0}


def joint_weights(inputs: VectorStanInputs) -> dict[str, Any]:
    """The weight GPs' hyperparameters sampled with theta (koh_emulator)."""
    return {"joint": 1}


def mean_terms(data: VectorCalibrationData, options: VectorOptions) -> MeanTerms | None:
    if options.mean_formula is None and not options.mean_intercept:
        return None
    return build_mean_terms(options.mean_formula, data.source, intercept=options.mean_intercept)


def _shared_stan_data(data: VectorCalibrationData, options: VectorOptions, new_rows: pd.DataFrame,
                      output_scale: float) -> dict[str, Any]:
    """What both vector programs take: experiments, noise, discrepancy switch,
    theta's bounds, the prediction rows' experiments."""
    if options.noise == "known" and not data.noise_sd:
        raise ValueError("noise = 'known' needs the physical data's noise_sd column")
    physical = data.physical
    number = {name: e + 1 for e, name in enumerate(data.experiments.index)}
    unknown = sorted(set(new_rows[data.experiment].astype(str)) - set(number))
    if unknown:
        raise ValueError(f"prediction rows: experiment(s) {unknown[:5]} are not in the physical data, whose "
                         f"experiments carry the inputs and per-experiment theta the rows need")
    known = (physical[data.noise_sd].to_numpy() / output_scale) if data.noise_sd else np.zeros(len(physical))
    return {
        "E": len(number), "D": len(data.inputs), "Q": len(data.parameters), "Q_exp": len(data.per_experiment),
        "N": len(physical), "experiment": physical[data.experiment].map(number).to_numpy(),
        "K_index": len(data.output_index), "noise_mode": NOISE_MODES[options.noise], "known_noise_sd": known,
        "use_discrepancy": int(options.has_discrepancy),
        "theta_lower": [p.lower for p in data.parameters], "theta_upper": [p.upper for p in data.parameters],
        "theta_exp_lower": [p.lower for p in data.per_experiment],
        "theta_exp_upper": [p.upper for p in data.per_experiment],
        "P": len(new_rows), "experiment_new": new_rows[data.experiment].astype(str).map(number).to_numpy(),
        "prior_only": 0}


def _mean_term_data(terms: MeanTerms | None, rows: int, new_rows: pd.DataFrame) -> dict[str, Any]:
    """H, h, beta_prior_sd and h_new: no terms, or a formula's."""
    if terms is None:
        return {"H": 0, "h": np.zeros((rows, 0)), "beta_prior_sd": np.zeros(0), "h_new": np.zeros((len(new_rows), 0))}
    return {"H": len(terms.names), "h": terms.h, "beta_prior_sd": terms.prior_sd, "h_new": terms.at(new_rows)}


def koh_vector_data(data: VectorCalibrationData, options: VectorOptions, terms: MeanTerms | None,
                    new_rows: pd.DataFrame) -> dict[str, Any]:
    """koh_vector.stan's data."""
    scaling, physical = data.scaling, data.physical
    simulator_columns = [*data.inputs, *data.output_index]
    return dict(
        _shared_stan_data(data, options, new_rows, scaling.y_scale),
        **_mean_term_data(terms, len(physical), new_rows),
        D_cov=len(data.covariate_columns), X=physical[simulator_columns].to_numpy(float),
        x_delta=scaling.to_unit(physical, data.discrepancy_inputs),
        y=scaling.standardise(physical[data.output].to_numpy()), y_center=scaling.y_center,
        y_scale=scaling.y_scale, kernel_id=options.kernel_id,
        X_new=new_rows[simulator_columns].to_numpy(float),
        x_delta_new=scaling.to_unit(data.with_one_hot(new_rows), data.discrepancy_inputs))


def same_emulator_point(x: np.ndarray, per_experiment: int) -> np.ndarray:
    """(E, E): 1 where two experiments' emulator inputs are identical, so
    their weights share the weight GPs' nugget (component_weights in
    functions/vector_output.stan): the same inputs x and no per-experiment
    theta (theta_e differ between experiments, and so do their points).
    With no inputs (``inputs = []``) every experiment is at one point."""
    if per_experiment:
        return np.eye(len(x))
    return same_point(np.asarray(x, float).reshape(len(x), -1)).astype(float)


def fidelity_levels(emulator: VectorEmulator) -> dict[str, Any]:
    """modular_vector.stan's levels of fidelity: each run's level and, per
    component, the cheaper levels' GPs and every level's scale on the one
    below (the top level's own GP is emulator_*); one level without
    cheaper runs, where these are empty."""
    L, C, M = emulator.fidelities, len(emulator.components), len(emulator.xt_runs)
    cheaper = [[lv.hyperparameters for lv in gp.levels[:-1]] if L > 1 else [] for gp in emulator.components]
    return {"n_levels": L, "run_level": np.ones(M, int) if emulator.run_level is None else emulator.run_level + 1,
            "level_rho": np.array([[lv.rho for lv in gp.levels[1:]] if L > 1 else [] for gp in emulator.components],
                                  float).reshape(C, L - 1),
            "level_mean": np.array([[h.mean for h in hs] for hs in cheaper], float).reshape(C, L - 1),
            "level_sd": np.array([[h.sd for h in hs] for hs in cheaper], float).reshape(C, L - 1),
            "level_length_scale": np.array([[h.length_scale for h in hs] for hs in cheaper], float).reshape(
                C, L - 1, emulator.xt_runs.shape[1]),
            "level_nugget": np.array([[h.nugget for h in hs] for hs in cheaper], float).reshape(C, L - 1)}


def modular_vector_data(data: VectorCalibrationData, options: VectorOptions, emulator: VectorEmulator,
                        new_rows: pd.DataFrame, terms: MeanTerms | None = None) -> dict[str, Any]:
    """modular_vector.stan's data (joint = 1 for koh_emulator)."""
    physical, basis = data.physical, data.basis
    mean, components = basis.at(physical[data.output_index].to_numpy())
    mean_new, components_new = basis.at(new_rows[data.output_index].to_numpy())
    hyper = [gp.hyperparameters for gp in emulator.components]
    shared = _shared_stan_data(data, options, new_rows, basis.scale)
    x = data.scaling.to_unit(data.experiments, data.inputs)
    return dict(
        shared, **_mean_term_data(terms, len(physical), new_rows),
        x=x, same_point=same_emulator_point(x, len(data.per_experiment)), D_cov=len(data.covariate_columns),
        z=data.scaling.to_unit(data.experiments, data.covariate_columns),
        index=data.scaling.to_unit(physical, data.output_index),
        y=(physical[data.output].to_numpy() - mean) / basis.scale, output_mean=mean, output_scale=basis.scale,
        C=basis.count, components=components,
        # the truncation error at every value, plus the interpolation error off the runs' grid
        truncation_variance=basis.independent_variance_at(physical[data.output_index].to_numpy()),
        M=len(emulator.xt_runs), xt_runs=emulator.xt_runs,
        run_weights=basis.weights(data.run_outputs) if emulator.run_weights is None else emulator.run_weights,
        emulator_alpha=np.column_stack([gp.alpha for gp in emulator.components]),
        M_variance=len(emulator.variance_runs), variance_runs=emulator.variance_runs + 1,
        emulator_mean=[h.mean for h in hyper], emulator_sd=[h.sd for h in hyper],
        emulator_length_scale=np.array([h.length_scale for h in hyper]),
        emulator_nugget=[h.nugget for h in hyper], **fidelity_levels(emulator),
        index_new=data.scaling.to_unit(new_rows, data.output_index), output_mean_new=mean_new,
        components_new=components_new)
