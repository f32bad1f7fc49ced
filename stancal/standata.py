"""Stan data for each program, built from a CalibrationData."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from .data import CalibrationData
from .mean_terms import MeanTerms, build_mean_terms
from .models import Kernel, Method
from .quadrature import input_box_quadrature


@dataclass(frozen=True)
class ModelOptions:
    """Choices that change the model, not the sampler."""

    discrepancy: str = "gp"  # see DISCREPANCIES
    kernel: str = "se"  # se | matern52
    estimate_rho: bool = False
    mean_formula: str | None = None  # discrepancy mean terms h(x, z)' beta, e.g. "I(v**2)"
    mean_intercept: bool = False  # a constant term in the discrepancy mean
    scaled_lambda: float | None = None  # scaled GP penalty lambda_z; None = sqrt(N)

    def __post_init__(self) -> None:
        if self.discrepancy not in DISCREPANCIES:
            raise ValueError(f"discrepancy must be one of {', '.join(DISCREPANCIES)}; "
                             f"got {self.discrepancy!r}")
        if self.kernel not in ("se", "matern52"):
            raise ValueError(f"kernel must be 'se' or 'matern52'; got {self.kernel!r}")
        if self.scaled_lambda is not None and not (np.isfinite(self.scaled_lambda) and self.scaled_lambda > 0):
            raise ValueError(f"scaled_lambda must be a positive number; got {self.scaled_lambda!r}")

    @property
    def kernel_id(self) -> int:
        return int(Kernel.SE if self.kernel == "se" else Kernel.MATERN52)

    @property
    def has_discrepancy(self) -> bool:
        return self.discrepancy != "none"


# discrepancy_form in koh.stan; "none" switches the discrepancy off
DISCREPANCIES = {"gp": 1, "orthogonal": 2, "scaled": 3, "none": 1}
RESTRICTED_DISCREPANCIES = ("orthogonal", "scaled")  # restricted_gp.stan, koh.stan only


EMULATOR_HYPERPARAMETERS = ("emulator_mean", "emulator_sd", "emulator_length_scale", "emulator_nugget")


def default_new_points(data: CalibrationData, size: int = 60) -> pd.DataFrame:
    """A grid over the one input when there is one; otherwise the physical
    points (every column, so that formulas over them can be evaluated)."""
    if len(data.discrepancy_inputs) == 1:
        values = data.physical[data.inputs[0]]
        return pd.DataFrame({data.inputs[0]: np.linspace(values.min(), values.max(), size)})
    return data.source.reset_index(drop=True)


def mean_terms_of(data: CalibrationData, options: ModelOptions) -> MeanTerms | None:
    if options.mean_formula is None and not options.mean_intercept:
        return None
    return build_mean_terms(options.mean_formula, data.source, intercept=options.mean_intercept)


def _standardise(data: CalibrationData, values: np.ndarray) -> np.ndarray:
    return (values - data.scaling.y_center) / data.scaling.y_scale


def build_stan_data(
    data: CalibrationData,
    method: Method | str,
    options: ModelOptions,
    new_points: pd.DataFrame,
    prior_only: bool = False,
    emulator_hyperparameters: dict[str, Any] | None = None,
) -> dict[str, Any]:
    method = Method(method)
    s = data.scaling
    terms = mean_terms_of(data, options)
    h_new = terms.at(new_points) if terms else np.zeros((len(new_points), 0))
    new_points = data.check_new_points(new_points)
    out: dict[str, Any] = dict(
        N=len(data.physical),
        D=len(data.inputs),
        D_delta=len(data.discrepancy_inputs),
        Q=len(data.parameters),
        x_delta=s.to_unit(data.physical, data.discrepancy_inputs),
        y=_standardise(data, data.physical[data.output].to_numpy()),
        y_center=s.y_center,
        y_scale=s.y_scale,
        H=h_new.shape[1],
        h=terms.h if terms else np.zeros((len(data.physical), 0)),
        beta_prior_sd=terms.prior_sd if terms else np.zeros(0),
        h_new=h_new,
        theta_lower=data.theta_lower,
        theta_upper=data.theta_upper,
        use_discrepancy=int(options.has_discrepancy),
        kernel_id=options.kernel_id,
        estimate_rho=int(options.estimate_rho),
        prior_only=int(prior_only),
        P=len(new_points),
        x_delta_new=s.to_unit(new_points, data.discrepancy_inputs),
    )
    if method is Method.KOH:
        out["X"] = data.physical[data.inputs].to_numpy()
        out["X_new"] = new_points[data.inputs].to_numpy()
        out.update(restricted_gp_data(data, options))
        return out
    if options.discrepancy in RESTRICTED_DISCREPANCIES:
        raise ValueError(f"discrepancy '{options.discrepancy}' needs method 'koh' (a simulator "
                         f"written in Stan); got method '{method}'")
    if data.runs is None:
        raise ValueError(f"method '{method}' needs simulator runs")
    out.update(emulator_run_data(data))
    out["x"] = s.to_unit(data.physical, data.inputs)
    out["x_new"] = s.to_unit(new_points, data.inputs)
    if method is Method.MODULAR:
        if emulator_hyperparameters is None:
            raise ValueError("method 'modular' needs the stage-1 emulator hyperparameters")
        out.update(emulator_hyperparameters)
    return out


def restricted_gp_data(data: CalibrationData, options: ModelOptions) -> dict[str, Any]:
    """koh.stan's data for the orthogonal and scaled GPs (restricted_gp.stan)."""
    n_inputs = len(data.inputs)
    out: dict[str, Any] = dict(
        discrepancy_form=DISCREPANCIES[options.discrepancy], R=0, X_quad=np.zeros((0, n_inputs)),
        x_quad=np.zeros((0, len(data.discrepancy_inputs))), w_quad=np.zeros(0),
        scaled_lambda=options.scaled_lambda or float(np.sqrt(len(data.physical))))
    if options.discrepancy == "orthogonal":
        quadrature = input_box_quadrature(data)
        out.update(R=len(quadrature.weights), X_quad=quadrature.nodes.to_numpy(),
                   x_quad=data.scaling.to_unit(quadrature.nodes, data.discrepancy_inputs),
                   w_quad=quadrature.weights)
    return out


def emulator_run_data(data: CalibrationData) -> dict[str, Any]:
    """The runs as the emulator programs take them (emulator.stan's data)."""
    assert data.runs is not None
    s = data.scaling
    return dict(
        M=len(data.runs),
        x_sim=s.to_unit(data.runs, data.inputs),
        theta_sim=s.to_unit(data.runs, data.theta_names),
        y_sim=_standardise(data, data.runs[data.output].to_numpy()),
    )


def build_emulator_data(data: CalibrationData, options: ModelOptions) -> dict[str, Any]:
    """Data of emulator.stan (stage 1 of modular calibration)."""
    return {**emulator_run_data(data), "D": len(data.inputs), "Q": len(data.parameters),
            "y_scale": data.scaling.y_scale, "kernel_id": options.kernel_id, "prior_only": 0}


def to_stan_json(stan_data: dict[str, Any]) -> dict[str, Any]:
    """Plain lists, for PyStan and for storing with a result."""
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in stan_data.items()}
