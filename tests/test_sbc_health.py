"""SBC says how its fits mixed (stancal.diagnosing.sbc_health): each fit's
sampler checks summed over the simulations, with the parameters most often
worst and advice that suits its reader; silent when every fit was healthy."""

import pytest

from stancal.diagnosing.sbc import _restored
from stancal.diagnosing.sbc_health import fit_health, fits_health, health_message
from stancal.problem import advice
from stancal.results.diagnostics import Diagnostics


def diagnostics(rhat: float, ess: float, worst: str = "noise_gp_sd", divergences: int = 0) -> Diagnostics:
    return Diagnostics(divergences=divergences, draws=200, max_rhat=rhat, worst_rhat=worst, min_ess_bulk=ess,
                       min_ess_tail=ess + 10, worst_ess=worst, treedepth_hits=0, low_bfmi_chains=[])


def test_the_fits_checks_are_counted_with_the_parameters_most_often_worst():
    healths = [fit_health(diagnostics(1.04, 70), chains=2), fit_health(diagnostics(1.02, 150, "delta_sd"), 2),
               fit_health(diagnostics(1.03, 90, divergences=3), 2), fit_health(diagnostics(1.005, 300), 2), None]
    summary = fits_health(healths)
    assert summary["fits"] == 4 and summary["unknown"] == 1  # a record kept before health was: unknown
    assert summary["rhat_above_limit"] == 3 and summary["worst_rhat_most_often"] == "noise_gp_sd"
    assert summary["ess_below_needed"] == 3 and summary["worst_ess_most_often"] == "noise_gp_sd"  # < 100 x 2
    assert summary["median_max_rhat"] == pytest.approx(1.025) and summary["median_min_ess"] == pytest.approx(120)
    assert summary["divergent_fits"] == 1 and summary["divergences"] == 3 and summary["fit_draws"] == 200
    message = health_message(summary, warmup=300, draws=100)
    assert message.startswith("SBC's fits: R-hat above 1.01 in 3 of 4 fits (median largest 1.025, most often "
                              "noise_gp_sd); effective sample size below 100 per chain in 3 (median smallest 120 "
                              "of 200 draws, most often noise_gp_sd); divergences in 1 (3 transitions).")
    assert "subset with warmup=1200, draws=1000" in message  # four times the warm-up, at least 1000 each
    with advice.spoken_to(advice.CLI):
        assert "--subset with --warmup 1200 --draws 1000" in health_message(summary, warmup=300, draws=100)


def test_healthy_fits_and_no_known_fits_say_nothing():
    assert health_message(fits_health([fit_health(diagnostics(1.002, 400), 2)] * 3), 300, 100) is None
    assert health_message(fits_health([None, None]), 300, 100) is None


def test_a_record_kept_before_sbc_kept_health_is_restored_as_ranks_alone():
    ranks = {"theta[k]": 3, "noise_sd": 40}
    assert _restored(None, None, ranks) == {"ranks": ranks, "health": None}
    current = {"ranks": ranks, "health": {"max_rhat": 1.0}}
    assert _restored(None, None, current) == current
