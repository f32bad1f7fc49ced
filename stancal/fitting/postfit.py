"""The tail every calibration shares once its draws exist: the draws on disk
first, then theta's modes weighed by their posterior mass, the sampler's
checks with their advice, the warnings, and the checked result on disk."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from stancal.results import diagnostics as sampler_checks
from stancal.results import modes as mode_checks

DRAWS_FILE = "posterior.nc"  # in a fit's out_dir


def save_draws(result, out_dir: str | Path | None) -> None:
    """Write the result where the caller asked, if it asked (nothing after
    sampling may lose the draws)."""
    if out_dir is not None:
        result.save(Path(out_dir) / DRAWS_FILE)


def check_fit(result, *, theta_names: list[str], theta_widths: np.ndarray, log_density_functions,
              max_treedepth: int, diagnosed: Callable[[list[str]], list[str]], seed: int,
              advice: Callable[[sampler_checks.Diagnostics], list[str]] = lambda d: [],
              out_dir: str | Path | None = None, runs_theta=None):
    """Modes and sampler checks of ``result``, reported as warnings, and the
    result saved again with them. ``log_density_functions``: a callable that
    gives the program's log density (for the modes' masses) or None where
    theta is not a density's (L2). ``diagnosed``: the posterior's variables
    whose R-hat and ESS are checked, from all of them. ``runs_theta``: the
    theta columns of the runs the emulator learned from (None: no emulator),
    to say which modes lie beyond them (results.modes.beyond_runs)."""
    tree = result.idata
    posterior = tree["posterior"].to_dataset()
    result.modes, weights_unavailable = mode_checks.modes_of(tree, theta_names, theta_widths,
                                                             log_density_functions, seed)
    result.modes = mode_checks.beyond_runs(result.modes, runs_theta)
    result.diagnostics = sampler_checks.check_sampler(
        posterior, tree["sample_stats"].to_dataset(), max_treedepth, diagnosed(list(posterior.data_vars)),
        [m.chains for m in result.modes])
    result.diagnostics.messages.extend(advice(result.diagnostics))
    sampler_checks.report(result.diagnostics)
    mode_checks.report(result.modes, weights_unavailable)
    save_draws(result, out_dir)
    return result
