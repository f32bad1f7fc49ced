"""Stan data for each program, built from a CalibrationData."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from stancal.numerics.hsgp import HALF_RANGE, HSGPBasis, first_basis
from stancal.numerics.intrinsic_variance import IntrinsicVariance
from stancal.numerics.parametrization import information_per_point, model_scale_values
from stancal.numerics.quadrature import input_box_quadrature
from stancal.numerics.scalable_emulator import ScalableEmulator
from stancal.problem.codes import DISCREPANCY_PARAMETRIZATION_CODES
from stancal.problem.data import CalibrationData
from stancal.problem.functional import functional_grid
from stancal.problem.mean_terms import MeanTerms, build_mean_terms
from stancal.problem.noise import NO_LOCATIONS, noise_locations, stan_noise_data
from stancal.problem.options import DISCREPANCIES, ModelOptions
from stancal.problem.source_bias import stan_bias_data

EMULATOR_HYPERPARAMETERS = ("emulator_mean", "emulator_sd", "emulator_length_scale", "emulator_nugget")


# more physical points than this: the default prediction points are a subsample,
# since every prediction point adds three values to every stored draw
MAX_DEFAULT_PREDICTION_POINTS = 500


def default_new_points(data: CalibrationData, size: int = 60) -> pd.DataFrame:
    """A grid over the one input when there is one; otherwise the physical
    points (every column, so that formulas over them can be evaluated), a
    fixed random subsample of them when there are many."""
    if len(data.discrepancy_inputs) == 1:
        values = data.physical[data.inputs[0]]
        return pd.DataFrame({data.inputs[0]: np.linspace(values.min(), values.max(), size)})
    points = data.source.reset_index(drop=True)
    if len(points) > MAX_DEFAULT_PREDICTION_POINTS:
        chosen = np.random.default_rng(0).choice(len(points), MAX_DEFAULT_PREDICTION_POINTS, replace=False)
        points = points.iloc[np.sort(chosen)].reset_index(drop=True)
    return points


def mean_terms_of(data: CalibrationData, options: ModelOptions) -> MeanTerms | None:
    if options.mean_formula is None and not options.mean_intercept:
        return None
    return build_mean_terms(options.mean_formula, data.source, intercept=options.mean_intercept,
                            centred=options.mean_centred)


@dataclass(frozen=True)
class StanInputs:
    """What every part of a program's Stan data is built from."""

    data: CalibrationData
    options: ModelOptions
    raw_points: pd.DataFrame  # prediction points as given (formulas read any column)
    points: pd.DataFrame  # the same, validated, categorical covariates one-hot
    emulator: dict[str, Any] | None  # stage 1's hyperparameters, where the program has a stage 1


def build_stan_data(
    data: CalibrationData,
    parts: tuple[Callable[[StanInputs], dict[str, Any]], ...],
    options: ModelOptions,
    new_points: pd.DataFrame,
    prior_only: bool = False,
    emulator_hyperparameters: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """A program's Stan data: the registry row's ``parts``, merged in order."""
    inputs = StanInputs(data, options, new_points, data.check_new_points(new_points), emulator_hyperparameters)
    out: dict[str, Any] = {}
    for part in parts:
        out.update(part(inputs))
    out["prior_only"] = int(prior_only)
    return out


def common_data(inputs: StanInputs) -> dict[str, Any]:
    """What every scalar program takes: sizes, the discrepancy's inputs,
    scaling, mean terms, theta's bounds and the model switches."""
    data, options, s = inputs.data, inputs.options, inputs.data.scaling
    terms = mean_terms_of(data, options)
    h_new = terms.at(inputs.raw_points) if terms else np.zeros((len(inputs.points), 0))
    return {
        "N": len(data.physical),
        "D": len(data.inputs),
        "D_delta": len(data.discrepancy_inputs),
        "Q": len(data.parameters),
        "x_delta": s.to_unit(data.physical, data.discrepancy_inputs),
        "y_center": s.y_center,
        "y_scale": s.y_scale,
        "H": h_new.shape[1],
        "h": terms.h if terms else np.zeros((len(data.physical), 0)),
        "beta_prior_sd": terms.prior_sd if terms else np.zeros(0),
        "h_new": h_new,
        "theta_lower": data.theta_lower,
        "theta_upper": data.theta_upper,
        "use_discrepancy": int(options.has_discrepancy),
        "kernel_id": options.kernel_id,
        "estimate_rho": int(options.estimate_rho),
        "P": len(inputs.points),
        "x_delta_new": s.to_unit(inputs.points, data.discrepancy_inputs),
        # Stan's RNG draws at the prediction points; the PyStan backend gives
        # normals per draw when it reruns generated quantities (backends.base)
        "P_normals": 0,
        "normals_new": np.zeros((0, 2 + len(options.functional))),
    }


def gaussian_outputs(inputs: StanInputs) -> dict[str, Any]:
    """The standardised outputs of the Gaussian programs."""
    data = inputs.data
    return {"y": data.scaling.standardise(data.physical[data.output].to_numpy())}


def noise_model(inputs: StanInputs) -> dict[str, Any]:
    """The measurement noise of the exact Gaussian programs (functions/noise.stan):
    with heteroscedastic noise, the locations of its log sd GP too."""
    locations = noise_locations(inputs.data, inputs.options)
    return {**stan_noise_data(inputs.options.noise, inputs.data.noise, inputs.data.scaling.y_scale),
            **(locations.stan_data() if locations else NO_LOCATIONS)}


def source_biases(inputs: StanInputs) -> dict[str, Any]:
    """Biased measurement sources (functions/source_bias.stan): how many, and each row's."""
    return stan_bias_data(inputs.options.biased_sources, inputs.data.noise)


def latent_outputs(inputs: StanInputs) -> dict[str, Any]:
    """The observation model and functional theta of koh_latent*.stan."""
    return latent_data(inputs.data, inputs.options, inputs.points, inputs.data.trials_at(inputs.raw_points))


def partial_centring(inputs: StanInputs) -> dict[str, Any]:
    """The data's value and information per point on the model scale, for
    koh_latent.stan's partially non-centred discrepancy (functions/latent_partial.stan)."""
    data = inputs.data
    return {"delta_pseudo": model_scale_values(data.observations, _gaussian_values(data)),
            "delta_information": information_per_point(data.observations)}


def simulator_points(inputs: StanInputs) -> dict[str, Any]:
    """The raw inputs where a program's Stan simulator runs."""
    data = inputs.data
    return {"X": data.physical[data.inputs].to_numpy(), "X_new": inputs.points[data.inputs].to_numpy()}


def hsgp_discrepancy(inputs: StanInputs) -> dict[str, Any]:
    """The Hilbert-space discrepancy's basis (hsgp.stan)."""
    x_delta_new = inputs.data.scaling.to_unit(inputs.points, inputs.data.discrepancy_inputs)
    return hsgp_data(inputs.data, inputs.options, x_delta_new)


def restricted_discrepancy(inputs: StanInputs) -> dict[str, Any]:
    """koh.stan's orthogonal and scaled GPs (restricted_gp.stan)."""
    return restricted_gp_data(inputs.data, inputs.options)


def emulator_inputs(inputs: StanInputs) -> dict[str, Any]:
    """The runs and the unit-scaled points of the GP-emulator programs."""
    return {**emulator_run_data(inputs.data), **emulator_points(inputs)}


def emulator_points(inputs: StanInputs) -> dict[str, Any]:
    """The physical and prediction points' simulator inputs, on the unit cube."""
    data = inputs.data
    return {"x": data.scaling.to_unit(data.physical, data.inputs),
            "x_new": data.scaling.to_unit(inputs.points, data.inputs)}


def fidelity_emulator(inputs: StanInputs) -> dict[str, Any]:
    """modular.stan's emulator: every simulator's runs, cheapest first,
    each with its level, and stage 1's hyperparameters of each level's GP
    (one level: the usual emulator; functions/fidelity.stan)."""
    if inputs.emulator is None:
        raise ValueError("this program needs the stage-1 emulator's hyperparameters")
    data, levels = inputs.data, inputs.emulator.get("levels") or [inputs.emulator]
    runs = (theta_low_runs(data, levels[-1].get("theta_low_unit")) if data.theta_low_names
            else fidelity_run_data(data))
    cheaper = sum(r["M"] for r in runs[:-1])  # a stochastic simulator is the calibrated one: its runs come last
    return {**stacked_runs(runs),
            "run_intrinsic_sd": np.concatenate([np.zeros(cheaper),
                                                np.sqrt(run_intrinsic_variance(data, inputs.emulator))]),
            "level_rho": [float(level["rho"]) for level in levels[1:]],
            "level_rho_slope": rho_slope_matrix(levels, len(data.inputs)),
            **theta_low_bounds(data),
            **{name: [level[name] for level in levels] for name in EMULATOR_HYPERPARAMETERS}}


def stacked_runs(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Every level's runs (emulator_run_data's, cheapest first) stacked, each
    run with its level: the runs of functions/fidelity.stan's programs."""
    return {"M": sum(r["M"] for r in runs), "L": len(runs),
            "x_sim": np.vstack([r["x_sim"] for r in runs]),
            "theta_sim": np.vstack([r["theta_sim"] for r in runs]),
            "y_sim": np.concatenate([r["y_sim"] for r in runs]),
            "run_level": np.concatenate([np.full(r["M"], k + 1) for k, r in enumerate(runs)])}


def sampled_fidelity_runs(inputs: StanInputs) -> dict[str, Any]:
    """koh_emulator.stan's runs: every simulator's, cheapest first, each with
    its level, and the points; every level's GP and scale are its parameters
    (one level: the calibrated simulator's runs, as emulator_inputs gives them)."""
    return {**stacked_runs(fidelity_run_data(inputs.data)), **emulator_points(inputs)}


def rho_slope_matrix(levels: list[dict[str, Any]], inputs: int) -> np.ndarray:
    """modular.stan's level_rho_slope: each level's rho slopes on the inputs (zeros: a constant rho)."""
    slopes = np.zeros((len(levels) - 1, inputs))
    for k, level in enumerate(levels[1:]):
        slopes[k] = level.get("rho_slope") or 0.0
    return slopes


def fixed_emulator(inputs: StanInputs) -> dict[str, Any]:
    """Stage 1's hyperparameters, fixed in the modular programs."""
    if inputs.emulator is None:
        raise ValueError("this program needs the stage-1 emulator's hyperparameters")
    return {name: inputs.emulator[name] for name in EMULATOR_HYPERPARAMETERS}


def scalable_emulator(inputs: StanInputs) -> dict[str, Any]:
    """modular_hsgp.stan's precomputed-weight emulator."""
    if inputs.emulator is None:
        raise ValueError("this program needs the stage-1 emulator")
    return scalable_emulator_data(inputs.data, inputs.emulator, inputs.points)


def _gaussian_values(data: CalibrationData) -> np.ndarray:
    """koh_latent*.stan's y_real: a Gaussian output standardised where it is
    observed exactly, 0 where it is censored or not Gaussian."""
    obs = data.observations
    return np.where(obs.observed & obs.is_gaussian, data.scaling.standardise(np.nan_to_num(obs.value)), 0.0)


def latent_data(data: CalibrationData, options: ModelOptions, new_points: pd.DataFrame,
                trials_new: np.ndarray) -> dict[str, Any]:
    """The observation model and functional theta of koh_latent*.stan."""
    obs = data.observations
    grid = functional_grid(data, options.functional_inputs)
    slots = [options.functional.index(name) + 1 if name in options.functional else 0
             for name in data.theta_names]
    fun_inputs = list(options.functional_inputs)
    # theta(x) is a latent GP over the distinct values only: replicates share them
    distinct, fun_point = np.unique(data.scaling.to_unit(data.physical, fun_inputs), axis=0,
                                    return_inverse=True)
    return {
        "likelihood_id": int(obs.likelihood),
        "y_real": _gaussian_values(data),
        "y_int": np.where(obs.is_gaussian, 0, np.nan_to_num(obs.value)).astype(int),
        "trials": obs.trials,
        "censoring": obs.censoring,
        # infinite bounds are never read (the censoring code says which side is used)
        "lower_bound": np.nan_to_num(data.scaling.standardise(obs.lower), posinf=0.0, neginf=0.0),
        "upper_bound": np.nan_to_num(data.scaling.standardise(obs.upper), posinf=0.0, neginf=0.0),
        "F": len(options.functional),
        "functional_slot": slots,
        "D_fun": len(fun_inputs),
        "N_fun": len(distinct) if fun_inputs else 0,
        "x_fun": distinct if fun_inputs else np.zeros((0, 0)),
        "fun_point": (fun_point.ravel() + 1) if fun_inputs else np.zeros(0, dtype=int),
        "functional_centred": int(options.functional_parametrization == "centred"),
        "delta_centred": DISCREPANCY_PARAMETRIZATION_CODES.get(options.discrepancy_parametrization, 0),
        "G": len(grid),
        "x_fun_grid": data.scaling.to_unit(grid, fun_inputs).reshape(len(grid), len(fun_inputs)),
        "x_fun_new": data.scaling.to_unit(new_points, fun_inputs),
        "trials_new": trials_new,
    }


def hsgp_data(data: CalibrationData, options: ModelOptions, x_delta_new: np.ndarray) -> dict[str, Any]:
    """The Hilbert-space discrepancy's basis (hsgp.stan); prediction points
    must lie inside its boundary, where the basis functions are defined."""
    inputs = data.discrepancy_inputs
    basis = (HSGPBasis(options.basis_functions, options.boundary_factor) if options.basis_functions
             else first_basis(options.kernel, inputs))
    if len(basis.counts) != len(inputs):
        raise ValueError(f"basis_functions and boundary_factor need one value per discrepancy input "
                         f"({', '.join(inputs)}); got {len(basis.counts)}")
    outside = np.abs(x_delta_new - HALF_RANGE) >= basis.boundary
    if outside.any():
        row, column = np.argwhere(outside)[0]
        raise ValueError(f"prediction point {row} lies outside the Hilbert-space discrepancy's boundary "
                         f"in '{inputs[column]}' ({outside.any(axis=1).sum()} points do): the basis "
                         f"covers {basis.boundary_factors[column]:.2f} half-ranges about the centre of "
                         f"the data; raise boundary_factor for it, or predict closer to the data")
    # Stan's RNG draws the basis weights; the PyStan backend gives normals per draw (backends.base)
    return {**basis.stan_data(), "B_normals": 0, "basis_normals": np.zeros(0),
            "longest_length_scale": basis.longest_length_scale(options.kernel)[:len(data.inputs)]}


def scalable_emulator_data(data: CalibrationData, emulator: dict[str, Any],
                           new_points: pd.DataFrame) -> dict[str, Any]:
    """modular_hsgp.stan's emulator: the mean's weights at the physical and
    the prediction points, and its error's covariance at the physical points
    at emulator["variance_theta"]: leading eigenvectors as basis columns, the
    rest as one variance (none before theta is known)."""
    assert data.runs is not None
    s = data.scaling
    state = scalable_emulator_of(data, emulator)
    x = s.to_unit(data.physical, data.inputs)
    theta = emulator.get("variance_theta")
    # results saved before the error basis existed kept no threshold: their fits had none
    error = None if theta is None else state.error_basis(x, np.asarray(theta),
                                                          emulator.get("error_threshold", np.inf))
    columns = np.zeros((len(x), 0)) if error is None else error.columns
    return {
        "emulator_mean": state.hyperparameters.mean,
        "theta_degree": list(state.interpolant.degrees),
        "G": int(np.prod([p + 1 for p in state.interpolant.degrees])),
        "emulator_weights": state.mean_weights(x),
        "emulator_weights_new": state.mean_weights(s.to_unit(new_points, data.inputs)),
        "emulator_error_rank": columns.shape[1],
        "emulator_error_basis": columns,
        # the marginal likelihood takes one independent variance; its spread is checked
        "emulator_variance": 0.0 if error is None else float(error.residual_variance.mean()),
    }


def scalable_emulator_of(data: CalibrationData, stored: dict[str, Any]) -> ScalableEmulator:
    """The stage-1 emulator of modular_hsgp that ``stored`` describes, on the data's runs."""
    runs = emulator_run_data(data)
    known = run_intrinsic_variance(data, stored) if stored.get("intrinsic_variance") else None
    return ScalableEmulator.of(runs["x_sim"], runs["theta_sim"], runs["y_sim"], stored, known)


def run_intrinsic_variance(data: CalibrationData, stored: dict[str, Any]) -> np.ndarray:
    """Each calibrated-simulator run's intrinsic variance, standardised
    units, from stage 1's surface (stancal.numerics.intrinsic_variance);
    zeros for a deterministic simulator (no surface stored)."""
    runs = emulator_run_data(data)
    if not stored.get("intrinsic_variance"):
        return np.zeros(runs["M"])
    surface = IntrinsicVariance.from_json(stored["intrinsic_variance"])
    return surface.at(np.hstack([runs["x_sim"], runs["theta_sim"]]))


def restricted_gp_data(data: CalibrationData, options: ModelOptions) -> dict[str, Any]:
    """koh.stan's data for the orthogonal and scaled GPs (restricted_gp.stan)."""
    n_inputs = len(data.inputs)
    out: dict[str, Any] = {
        "discrepancy_form": DISCREPANCIES[options.discrepancy], "R": 0, "X_quad": np.zeros((0, n_inputs)),
        "x_quad": np.zeros((0, len(data.discrepancy_inputs))), "w_quad": np.zeros(0),
        "scaled_lambda": options.scaled_lambda or float(np.sqrt(len(data.physical)))}
    if options.discrepancy == "orthogonal":
        quadrature = input_box_quadrature(data)
        out.update(R=len(quadrature.weights), X_quad=quadrature.nodes.to_numpy(),
                   x_quad=data.scaling.to_unit(quadrature.nodes, data.discrepancy_inputs),
                   w_quad=quadrature.weights)
    return out


def emulator_run_data(data: CalibrationData, runs: pd.DataFrame | None = None) -> dict[str, Any]:
    """The runs (by default the calibrated simulator's) as the emulator
    programs take them (emulator.stan's data)."""
    runs = data.runs if runs is None else runs
    assert runs is not None
    s = data.scaling
    return {
        "M": len(runs),
        "x_sim": s.to_unit(runs, data.inputs),
        "theta_sim": s.to_unit(runs, data.theta_names),
        "y_sim": data.scaling.standardise(data.runs_on_link_scale(runs)),
    }


def fidelity_run_data(data: CalibrationData) -> list[dict[str, Any]]:
    """Every simulator's runs, cheapest first, as emulator_run_data gives each
    (with a cheap level's own theta_l, as theta_low_runs gives them)."""
    if data.theta_low_names:
        return theta_low_runs(data)
    return [emulator_run_data(data, runs) for runs in data.runs_by_fidelity()]


def theta_low_runs(data: CalibrationData, theta_low_unit: Any = None) -> list[dict[str, Any]]:
    """The cheap and the expensive runs when the cheap simulator has its
    own theta_l (Goh et al. 2013; functions/fidelity_theta.stan): theta_sim
    is (theta, theta_l) on the unit cube, the parameters a simulator lacks at
    the box's centre (cheap runs: theta, unused) or at ``theta_low_unit``
    (expensive runs: stage 1's theta_l; stage 2 samples it)."""
    s = data.scaling
    low, high = data.runs_by_fidelity()
    q, q_low = len(data.theta_names), len(data.theta_low_names)
    at = np.full(q_low, 0.5) if theta_low_unit is None else np.asarray(theta_low_unit, float)

    def level(runs: pd.DataFrame, theta: np.ndarray) -> dict[str, Any]:
        return {"M": len(runs), "x_sim": s.to_unit(runs, data.inputs), "theta_sim": theta,
                "y_sim": s.standardise(data.runs_on_link_scale(runs))}

    return [level(low, np.hstack([np.full((len(low), q), 0.5), s.to_unit(low, data.theta_low_names)])),
            level(high, np.hstack([s.to_unit(high, data.theta_names), np.tile(at, (len(high), 1))]))]


def theta_low_bounds(data: CalibrationData) -> dict[str, Any]:
    """modular.stan's theta_l: how many, and their bounds (none: the levels share theta)."""
    return {"Q_low": len(data.theta_low_names),
            "theta_low_lower": [p.lower for p in data.low_parameters],
            "theta_low_upper": [p.upper for p in data.low_parameters]}


def build_emulator_data(data: CalibrationData, options: ModelOptions) -> dict[str, Any]:
    """Data of emulator.stan (stage 1 of modular calibration)."""
    return {**emulator_run_data(data), "D": len(data.inputs), "Q": len(data.parameters),
            "y_scale": data.scaling.y_scale, "kernel_id": options.kernel_id, "prior_only": 0,
            "run_intrinsic_sd": np.zeros(len(data.runs))}  # stage 1 sets a stochastic simulator's


def to_stan_json(stan_data: dict[str, Any]) -> dict[str, Any]:
    """Plain lists, for PyStan and for storing with a result."""
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in stan_data.items()}
