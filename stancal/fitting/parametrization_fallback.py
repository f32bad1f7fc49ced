"""The latent discrepancy's other parametrisation, after a fit that
saturates the tree depth: the plan's choice (stancal.numerics.parametrization)
is a rule of thumb, and the sampler's tree depth is the measurement that
settles it (Betancourt & Girolami 2015: a latent GP in the wrong form shows as
long trajectories, at the maximum tree depth, or as divergences)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from stancal.problem.options import ModelOptions

logger = logging.getLogger("stancal")

SATURATED_SHARE = 0.05  # issue 30's target: at most 5 % of transitions at the maximum tree depth


def saturated_share(tree, max_treedepth: int) -> float:
    """The share of a fit's transitions (after warm-up: the backends keep
    no warm-up statistics) at the maximum tree depth."""
    depth = np.asarray(tree["sample_stats"]["tree_depth"])
    return float(np.mean(depth >= max_treedepth)) if depth.size else 0.0


def other_parametrization(options: ModelOptions) -> ModelOptions:
    """The same options with the discrepancy's latent GP the other way:
    non-centred after centred or partially non-centred, centred after non-centred."""
    other = "centred" if options.discrepancy_parametrization == "non_centred" else "non_centred"
    return replace(options, discrepancy_parametrization=other)


def with_fallback(sample_once: Callable[[ModelOptions], Any], first: Any, options: ModelOptions,
                  max_treedepth: int, tree_of: Callable[[Any], Any]) -> tuple[Any, ModelOptions]:
    """``first`` (a fit with ``options``), or, when it spent more than
    SATURATED_SHARE of its transitions at the maximum tree depth, one refit
    with the other parametrisation: the fit with the smaller share is kept,
    and the options' reason says what happened in one line with the numbers."""
    share = saturated_share(tree_of(first), max_treedepth)
    if share <= SATURATED_SHARE:
        return first, options
    other = other_parametrization(options)
    logger.info("the discrepancy's latent GP sampled %s spent %.0f %% of transitions at the maximum tree "
                "depth %d; refitting %s", options.discrepancy_parametrization, 100 * share, max_treedepth,
                other.discrepancy_parametrization)
    second = sample_once(other)
    other_share = saturated_share(tree_of(second), max_treedepth)
    keep_other = other_share < share
    kept = other if keep_other else options
    line = (f"{options.discrepancy_parametrization} spent {100 * share:.0f} % of transitions at the maximum "
            f"tree depth {max_treedepth} (> {100 * SATURATED_SHARE:.0f} %), so it was refitted "
            f"{other.discrepancy_parametrization}: {100 * other_share:.0f} %; kept "
            f"{kept.discrepancy_parametrization}")
    logger.info("%s", line)
    reason = f"{options.discrepancy_parametrization_reason}; then {line}"
    return (second if keep_other else first), replace(kept, discrepancy_parametrization_reason=reason)
