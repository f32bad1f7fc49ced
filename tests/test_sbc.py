"""Simulation-based calibration (issue 16, part 2): the rank statistics and
their uniformity test in numpy, and (slow) the whole loop on a program."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import COOLING, ROOT, cooling_data, no_stancal_warnings

from stancal.diagnosing.sbc_ranks import (
    REFERENCE_SAMPLES,
    fractional_ranks,
    gamma_statistic,
    rank_of,
    reference_statistics,
    uniformity,
)
from stancal.reporting.sbc_report import write_sbc_report


def test_rank_counts_the_draws_below_the_truth():
    assert rank_of(0.5, np.array([0.1, 0.7, 0.4, 0.9])) == 2
    assert rank_of(-1.0, np.arange(5.0)) == 0 and rank_of(9.0, np.arange(5.0)) == 5


def test_uniform_ranks_pass_and_overconfident_ones_are_rejected():
    """Ranks of a correct fit are uniform on 0..L; a posterior too narrow
    puts the truth in its tails (U-shaped ranks), one biased upwards puts it
    low: both are rejected, and the uniform ones are not."""
    rng = np.random.default_rng(1)
    sims, draws = 200, 99
    uniform = rng.integers(0, draws + 1, sims)
    assert not uniformity(fractional_ranks(uniform, draws, rng)).rejected
    truth, narrow = rng.normal(size=sims), rng.normal(size=(sims, draws)) * 0.5
    overconfident = [rank_of(t, draws_s) for t, draws_s in
                     zip(truth, narrow + rng.normal(size=(sims, 1)), strict=False)]
    assert uniformity(fractional_ranks(np.array(overconfident), draws, rng)).p_value < 0.01
    biased = [rank_of(t, d) for t, d in zip(truth, rng.normal(size=(sims, draws)) + truth[:, None] + 0.5, strict=False)]
    assert uniformity(fractional_ranks(np.array(biased), draws, rng)).p_value < 0.01


def test_the_reference_law_is_the_statistic_of_successive_uniform_samples():
    """The reference statistics, computed for all samples at once, are the
    statistic of each uniform sample drawn in turn from the seed's stream."""
    rng = np.random.default_rng(4)
    grid = np.arange(1, 30) / 30
    one_by_one = [gamma_statistic(rng.uniform(size=30), grid) for _ in range(REFERENCE_SAMPLES)]
    np.testing.assert_allclose(reference_statistics(30, 4), one_by_one, rtol=1e-12)


def test_the_simultaneous_band_holds_uniform_ecdfs_at_its_level():
    """About 95 % of uniform samples stay inside the 95 % band everywhere."""
    rng = np.random.default_rng(2)
    test = uniformity(rng.uniform(size=100), level=0.95, seed=3)
    inside = []
    for _ in range(400):
        u = np.sort(rng.uniform(size=100))
        difference = np.searchsorted(u, test.grid, side="right") / 100 - test.grid
        inside.append(bool(((difference >= test.band[0] - 1e-12) & (difference <= test.band[1] + 1e-12)).all()))
    assert 0.91 <= np.mean(inside) <= 0.99, np.mean(inside)


@pytest.mark.slow
def test_sbc_passes_koh_and_flags_a_likelihood_with_the_wrong_noise_scale(tmp_path):
    """koh without a discrepancy on the cooling design, 60 simulations: no
    parameter is rejected. The same simulations fitted by a copy of koh.stan
    whose likelihood doubles the noise sd are flagged (noise_sd's ranks and
    the log-likelihood's)."""
    from stancal.diagnosing.sbc import simulation_based_calibration
    from stancal.stan.source import shipped_models_dir

    # health is not asserted per fit: 60 fits of 2 x (200 + 50) draws, some short of ESS (SBCResult's
    # fits_health says how many); uniform ranks are the check here
    data = cooling_data(seed=7)
    settings = {"simulator": COOLING / "simulator.stan", "method": "koh", "discrepancy": "none", "simulations": 60,
                    "draws_per_fit": 50, "seed": 5, "warmup": 200}
    good = simulation_based_calibration(data, out_dir=tmp_path / "good", **settings)
    print({n: round(t.p_value, 3) for n, t in good.tests.items()})
    assert not any(t.rejected for t in good.tests.values()) and not good.failed
    wrong = tmp_path / "koh_wrong_noise.stan"
    source = (shipped_models_dir() / "koh.stan").read_text()
    right = "resid ~ independent_noise(noise_var, nu);"  # the noise sd doubled: its variance times 4
    assert source.count(right) == 1
    wrong.write_text(source.replace(right, "resid ~ independent_noise(4 * noise_var, nu);"))
    bad = simulation_based_calibration(data, program=wrong, **settings)
    print({n: round(t.p_value, 4) for n, t in bad.tests.items()})
    assert bad.tests["noise_sd"].rejected and bad.tests["log_likelihood"].rejected
    write_sbc_report(good, tmp_path / "good")
    assert (tmp_path / "good" / "sbc.json").is_file() and (tmp_path / "good" / "ecdf.png").is_file()


def test_the_log_likelihood_at_given_parameters_matches_numpy():
    """SBC ranks the log-likelihood at the true parameters among its values
    at the posterior draws. At one posterior draw's own Stan parameters it
    must equal the sampler's log_lik there, and, for koh without a
    discrepancy, the normal density of the residuals (original units)."""
    from make_data import newton
    from scipy.stats import norm

    import stancal
    from stancal.diagnosing.sbc import log_likelihood_at, log_likelihood_draws

    data = cooling_data(seed=7)
    # health not asserted: 20 draws, read only as parameter values at which two log-likelihoods are compared
    with no_stancal_warnings(allow="R-hat|effective sample size"):  # 20 draws: they say so
        fit = stancal.calibrate(data, simulator=COOLING / "simulator.stan", method="koh", discrepancy="none",
                                chains=1, warmup=150, draws=20, seed=2)
    draw = 7
    parameters = {k: np.asarray(v)[0, draw] for k, v in fit.idata["stan_parameters"].data_vars.items()}
    at_truth = log_likelihood_at(fit, parameters)
    assert at_truth == pytest.approx(log_likelihood_draws(fit)[draw], rel=1e-10)
    k = float(np.asarray(fit.idata["posterior"]["theta"])[0, draw, 0])
    sd = float(np.asarray(fit.idata["posterior"]["noise_sd"])[0, draw])
    physical = data.physical
    residual = physical["temperature"] - newton(physical["t"], physical["T0"], k)
    assert at_truth == pytest.approx(norm.logpdf(residual, 0, sd).sum(), rel=1e-8)


def test_simulated_outputs_are_censored_as_the_lab_censored():
    """A detection limit (below 1: left-censored) and a quantification limit
    ([1, 1.5]: interval) in the data censor simulated values the same way."""
    import pandas as pd

    import stancal

    frame = pd.DataFrame({"t": np.arange(5.0), "y": [np.nan, np.nan, 2.0, 3.0, 4.0],
                          "lo": [np.nan, 1.0, np.nan, np.nan, np.nan], "hi": [1.0, 1.5, np.nan, np.nan, np.nan]})
    data = stancal.CalibrationData(frame, ["t"], "y", {"k": (0.0, 1.0)}, lower="lo", upper="hi")
    simulated = data.with_output(np.array([2.5, 0.4, 1.2, 0.9, 3.0]))
    observations = simulated.observations
    np.testing.assert_array_equal(observations.observed, [True, False, False, False, True])
    np.testing.assert_array_equal(observations.lower[1:4], [-np.inf, 1.0, -np.inf])
    np.testing.assert_array_equal(observations.upper[1:4], [1.0, 1.5, 1.0])
    assert simulated.scaling == data.scaling


def test_functional_theta_is_simulated_and_fitted_non_centred_unless_told():
    """Data drawn from the prior seldom pin theta(x): fitted centred, the beam's
    SBC hit the maximum tree depth in most transitions and rejected every
    parameter (S = 200, p < 0.001); fitted non-centred, no divergence."""
    from stancal.diagnosing.sbc import functional_parametrizations

    assert functional_parametrizations({}) == (None, None)
    assert functional_parametrizations({"functional": ["E"]}) == ("non_centred", "non_centred")
    told = {"functional": ["E"], "functional_parametrization": "centred"}
    assert functional_parametrizations(told) == ("non_centred", "centred")


def test_the_truths_log_likelihood_reads_the_priors_discrepancy_parametrization():
    """A latent fit may sample its discrepancy the other way than the prior's
    draws (stancal.fitting.parametrization_fallback): the truth's delta_raw
    is read in the prior's parametrisation. At a non-centred draw, the
    centred values delta (= L z) read as centred give the sampler's log_lik."""
    import pandas as pd

    import stancal
    from stancal.diagnosing.sbc import log_likelihood_at, log_likelihood_draws

    d, s = np.meshgrid(np.linspace(0.5, 3.0, 5), [0.0, 2.5])
    counts = np.random.default_rng(3).poisson(2000 * np.exp(-0.35 * s.ravel()) / d.ravel() ** 2)
    data = stancal.CalibrationData(pd.DataFrame({"d": d.ravel(), "s": s.ravel(), "counts": counts}), ["d", "s"],
                                   "counts", {"mu": (0.05, 1.0)}, likelihood="poisson")
    # health not asserted: 20 draws, read only as parameter values at which two log-likelihoods are compared
    with no_stancal_warnings(allow="R-hat|effective sample size"):  # 20 draws: they say so
        fit = stancal.calibrate(data, simulator=ROOT / "case_studies" / "detector_counts" / "simulator.stan",
                                discrepancy_parametrization="non_centred", chains=1, warmup=100, draws=20, seed=2)
    draw = 5
    parameters = {k: np.asarray(v)[0, draw] for k, v in fit.idata["stan_parameters"].data_vars.items()}
    expected = log_likelihood_draws(fit)[draw]
    assert log_likelihood_at(fit, parameters) == pytest.approx(expected, rel=1e-10)
    centred = {**parameters, "delta_raw": np.asarray(fit.idata["at_observations"]["delta_gp"])[0, draw]}
    assert log_likelihood_at(fit, centred, discrepancy_parametrization="centred") == pytest.approx(expected,
                                                                                                   rel=1e-8)
    assert log_likelihood_at(fit, centred) != pytest.approx(expected, rel=1e-3)


def test_the_prior_run_samples_a_latent_discrepancy_non_centred(monkeypatch):
    """With no data the centred latent GP is a funnel: the prior run of SBC
    is sampled non-centred whatever the fits use (the fits keep the user's
    choice, or the plan's)."""
    import stancal.diagnosing.sbc as sbc

    asked = []

    class Stop(Exception):
        pass

    def calibrate(data, **options):
        asked.append(options)
        raise Stop

    monkeypatch.setattr(sbc, "calibrate", calibrate)
    with pytest.raises(Stop):
        sbc.simulation_based_calibration(cooling_data(seed=7), simulator=COOLING / "simulator.stan", simulations=4,
                                         scheduler="in-process", discrepancy_parametrization="centred")
    assert asked[0]["prior"] and asked[0]["discrepancy_parametrization"] == "non_centred"


class _PriorRun:
    """A prior run's stand-in: ``idata["prior"]`` holds one chain of an
    AR(1) series (autocorrelation ``phi``) per variable."""

    def __init__(self, draws: int, phi: float, seed: int = 1):
        import xarray as xr

        rng, values = np.random.default_rng(seed), np.zeros(draws)
        for i in range(1, draws):
            values[i] = phi * values[i - 1] + rng.normal()
        self.draws = draws
        self.idata = {"prior": xr.DataTree(xr.Dataset({"nu": (("chain", "draw"), values[None]),
                                                       "k": (("chain", "draw"), rng.normal(size=(1, draws))),
                                                       "rho": (("chain", "draw"), np.ones((1, draws)))}))}


def test_the_prior_run_is_long_enough_for_independent_truths():
    """SBC's truths must be independent draws of the prior (Talts et al.
    2018). A sticky prior chain (Student-t's degrees of freedom above their
    mixture weights, autocorrelation time near 20 draws) thinned from 5 draws
    per simulation gave truths that fail the rank test with no fit involved;
    the run is now lengthened until its smallest ESS is 2 per simulation."""
    import stancal.diagnosing.sbc as sbc

    lengths = []

    def run_prior(draws):
        lengths.append(draws)
        return _PriorRun(draws, phi=0.9)

    fit, record = sbc._independent_prior(run_prior, simulations=100)
    assert sbc._smallest_ess(_PriorRun(500, phi=0.9))[0] < 200  # 5 per simulation was too short
    assert lengths[0] == 500 and len(lengths) >= 2 and fit.draws == lengths[-1] == record["draws"]
    assert record["min_ess"] >= 200 and record["min_ess_of"] == "nu"  # rho, a constant, has no ESS to wait for


def test_a_prior_run_that_never_mixes_is_reported():
    import stancal.diagnosing.sbc as sbc
    from stancal.results.diagnostics import SamplerWarning

    with pytest.warns(SamplerWarning, match="nu's effective sample size is .* below 40"):
        _, record = sbc._independent_prior(lambda draws: _PriorRun(draws, phi=0.9999), simulations=20)
    assert record["draws"] == sbc.PRIOR_MAX_THINNING * 20 and record["min_ess"] < 40


def test_the_student_t_priors_truths_are_draws_of_its_prior():
    """koh's Student-t family with a GP: its degrees of freedom ν sit above
    24 mixture weights, a funnel the prior run's chain leaves slowly. Thinned
    from 5 draws per simulation (the old run), SBC's 200 truths of ν at seed 1
    put 38 in the prior's lowest decile (20 expected) and failed SBC's own
    uniformity test against gamma(2, 0.1) with no fit involved (p = 0.003);
    they made the family's rank test reject ν twice. Lengthened until ν's ESS
    is 2 per simulation (6,637 draws here), the truths pass (p = 0.93)."""
    import functools

    from scipy.stats import gamma

    import stancal.diagnosing.sbc as sbc
    from stancal.fitting.calibrate import calibrate

    prior_run = functools.partial(calibrate, cooling_data(seed=7), simulator=COOLING / "simulator.stan", method="koh",
                                  prior=True, chains=1, warmup=300, seed=1, discrepancy="gp", noise="student_t",
                                  discrepancy_parametrization="non_centred")
    # the prior runs' own checks may say their single chain mixes poorly in the funnel (R-hat of its halves, its
    # ESS, its E-BFMI): that is what the lengthening answers; nothing else of stancal's may warn
    with no_stancal_warnings(allow="^(R-hat up to|effective sample size down to|E-BFMI below)"):
        fit, record = sbc._independent_prior(prior_run, simulations=200)
    assert record["draws"] > 1000 and record["min_ess"] >= 400, record
    truths = sbc._thinned(np.asarray(fit.idata["prior"]["nu"]).reshape(-1), 200)
    ranks = np.floor(100 * gamma.cdf(truths, 2, scale=10)).astype(int)  # the prior's CDF: an exact rank
    assert not uniformity(fractional_ranks(ranks, 100, np.random.default_rng(1)), 0.95, 1).rejected
