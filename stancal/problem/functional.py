"""Functional calibration parameters theta_j(x) (review section 8.2): which
theta vary over which inputs, and the grid their curves are reported on."""

from __future__ import annotations

from itertools import product

import numpy as np
import pandas as pd

from stancal.problem.data import CalibrationData
from stancal.problem.validation import DataError

# points per input of the theta(x) grid: 50 for one input, a coarse product grid for more
GRID_POINTS = {1: 50, 2: 12}
GRID_POINTS_MANY = 6


def check_functional(data: CalibrationData, functional: tuple[str, ...],
                     functional_inputs: tuple[str, ...]) -> None:
    """Names that exist, and inputs the functional theta can vary over."""
    if not functional:
        if functional_inputs:
            raise DataError("functional_inputs given without functional: name the theta that vary")
        return
    unknown = [name for name in functional if name not in data.theta_names]
    if unknown:
        raise DataError(f"functional: {unknown} are not calibration parameters; theta: {data.theta_names}")
    if len(set(functional)) < len(functional):
        raise DataError(f"functional: a parameter is named twice in {list(functional)}")
    if not functional_inputs:
        raise DataError("functional: name the inputs theta(x) varies over with functional_inputs")
    numeric = [*data.inputs, *(c for c in data.covariates if c not in data.levels)]
    bad = [c for c in functional_inputs if c not in numeric]
    if bad:
        raise DataError(f"functional_inputs: {bad} are not numeric simulator inputs or covariates; "
                        f"choose from {numeric}")
    if len(set(functional_inputs)) < len(functional_inputs):
        raise DataError(f"functional_inputs: an input is named twice in {list(functional_inputs)}")


def functional_grid(data: CalibrationData, functional_inputs: tuple[str, ...]) -> pd.DataFrame:
    """A grid over the observed range of the functional inputs."""
    if not functional_inputs:
        return pd.DataFrame(columns=[])
    per_input = GRID_POINTS.get(len(functional_inputs), GRID_POINTS_MANY)
    axes = [np.linspace(data.physical[c].min(), data.physical[c].max(), per_input)
            for c in functional_inputs]
    return pd.DataFrame(list(product(*axes)), columns=list(functional_inputs))
