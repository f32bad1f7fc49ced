"""The cheapest simulator's own calibration parameters theta_l (Goh et al.
2013, Technometrics 55(4), "Prediction and computer model calibration using
outputs from multifidelity simulators"; review section 8.3): the calibrated
simulator is rho f_low(x, theta_l) + g(x, theta), the cheap simulator at its
own best setting plus a GP of its shortfall over (x, theta).

The rules a config or a CalibrationData must meet, checked before anything
compiles, each refusal one line that names the parameter or the column:

- theta_l needs low-fidelity runs, and one level of them (the cheapest level
  has its own parameters; a level between would need a rule for which of
  the two it takes);
- theta_l's names differ from theta's: they are reported side by side, and
  a cheap simulator's best setting is not the physical parameter even when
  both are "k" (name it "k_low");
- the cheap runs carry theta_l's columns and none of theta's: a theta column
  there would say the cheap simulator takes theta too, which this model
  leaves out (Goh et al.'s cheap level depends on (x, theta_l) alone).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import pandas as pd

from stancal.problem.validation import DataError, described


class Named(Protocol):
    name: str


def check_low_fidelity_theta(parameters: Sequence[Named], low_parameters: Sequence[Named],
                             low_runs: Sequence[pd.DataFrame], columns: Sequence[str] = ()) -> None:
    """Refuse theta_l without one level of cheap runs, theta_l named as a
    theta or as a data column (``columns``: inputs, covariates, output), and
    cheap runs with a theta column (DataError naming it)."""
    if not low_parameters:
        return
    names = [p.name for p in low_parameters]
    clash = [name for name in names if name in columns]
    if clash:
        raise DataError(f"low-fidelity theta '{clash[0]}' is also a data column: name the parameter differently")
    if len(low_runs) != 1:
        raise DataError(f"low-fidelity theta {names}: the cheapest simulator's own parameters need exactly one "
                        f"level of low-fidelity runs; got {len(low_runs)}")
    shared = [p.name for p in parameters if p.name in names]
    if shared:
        raise DataError(f"low-fidelity theta '{shared[0]}' is also a theta: name the cheap simulator's own "
                        f"parameter differently (for example '{shared[0]}_low'), in its runs' columns too")
    extra = [p.name for p in parameters if p.name in low_runs[0].columns]
    if extra:
        raise DataError(f"{described('simulator runs', low_runs[0])}: column '{extra[0]}' is a theta, but with "
                        f"a low-fidelity theta the cheap simulator takes its own parameters {names} only; drop "
                        f"the column or declare no low-fidelity theta")
