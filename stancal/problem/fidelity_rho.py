"""The form of the scale between two fidelities, rho in
f_k(x, theta) = rho_k(x) f_{k-1}(x, theta) + g_k(x, theta) (Kennedy &
O'Hagan 2000, section 2.1; docs/multifidelity.md):

- ``constant``: one number per level (the default);
- ``linear``: rho_k(x) = beta_0 + x' beta_x, a regression on the simulator's
  inputs x (Le Gratiet & Garnier 2014, section 2, write rho as a regression
  on the inputs, g(x)' beta_rho). It depends on x alone, not on theta: at
  the physical points, which share theta, the levels' weights stay data.

The rules, checked before anything compiles, each refusal one line: a known
form; a non-constant form needs low-fidelity runs; not yet with a cheap
level's own theta_l (Goh et al. 2013), whose stage 1 fits a constant rho;
and a linear rho needs each upper level's runs to tell its coefficients
apart (check_rho_identified).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from stancal.problem.validation import DataError

RHO_FORMS = ("constant", "linear")


def check_low_fidelity_rho(form: str, low_fidelity_levels: int, theta_low: bool) -> str:
    """The form, checked (DataError naming the problem)."""
    if form not in RHO_FORMS:
        raise DataError(f"low-fidelity rho must be one of {', '.join(RHO_FORMS)}; got {form!r}")
    if form != "constant" and not low_fidelity_levels:
        raise DataError(f"low-fidelity rho = {form!r} needs low-fidelity runs: it is the scale between two levels")
    if form != "constant" and theta_low:
        raise DataError(f"low-fidelity rho = {form!r} is not yet available with the cheap simulator's own theta_l "
                        "([simulator.low_fidelity.theta]); use rho = \"constant\" there")
    return form


def rho_slopes(form: str, inputs: int) -> int:
    """How many slopes a level's rho has: one per simulator input when linear, none when constant."""
    return inputs if form == "linear" else 0


def check_rho_identified(form: str, runs_by_level: list[pd.DataFrame], inputs: list[str]) -> None:
    """A linear rho's intercept and slopes are learned, at each level above
    the cheapest, from that level's runs alone: an input the level's runs
    hold constant trades its slope against the intercept, and fewer runs
    than twice the coefficients let the fit drive the level's own GP to zero
    and claim no error (found in review: 3 expensive runs over 2 inputs).
    DataError naming the level and the input."""
    if form != "linear":
        return
    for level, runs in enumerate(runs_by_level[1:], start=2):
        x = runs[inputs].to_numpy(dtype=float)
        flat = [name for name, column in zip(inputs, x.T, strict=True) if np.ptp(column) == 0]
        if flat:
            raise DataError(f"low-fidelity rho = 'linear': level {level}'s runs hold input(s) {flat} constant, so "
                            "rho's slope there cannot be told from its intercept; use rho = \"constant\" or vary them")
        needed = 2 * (len(inputs) + 1)
        if len(runs) < needed or np.linalg.matrix_rank(np.column_stack([np.ones(len(x)), x])) < len(inputs) + 1:
            raise DataError(f"low-fidelity rho = 'linear' has {len(inputs) + 1} coefficients per level; level "
                            f"{level} has {len(runs)} runs (at least {needed} spread over the inputs are needed); "
                            "use rho = \"constant\"")
