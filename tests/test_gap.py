"""The gap diagnosis on three case studies whose effect is withheld from the
simulator: cooling (the real effect is a simulator variant; run through the
command line), pipe flow (the real effect is a formula; run through the
Python API with the joint emulator) and shield build-up (Poisson counts; the
real effect is a multiplicative variant; decoys include a nearly constant
air pressure)."""

import numpy as np
import pandas as pd
import pytest
import stan
from conftest import (
    COOLING,
    ROOT,
    assert_gap_summary_healthy,
    assert_healthy,
    assert_trouble_reported,
    case_study_module,
    no_stancal_warnings,
)

import stancal
from stancal.diagnosing.gap import Candidate, CandidateError, check_candidates, diagnose_gap
from stancal.fitting.plan import make_plan
from stancal.fitting.warm_start import candidate_warmup, refit_draws, refit_warmup
from stancal.problem.candidates import variant_data
from stancal.problem.codes import Likelihood
from stancal.problem.config import ConfigError, load_config
from stancal.reporting.gap_report import write_gap_report
from stancal.stan.backends import get_backend

PIPE = ROOT / "case_studies" / "pipe_flow"
SHIELD = ROOT / "case_studies" / "shield_buildup"
# loaded under their own names: conftest already imported cooling's make_data
pipe_physics, shield_physics = case_study_module(PIPE), case_study_module(SHIELD)

COOLING_K_TRUE = 0.05
# the joint emulator is slower per draw than the cheap simulator (COOLING_SAMPLING)
PIPE_SAMPLING = {"chains": 2, "warmup": 400, "draws": 600, "seed": 3}
# the shield case compares by 5-fold cross-validation (the misfitting fits have
# more than 5 observations with Pareto k > 0.7): 24 latent fits, about 40
# minutes on 2 cores, so it is a slow study
SHIELD_SAMPLING = {"chains": 2, "warmup": 500, "draws": 700, "seed": 3}


def gap_through_python(case, tmp_path_factory, sampling, expected_warning=None):
    """diagnose_gap on a case study's config (method as configured), and its
    report. ``expected_warning``: (category, match) of a warning the case
    must raise; any other stancal warning fails."""
    problem = load_config(case / "config.toml")
    out = tmp_path_factory.mktemp("gap") / case.name
    if expected_warning is None:
        with no_stancal_warnings():
            analysis = diagnose_gap(problem.data, problem.candidates, simulator=problem.simulator,
                                    method=problem.model.get("method"), out_dir=out, **sampling)
    else:
        with pytest.warns(*expected_warning[:1], match=expected_warning[1]):
            analysis = diagnose_gap(problem.data, problem.candidates, simulator=problem.simulator,
                                    method=problem.model.get("method"), out_dir=out, **sampling)
    return analysis, write_gap_report(analysis, out)


def assert_analysis_healthy(analysis, divergences=0, **allowed):
    """The baseline and every candidate's fit; ``allowed``: divergences per candidate name."""
    assert_healthy(analysis.baseline, divergences=divergences)
    for fit in analysis.candidates:
        assert_healthy(fit.result, divergences=allowed.get(fit.candidate.name, divergences))


def assert_gap_json_healthy(summary, out=None, claims=("quadratic_loss",)):
    """The baseline and the candidates the cooling claims rest on, from the
    diagnostics in gap.json and, where the fits' posteriors are in the folder,
    from the fits themselves; the decoys' trouble is reported, never hidden."""
    # a few divergences of 4,000 are allowed: the cooling baseline had 3 at adapt_delta 0.9 (at the
    # short length scales of the discrepancy the withheld loss leaves), and 9 at 0.95 once koh.stan took
    # the noise models (the same model on another floating-point path); they are reported, and the
    # claims are checked against the truth
    allowed = 12
    assert_gap_summary_healthy(summary, claims, divergences=allowed)
    if out is not None:
        assert_healthy(stancal.load_result(out / "baseline" / "posterior.nc"), divergences=allowed)
        for name in claims:
            assert_healthy(stancal.load_result(out / "candidates" / name / "posterior.nc"), divergences=allowed)


@pytest.fixture(scope="module")
def pipe_gap(tmp_path_factory):
    return gap_through_python(PIPE, tmp_path_factory, PIPE_SAMPLING)


def by_name(summary):
    return {c["name"]: c for c in summary["candidates"]}


# ---- cooling: the withheld effect is a simulator variant ---------------------
@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_cooling_withheld_effect_ranks_first_and_shrinks_the_gap(cooling_gap):
    summary, out = cooling_gap
    assert_gap_json_healthy(summary, out)
    cands = by_name(summary)
    assert summary["candidates"][0]["name"] == "quadratic_loss"
    # more than one se better. Exact LOO (PSIS, with refits where k > 0.7) gives
    # smaller differences than the 5-fold it replaced: the GP fills a single gap
    # better than a fifth of the data; here 5.9 +- 3.5
    assert cands["quadratic_loss"]["elpd_diff"] > cands["quadratic_loss"]["elpd_diff_se"]
    assert cands["quadratic_loss"]["shrinkage"]["mean"] > 0.5
    for decoy in ("humidity", "operator", "humid_convection"):
        assert cands[decoy]["shrinkage"]["mean"] < 0.2, decoy


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_cooling_theta_moves_to_the_truth(cooling_gap):
    summary, _ = cooling_gap
    assert_gap_json_healthy(summary)
    before = summary["baseline"]["theta"]["k"]
    after = by_name(summary)["quadratic_loss"]["theta"]["k"]
    assert abs(after["mean"] - COOLING_K_TRUE) < abs(before["mean"] - COOLING_K_TRUE)
    assert after["q05"] < COOLING_K_TRUE < after["q95"]
    c = by_name(summary)["quadratic_loss"]["theta"]["c"]  # the variant's own parameter
    assert c["q05"] < 4e-4 < c["q95"]


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_cooling_where(cooling_gap):
    summary, _ = cooling_gap
    assert_gap_json_healthy(summary)
    importance = {v: e["mean"] for v, e in summary["where"]["importance"].items()}
    # the loss has acted longer the later the reading: time drives the gap
    assert max(importance, key=importance.get) == "t"
    assert max(importance["humidity"], importance["operator"]) < 0.5 * importance["t"]
    # the region must cover the end of the run, where the withheld loss has acted longest
    t_regions = [r for r in summary["where"]["regions"] if r["variable"] == "t" and not r["whole_range"]]
    assert any(r["from"] <= 55 <= r["to"] for r in t_regions)


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_cooling_report_folder(cooling_gap):
    summary, out = cooling_gap
    for name in ("gap.json", "report.md", "report.html", "importance.png", "where.png", "candidates.png",
                 "baseline/posterior.nc", "baseline/summary.json", "baseline/report.html", "baseline/fit.png",
                 "candidates/quadratic_loss/posterior.nc"):
        assert (out / name).stat().st_size > 0, name
    report = (out / "report.md").read_text()
    assert "Best candidate: **quadratic_loss**" in report
    assert set(summary["baseline"]) >= {"theta", "discrepancy_rms", "elpd_loo", "elpd_se"}
    for c in summary["candidates"]:
        assert set(c) >= {"name", "kind", "elpd_diff", "elpd_diff_se", "discrepancy_rms",
                          "shrinkage", "theta", "holdout_rmse"}
    diffs = [c["elpd_diff"] for c in summary["candidates"]]
    assert diffs == sorted(diffs, reverse=True)
    for fit in [summary["baseline"], *summary["candidates"]]:  # moment matching before any refit
        still = [p for p in fit["moment_matching"]["tried"] if p["k_after"] > 0.7]
        assert fit["moment_matching"]["points"] == len(fit["moment_matching"]["tried"]) - len(still)
        if "settled" not in fit["scheme"]:
            assert fit["refits"] == len(still), fit["name"] if "name" in fit else "baseline"


# ---- pipe flow: the withheld effect is a formula, fitted with the emulator ---------
@pytest.mark.slow  # 200 s: the default run keeps the cooling and counts gap tests
def test_pipe_withheld_effect_ranks_first_and_shrinks_the_gap(pipe_gap):
    analysis, summary = pipe_gap
    assert_analysis_healthy(analysis)
    cands = by_name(summary)
    assert summary["baseline"]["method"] == "koh_emulator"
    assert summary["candidates"][0]["name"] == "minor_loss"
    assert cands["minor_loss"]["shrinkage"]["mean"] > 0.5
    for decoy in ("batch", "humidity"):
        assert cands[decoy]["shrinkage"]["mean"] < 0.2, decoy
    # no held-out check: the baseline's GP predicts the v^2 shape about as well
    # (measured ELPD +0.3 +- 2.6, held-out RMSE 0.02059 against 0.02054 kPa);
    # the formula's gain is that it explains the gap, which shrinkage measures


def least_squares_under_the_true_model():
    """mu and beta fitted by least squares with the withheld term put back:
    the best any method can do on this data (mu lands 2 se below its true
    value in this realisation)."""
    d = pd.read_csv(PIPE / "physical.csv")
    design = np.column_stack([pipe_physics.poiseuille(d.v, d.L, 1.0), d.v**2])
    coef, *_ = np.linalg.lstsq(design, d.dp, rcond=None)
    resid = d.dp - design @ coef
    cov = resid @ resid / (len(d) - 2) * np.linalg.inv(design.T @ design)
    return coef, np.sqrt(np.diag(cov))


@pytest.mark.slow  # 200 s: the default run keeps the cooling and counts gap tests
def test_pipe_theta_moves_to_the_truth_and_beta_is_recovered(pipe_gap):
    analysis, summary = pipe_gap
    assert_analysis_healthy(analysis)
    (mu_ls, beta_ls), (mu_se, beta_se) = least_squares_under_the_true_model()
    before = summary["baseline"]["theta"]["mu"]["mean"]
    after = by_name(summary)["minor_loss"]["theta"]["mu"]
    assert abs(after["mean"] - pipe_physics.MU_TRUE) < abs(before - pipe_physics.MU_TRUE)
    assert abs(after["mean"] - mu_ls) < 0.5 * mu_se
    assert after["q05"] < mu_ls < after["q95"]
    fit = next(f for f in analysis.candidates if f.candidate.name == "minor_loss")
    beta = np.asarray(fit.result.idata["posterior"]["beta"].sel(mean_term="I(v ** 2)")).ravel()
    true_beta = pipe_physics.MINOR_LOSS_K * pipe_physics.DENSITY / 2 / 1000  # kPa per (m/s)^2
    assert np.quantile(beta, 0.05) < true_beta < np.quantile(beta, 0.95)
    assert abs(np.mean(beta) - beta_ls) < beta_se


@pytest.mark.slow  # 200 s: the default run keeps the cooling and counts gap tests
def test_pipe_prediction_carries_the_added_effect(pipe_gap):
    """predict() evaluates the formula at new points: fast flow in a long pipe,
    where the minor loss is about 0.3 kPa of 2.5."""
    analysis, _ = pipe_gap
    assert_analysis_healthy(analysis)
    fit = next(f for f in analysis.candidates if f.candidate.name == "minor_loss")
    new = pd.DataFrame({"v": [0.45, 0.1], "L": [8.0, 2.0], "batch": ["B", "A"], "humidity": [50.0, 40.0]})
    table = fit.result.predict(new)
    truth = pipe_physics.reality(new.v, new.L).to_numpy()
    (mu_ls, beta_ls), _ = least_squares_under_the_true_model()
    best = pipe_physics.poiseuille(new.v, new.L, mu_ls).to_numpy() + beta_ls * new.v.to_numpy() ** 2
    # this data puts mu 2 se low, so the narrow zeta band is judged against
    # the least-squares prediction; a new measurement's band must cover the truth
    assert np.abs(table.zeta_q50 - best).max() < 0.01  # kPa; noise sd is 0.02
    assert np.abs(table.zeta_q50 - truth).max() < 0.03
    assert (table.y_q05 < truth).all() and (truth < table.y_q95).all()


@pytest.mark.slow  # 200 s: the default run keeps the cooling and counts gap tests
def test_pipe_where(pipe_gap):
    analysis, summary = pipe_gap
    assert_analysis_healthy(analysis)
    importance = {v: e["mean"] for v, e in summary["where"]["importance"].items()}
    assert max(importance, key=importance.get) == "v"
    # the minor loss grows as v^2: the gap must be found at the fastest flows
    v_regions = [r for r in summary["where"]["regions"] if r["variable"] == "v"]
    assert any(r["to"] >= 0.45 for r in v_regions)


# ---- shield build-up: Poisson counts, a multiplicative effect withheld -------
@pytest.fixture(scope="module")
def shield_gap(tmp_path_factory):
    # the misfitting fits leave more than 5 observations with Pareto k > 0.7 (see SHIELD_SAMPLING)
    return gap_through_python(SHIELD, tmp_path_factory, SHIELD_SAMPLING,
                              (stancal.GapWarning, "compared by 5-fold cross-validation instead"))


@pytest.mark.slow
def test_counts_withheld_effect_ranks_first_and_shrinks_the_gap(shield_gap):
    analysis, summary = shield_gap
    assert_analysis_healthy(analysis, buildup=5)  # see test_counts_theta_error_shrinks_with_the_effect
    cands = by_name(summary)
    assert summary["baseline"]["method"] == "koh_latent"
    assert summary["baseline"]["discrepancy_scale"] == "log of the mean count"
    assert summary["candidates"][0]["name"] == "buildup"
    assert cands["buildup"]["elpd_diff"] > 2 * cands["buildup"]["elpd_diff_se"]
    assert cands["buildup"]["shrinkage"]["mean"] > 0.5
    for decoy in ("pressure", "operator"):
        assert cands[decoy]["shrinkage"]["mean"] < 0.2, decoy
    # the nearly constant pressure trades its level with the discrepancy's
    # constant: on the identified part its shrinkage is near zero (the median:
    # a ratio of two small noisy sizes is skewed), not the -5 that an RMS with
    # the level gave
    assert abs(cands["pressure"]["shrinkage"]["q50"]) < 0.2


@pytest.mark.slow
def test_counts_theta_error_shrinks_with_the_effect(shield_gap):
    analysis, summary = shield_gap
    before = summary["baseline"]["theta"]["mu"]["mean"]
    after = by_name(summary)["buildup"]["theta"]
    assert abs(after["mu"]["mean"] - shield_physics.MU_TRUE) < 0.5 * abs(before - shield_physics.MU_TRUE)
    # the reference: Poisson maximum likelihood of the true model (no
    # discrepancy) on the same counts; measured mu 0.3422 +- 0.0045 against
    # 0.3433, a 1.438 +- 0.043 against 1.456
    best = maximum_likelihood_with_buildup()
    for k, name in enumerate(("mu", "a")):
        assert abs(after[name]["mean"] - best[k]) < 0.5 * after[name]["sd"], name
    # the recovery claim rests on the candidate's fit. Its discrepancy nearly
    # vanishes, so the non-centred latent GP has a funnel at small delta_sd:
    # a few divergences (2 of 1,400 measured)
    assert_analysis_healthy(analysis, buildup=5)


def maximum_likelihood_with_buildup():
    from scipy.optimize import minimize

    f = pd.read_csv(SHIELD / "physical.csv")

    def negative_log_lik(p):
        log_mean = np.log(shield_physics.narrow_beam(f.d, f.s, p[0]) * (1 + p[1] * p[0] * f.s))
        return -(f.counts * log_mean - np.exp(log_mean)).sum()

    return minimize(negative_log_lik, [0.3, 1.0], method="Nelder-Mead",
                    options={"xatol": 1e-10, "fatol": 1e-10}).x


@pytest.mark.slow
def test_counts_where(shield_gap):
    analysis, summary = shield_gap
    assert_analysis_healthy(analysis, buildup=5)  # see test_counts_theta_error_shrinks_with_the_effect
    importance = {v: e["mean"] for v, e in summary["where"]["importance"].items()}
    assert max(importance, key=importance.get) == "s"  # the build-up grows with the shield
    for decoy in ("pressure", "operator"):
        assert importance[decoy] < 0.2, decoy


def test_gap_on_counts_end_to_end(tmp_path):
    """The whole latent path in the default run, at a small size (the shield
    case itself is a slow study): formula candidate, PSIS and then 2-fold
    scores from Poisson densities, Sobol indices of the latent delta, report."""
    frame = pd.read_csv(SHIELD / "physical.csv").query("d in [0.5, 1.0, 2.0] and s % 2 == 0")
    data = stancal.CalibrationData(frame, ["d", "s"], "counts", {"mu": (0.05, 1.0)},
                                   covariates=["pressure"], likelihood="poisson")
    # the pipeline at a small size, not a statistical claim: 2 x (200 + 200) is too short for
    # a healthy latent fit (6 of 400 transitions diverged, bulk ESS 74 at seed 1), so the
    # sampler's warnings are expected, and each breach of the health bar must be among them
    with no_stancal_warnings(allow="diverged|effective sample size|R-hat|maximum tree depth|E-BFMI"):
        analysis = diagnose_gap(data, [Candidate("pressure", formula="pressure")],
                                simulator=ROOT / "case_studies" / "detector_counts" / "simulator.stan",
                                kfold=2, chains=2, warmup=200, draws=200, seed=1)
    for result in (analysis.baseline, *(c.result for c in analysis.candidates)):
        assert_trouble_reported(result.diagnostics.summary())
    summary = write_gap_report(analysis, tmp_path)
    assert summary["baseline"]["method"] == "koh_latent"
    assert summary["baseline"]["scheme"] == "kfold" and np.isfinite(summary["baseline"]["elpd_loo"])
    (pressure,) = summary["candidates"]
    assert pressure["scheme"] == "kfold" and np.isfinite(pressure["elpd_diff"])
    assert np.isfinite(pressure["shrinkage"]["mean"])
    assert set(summary["where"]["importance"]) == {"d", "s", "pressure"}
    assert "log of the mean count" in (tmp_path / "report.md").read_text()


def test_variant_data_keeps_the_observation_model():
    problem = load_config(SHIELD / "config.toml")
    buildup = next(c for c in problem.candidates if c.name == "buildup")
    data = variant_data(problem.data, buildup)
    assert data.observations.likelihood is Likelihood.POISSON
    assert data.levels == problem.data.levels


# ---- bad candidates: errors that name the candidate ----------------------------
@pytest.fixture(scope="module")
def cooling_problem():
    return load_config(COOLING / "config.toml")


@pytest.mark.parametrize("candidate, message", [
    (Candidate("wind", formula="I(wind**2)"), "candidate 'wind': formula 'I(wind**2)'"),
    (Candidate("broken", formula="t +"), "candidate 'broken'"),
    (Candidate("v2", stan=COOLING / "simulator_quadratic_loss.stan", inputs=("t", "pressure")),
     "candidate 'v2': unknown input column(s) ['pressure']"),
    (Candidate("gone", stan=COOLING / "nope.stan", inputs=("t",)), "candidate 'gone': Stan file not found"),
])
def test_bad_candidates_are_named(cooling_problem, candidate, message):
    with pytest.raises(CandidateError) as err:
        check_candidates(cooling_problem.data, [candidate], get_backend("pystan"))
    assert message in str(err.value)


@pytest.mark.parametrize("baseline, candidate", [
    ("humidity + t", "humidity"),
    ("humidity * t", "t:humidity"),  # the same interaction, named otherwise
    ("C(operator)", "operator"),  # the same offsets, coded again
    ("t + T0", "I(t + T0)"),  # a combination of the baseline's terms
])
def test_a_formula_candidate_must_add_a_term_to_the_baselines_mean(cooling_problem, baseline, candidate):
    """A formula candidate that does not widen the baseline's mean (its
    mean_formula and a constant: the columns' rank) would fit the baseline
    again: refused by name before anything compiles. One new term is enough."""
    plan = make_plan(cooling_problem.data, COOLING / "simulator.stan", mean_formula=baseline)
    backend = get_backend("pystan")
    with pytest.raises(CandidateError) as err:
        check_candidates(cooling_problem.data, [Candidate("c", formula=candidate)], backend, plan)
    assert str(err.value) == (f"candidate 'c': formula {candidate!r} adds no term to [model] mean_formula "
                              f"{baseline!r}, so its fit would be the baseline's again")
    check_candidates(cooling_problem.data, [Candidate("start", formula=f"{candidate} + humidity:T0")], backend, plan)


def test_variant_that_does_not_compile_is_named(cooling_problem, tmp_path):
    bad = tmp_path / "bad_variant.stan"
    bad.write_text("vector simulator(matrix X, vector theta) {\n  return theta[1] * X[:, 1] + undefined_thing;\n}\n")
    with pytest.raises(CandidateError) as err:
        check_candidates(cooling_problem.data, [Candidate("bad", stan=bad, inputs=("t", "T0"))],
                         get_backend("pystan"))
    assert "candidate 'bad': the variant does not compile" in str(err.value)
    assert "bad_variant.stan" in str(err.value) and "line 2" in str(err.value)


@pytest.mark.parametrize("snippet, message", [
    ('[candidates]\nx = 3\n', "candidate 'x': give a formula string or a table"),
    ('[candidates.v]\nstan = "simulator.stan"\ninputs = ["t"]\ncolour = 1\n', "candidate 'v': unknown key(s) ['colour']"),
    ('[candidates.v]\nstan = "missing.stan"\ninputs = ["t"]\n', "candidate 'v': Stan file not found"),
    ('[candidates.v]\nstan = "simulator.stan"\n', "[candidates.v] needs 'inputs'"),
])
def test_bad_candidate_config(tmp_path, snippet, message):
    config = tmp_path / "config.toml"
    base = (COOLING / "config.toml").read_text().split("# Candidate unmodelled effects")[0]
    base = base.replace('"physical.csv"', f'"{COOLING / "physical.csv"}"').replace(
        '"runs.csv"', f'"{COOLING / "runs.csv"}"')
    (tmp_path / "simulator.stan").write_text((COOLING / "simulator.stan").read_text())
    config.write_text(base + snippet)
    with pytest.raises(ConfigError) as err:
        load_config(config)
    assert message in str(err.value)


# ---- K-fold, used when Pareto k is high --------------------------------------------
def test_kfold_comparison_and_a_failed_candidate(exact_cooling_data, monkeypatch):
    """Forced 3-fold on a small problem: every point gets a held-out density,
    and a useless offset per half of the data does not beat the baseline.
    A candidate whose fit fails (twice) is named and left out; the rest
    are ranked (in-process, so that the failure can be planted). Each fold's
    refit starts from its full fit (stancal.fitting.warm_start): PyStan is
    given a draw of the full fit per chain, its step size and a short warm-up."""
    frame = exact_cooling_data.source.assign(half=np.where(np.arange(24) % 2, "odd", "even"))
    data = stancal.CalibrationData(frame, ["t", "T0"], "temperature", {"k": (0.01, 0.2)})
    real_calibrate = stancal.diagnosing.gap.calibrate
    attempts, fits, sampled = [], [], []

    def calibrate(data, **options):
        if options["plan"].options.mean_formula == "t":
            attempts.append(1)
            raise RuntimeError("Stan failed while sampling: planted")
        fits.append((options, real_calibrate(data, **options)))
        return fits[-1][1]

    def model_sample(model, **kwargs):  # what reaches httpstan
        sampled.append(kwargs)
        return real_sample(model, **kwargs)

    real_sample = stan.model.Model.sample
    monkeypatch.setattr(stan.model.Model, "sample", model_sample)
    monkeypatch.setattr(stancal.diagnosing.gap, "calibrate", calibrate)
    # the pipeline and loose claims (the held-out error within 0.2-0.6, a difference within 2 se):
    # of the 9 refits at 4 x (300 + 700) on two thirds of the points, one had R-hat 1.01 and one
    # transition diverged (seed 5), so those warnings are expected; the full fits' health is asserted
    with no_stancal_warnings(allow="diverged|R-hat|effective sample size"):
        analysis = diagnose_gap(data, [Candidate("half", formula="C(half)"), Candidate("slope", formula="t")],
                                simulator=COOLING / "simulator.stan", kfold=3, scheduler="in-process",
                                chains=4, warmup=300, draws=700, seed=5,  # at 4 x (300 + 300) R-hat 1.010
                                warm_candidates=True)
    assert_analysis_healthy(analysis, divergences=2)  # the full fits: at most one divergence seen
    summary = analysis.to_json()
    assert [c["name"] for c in summary["candidates"]] == ["half"] and len(attempts) == 2
    assert summary["failed"] == [{"name": "candidate 'slope'", "error": "RuntimeError: Stan failed while "
                                                                         "sampling: planted"}]
    assert summary["baseline"]["scheme"] == "kfold"
    assert np.isfinite(analysis.baseline_score.elpd_i).all()
    assert summary["candidates"][0]["elpd_diff"] < 2 * summary["candidates"][0]["elpd_diff_se"]
    # the exact simulator with noise 0.3 predicts held-out points to about the noise
    assert 0.2 < summary["baseline"]["holdout_rmse"] < 0.6
    assert_refits_warm(fits, sampled, folds=3, rows=24)


def assert_refits_warm(fits, sampled, folds, rows):
    """Every candidate's fit started from a draw of the baseline's (the first
    fit), and every refit (a fit to fewer rows than the full one) from a draw
    of its own full fit, each with that fit's step size, in a short warm-up."""
    assert len(sampled) == len(fits)
    full = [(options, result, kwargs) for (options, result), kwargs in zip(fits, sampled, strict=True)
            if len(result.data.physical) == rows]
    for _, _, kwargs in full[1:]:
        assert_started_from(full[0][1], kwargs, candidate_warmup(300), 700)
    by_term = {options["plan"].options.mean_formula: result for options, result, _ in full}
    refits = [(options, kwargs) for (options, result), kwargs in zip(fits, sampled, strict=True)
              if len(result.data.physical) < rows]
    assert len(refits) == folds * len(full)
    for options, kwargs in refits:
        assert_started_from(by_term[options["plan"].options.mean_formula], kwargs, refit_warmup(300),
                            refit_draws(700))


def assert_started_from(source, kwargs, warmup, draws):
    """httpstan was given a draw of ``source`` per chain (theta by value), its median step size, and
    ``warmup`` iterations in Stan's three adaptation stages, then ``draws``."""
    thetas = np.asarray(source.idata["stan_parameters"]["theta_unit"]).reshape(-1)
    assert all(np.isclose(np.asarray(init["theta_unit"])[:, None], thetas, rtol=0, atol=1e-9).any(axis=1).all()
               for init in kwargs["init"])
    assert kwargs["stepsize"] == pytest.approx(np.median(np.asarray(source.idata["sample_stats"]["step_size"])))
    assert (kwargs["num_warmup"], kwargs["num_samples"]) == (warmup, draws)
    assert kwargs["init_buffer"] + kwargs["window"] + kwargs["term_buffer"] == kwargs["num_warmup"]


def test_a_formula_candidate_keeps_the_baselines_mean_terms():
    """The formula a formula candidate fits beside a baseline with mean terms
    of its own (mean_formula): both sets of terms, the candidate's grouped so
    that its own minus signs do not remove the baseline's terms."""
    from stancal.problem.mean_terms import build_mean_terms

    candidate = Candidate("start", formula="T0")
    assert candidate.with_baseline_terms(None) == "T0"
    joined = candidate.with_baseline_terms("I(t**2)")
    frame = pd.DataFrame({"t": [1.0, 2.0, 3.0], "T0": [60.0, 90.0, 75.0]})
    assert build_mean_terms(joined, frame).names == ["I(t ** 2)", "T0"]
    grouped = Candidate("rest", formula="T0 - t").with_baseline_terms("t")
    assert build_mean_terms(grouped, frame).names == ["t", "T0"]
