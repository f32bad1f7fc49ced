import pytest

from stancal.backends import get_backend
from stancal.backends.cmdstanpy_backend import cmdstan_available

needs_cmdstan = pytest.mark.skipif(
    not cmdstan_available(),
    reason="CmdStan is not installed (cmdstanpy.cmdstan_path() fails); "
    "cmdstanpy.install_cmdstan() needs GitHub, which this machine cannot reach",
)


def test_auto_picks_what_is_installed():
    expected = "cmdstanpy" if cmdstan_available() else "pystan"
    assert get_backend("auto").name == expected


def test_environment_variable_selects_backend(monkeypatch):
    monkeypatch.setenv("STANCAL_BACKEND", "pystan")
    assert get_backend().name == "pystan"


def test_unknown_backend():
    with pytest.raises(ValueError, match="backend must be one of auto, cmdstanpy, pystan"):
        get_backend("jags")


@pytest.mark.skipif(cmdstan_available(), reason="CmdStan is installed here")
def test_cmdstanpy_without_cmdstan_says_so():
    with pytest.raises(RuntimeError, match="needs a CmdStan installation"):
        get_backend("cmdstanpy")


@pytest.mark.cmdstan
@needs_cmdstan
def test_cmdstanpy_recovers_theta(exact_cooling_data):
    from conftest import COOLING, K_TRUE, fit

    result = fit(exact_cooling_data, simulator=COOLING / "simulator.stan", method="koh",
                 backend="cmdstanpy")
    k = result.theta_summary()["k"]
    assert result.backend == "cmdstanpy"
    assert k["q05"] < K_TRUE < k["q95"]
