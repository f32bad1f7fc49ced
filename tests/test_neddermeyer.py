"""SEPIA's Neddermeyer implosion (github.com/lanl/SEPIA, examples/Neddermeyer;
Higdon et al. 2008, JASA 103), regenerated from its physics by
case_studies/neddermeyer/make_data.py: theta's posterior is as narrow as the
data allow (issue 31). The near-exact reference is the physics itself by
quadrature (case_studies/neddermeyer/reference.py); docs/neddermeyer.md has
the measurements behind the tolerances."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, assert_healthy, case_study_module, no_stancal_warnings

NEDDERMEYER = ROOT / "case_studies" / "neddermeyer"
# SEPIA's posterior sd over the prior sd (yield stress, HE energy): its example's own printout of
# the same regenerated problem (docs/neddermeyer.md), 3 components and a 24-kernel discrepancy
SEPIA_SD_OVER_PRIOR = np.array([0.083, 0.12])


def _problem():
    """The shipped case study, with the basis the default rule keeps (not the config's `components = 3`;
    the rule also keeps 3)."""
    from stancal.problem.vector_data import VectorCalibrationData

    physical, runs = pd.read_csv(NEDDERMEYER / "physical.csv"), pd.read_csv(NEDDERMEYER / "runs.csv")
    theta = case_study_module(NEDDERMEYER).THETA_BOUNDS
    return VectorCalibrationData(physical, "shot", ["mass_ratio"], "radius", ["time", "angle"], theta,
                                 runs=runs, run="run")


def test_the_regenerated_data_are_the_shipped_ones(tmp_path):
    """make_data.py writes the CSVs the case study ships, byte for byte."""
    case_study_module(NEDDERMEYER).main(tmp_path)
    for name in ("physical.csv", "runs.csv"):
        assert (tmp_path / name).read_bytes() == (NEDDERMEYER / name).read_bytes(), name


def test_the_reference_is_the_quadrature_of_the_physics_and_holds_the_truth():
    """The near-exact posterior (no emulator, no discrepancy, the noise sd
    integrated out): its grid holds the posterior (mass on the fine grid's
    border below 1e-6) and a finer grid changes its sds by under 1 %; the
    truth (the middle of each range) within 2 sds; theta's two parameters on
    one ridge (correlation above 0.9: a stronger cylinder needs more energy)."""
    make_data, reference = case_study_module(NEDDERMEYER), case_study_module(NEDDERMEYER, "reference")
    physical = pd.read_csv(NEDDERMEYER / "physical.csv")
    ref = reference.reference_posterior(physical)
    finer = reference.reference_posterior(physical, fine=81, zoom=0.07)  # a finer step, over less of the box
    assert ref.edge_mass < 1e-6, ref
    np.testing.assert_allclose(finer.sd, ref.sd, rtol=0.01)
    truth = np.array([make_data.YIELD_STRESS, make_data.HE_ENERGY])
    assert np.all(np.abs(ref.mean - truth) < 2 * ref.sd), (ref, truth)
    assert ref.correlation > 0.9 and np.all(ref.sd_over_prior < 0.06), ref


def test_the_default_basis_keeps_the_components_that_carry_theta():
    """The fast version of the calibration test below, no sampling: the
    default basis leaves a truncation error (taken by the likelihood as
    independent noise) below the measurements' 0.01 cm, keeping SEPIA's 3
    components. The default before issue 31 (99.5 % of the runs' variance)
    kept 1 and left 0.025 cm: theta's sd was then 0.83 of its prior's."""
    make_data = case_study_module(NEDDERMEYER)
    basis = _problem().basis
    truncation_sd = np.sqrt(basis.truncation_variance) * basis.scale
    assert basis.count == 3 and truncation_sd < make_data.NOISE_SD / 2, (basis.describe(), truncation_sd)


@pytest.mark.slow
def test_modular_on_neddermeyer_is_as_sharp_as_sepia_and_near_the_physics():
    """Issue 31's case, default basis, a GP discrepancy, the noise
    estimated, 4 x (500 + 500), about 5 minutes: theta's posterior sd within
    1.5 times SEPIA's (the issue's bar), and within 2.5 times the
    near-exact no-discrepancy reference's (measured 2.0 and 2.1: the
    emulator's uncertainty makes 1.4 of that, the discrepancy, which the data
    cannot tell from zero, the rest; docs/neddermeyer.md); the truth within
    2.5 sds. Before issue 31 the default basis kept one component, and the
    sds were 0.83 and 0.69 of the prior's."""
    from stancal.fitting.vector_calibrate import calibrate_vector

    make_data, reference = case_study_module(NEDDERMEYER), case_study_module(NEDDERMEYER, "reference")
    data = _problem()
    with no_stancal_warnings():
        result = calibrate_vector(data, method="modular", discrepancy="gp", noise="one", chains=4, warmup=500,
                                  draws=500, seed=1)
    assert_healthy(result)
    summary = result.theta_summary()
    bounds = make_data.THETA_BOUNDS
    sd = np.array([summary[name]["sd"] / ((high - low) / np.sqrt(12)) for name, (low, high) in bounds.items()])
    ref = reference.reference_posterior(data.physical)
    print(sd, ref.sd_over_prior, summary)
    assert np.all(sd <= 1.5 * SEPIA_SD_OVER_PRIOR), (sd, SEPIA_SD_OVER_PRIOR)
    assert np.all(sd <= 2.5 * ref.sd_over_prior), (sd, ref.sd_over_prior)
    truth = {"yield_stress": make_data.YIELD_STRESS, "he_energy": make_data.HE_ENERGY}
    for name, value in truth.items():
        assert abs(summary[name]["mean"] - value) <= 2.5 * summary[name]["sd"], (name, summary[name])
