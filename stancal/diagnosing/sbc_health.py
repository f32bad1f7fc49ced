"""How SBC's fits mixed, over the simulations. SBC's ranks are only as
good as the fits that make them: a sampler that has not mixed ranks the
truths unevenly with no program at fault (Talts et al. 2018,
arXiv:1804.06788, sec. 4.2; Modrák et al. 2023, arXiv:2211.02383), and a
rejection is then the fits' to rule out first. Each fit's sampler checks
(stancal.results.diagnostics, the ones every calibration makes) travel back
with its ranks; the run sums them up, with the numbers, the parameters most
often worst and advice."""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from stancal.problem import advice
from stancal.results.diagnostics import ESS_PER_CHAIN, RHAT_LIMIT, Diagnostics

LONGER_WARMUP = LONGER_DRAWS = 1000  # the advice's longer fits: at least this per chain


def fit_health(diagnostics: Diagnostics, chains: int) -> dict[str, Any]:
    """What one fit's sampler checks send back beside its ranks (small JSON)."""
    return {"max_rhat": diagnostics.max_rhat, "worst_rhat": diagnostics.worst_rhat,
            "min_ess": min(diagnostics.min_ess_bulk, diagnostics.min_ess_tail),
            "worst_ess": diagnostics.worst_ess, "ess_needed": ESS_PER_CHAIN * chains, "draws": diagnostics.draws,
            "divergences": diagnostics.divergences, "treedepth_hits": diagnostics.treedepth_hits,
            "low_bfmi_chains": len(diagnostics.low_bfmi_chains)}


def _most_often(names: list[str]) -> str | None:
    return Counter(names).most_common(1)[0][0] if names else None


def fits_health(healths: list[dict[str, Any] | None]) -> dict[str, Any]:
    """The fits' checks over the simulations (None: a fit whose record was
    written before SBC kept its health; counted as unknown)."""
    known = [h for h in healths if h is not None]
    if not known:
        return {"fits": 0, "unknown": len(healths)}
    high_rhat = [h for h in known if h["max_rhat"] > RHAT_LIMIT]
    low_ess = [h for h in known if h["min_ess"] < h["ess_needed"]]
    return {
        "fits": len(known), "unknown": len(healths) - len(known),
        "rhat_above_limit": len(high_rhat), "median_max_rhat": float(np.median([h["max_rhat"] for h in known])),
        "worst_rhat_most_often": _most_often([h["worst_rhat"] for h in high_rhat]),
        "ess_below_needed": len(low_ess), "median_min_ess": float(np.median([h["min_ess"] for h in known])),
        "fit_draws": int(np.median([h["draws"] for h in known])),
        "worst_ess_most_often": _most_often([h["worst_ess"] for h in low_ess]),
        "divergent_fits": sum(h["divergences"] > 0 for h in known),
        "divergences": int(sum(h["divergences"] for h in known)),
        "treedepth_fits": sum(h["treedepth_hits"] > 0 for h in known),
        "low_bfmi_fits": sum(h["low_bfmi_chains"] > 0 for h in known)}


def health_message(summary: dict[str, Any], warmup: int, draws: int) -> str | None:
    """One message for the whole run, None when every fit was healthy: how
    many fits mixed poorly and where, and how to tell their fault from the
    program's (refit some simulations longer and compare rank by rank)."""
    if not summary["fits"]:
        return None
    n, parts = summary["fits"], []
    if summary["rhat_above_limit"]:
        parts.append(f"R-hat above {RHAT_LIMIT} in {summary['rhat_above_limit']} of {n} fits (median largest "
                     f"{summary['median_max_rhat']:.3f}, most often {summary['worst_rhat_most_often']})")
    if summary["ess_below_needed"]:
        parts.append(f"effective sample size below {ESS_PER_CHAIN} per chain in {summary['ess_below_needed']} "
                     f"(median smallest {summary['median_min_ess']:.0f} of {summary['fit_draws']} draws, most "
                     f"often {summary['worst_ess_most_often']})")
    if summary["divergent_fits"]:
        parts.append(f"divergences in {summary['divergent_fits']} ({summary['divergences']} transitions)")
    if summary["treedepth_fits"]:
        parts.append(f"the maximum tree depth hit in {summary['treedepth_fits']}")
    if summary["low_bfmi_fits"]:
        parts.append(f"E-BFMI below 0.3 in {summary['low_bfmi_fits']}")
    if not parts:
        return None
    longer = advice.options(warmup=max(LONGER_WARMUP, 4 * warmup), draws=max(LONGER_DRAWS, 4 * draws))
    return (f"SBC's fits: {'; '.join(parts)}. A rank test rejected here may be the fits' fault, not the "
            f"program's: refit some simulations with longer chains ({advice.option('subset')} with {longer}, "
            f"into another output folder) and compare each rank with this run's; if they do not move, the "
            f"fits' length is not the cause.")
