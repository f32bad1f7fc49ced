"""The command line: a full run on the shipped case study and bad input."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr
from conftest import COOLING, assert_trouble_reported

STANCAL = [sys.executable, "-m", "stancal.cli"]


def run(*args, cwd=None):
    return subprocess.run([*STANCAL, *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "out"
    done = run("calibrate", COOLING / "config.toml", "--out", out, "--chains", 4, "--warmup", 300,
               "--draws", 300, "--seed", 4, "--backend", "pystan")
    return done, out


def test_calibrate_writes_the_report_folder(cli_run):
    done, out = cli_run
    assert done.returncode == 0, done.stderr
    # checks the folder's files and fields, not the posterior: the shipped case study's simulator
    # lacks a loss the discrepancy takes up, and theta mixes slowly with it (R-hat 1.012 to 1.018
    # at 4 x (300 + 300) up to 4 x (500 + 500) with adapt_delta 0.99), so its trouble must be reported
    assert_trouble_reported(json.loads((out / "summary.json").read_text())["diagnostics"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "koh" and summary["backend"] == "pystan"
    k = summary["theta"]["k"]
    assert set(k) >= {"mean", "sd", "q05", "q50", "q95", "rhat", "ess_bulk"}
    # the summary is that of the posterior written beside it
    import xarray as xr

    draws = np.asarray(xr.open_datatree(out / "posterior.nc")["posterior"]["theta"]).ravel()
    assert k["q05"] == pytest.approx(np.quantile(draws, 0.05), rel=1e-9)
    assert k["q95"] == pytest.approx(np.quantile(draws, 0.95), rel=1e-9)
    assert k["rhat"] <= 1.01
    assert set(summary["diagnostics"]["warnings"]) <= set(summary["warnings"])  # reported, not hidden
    assert set(summary["diagnostics"]) >= {"divergences", "max_rhat", "min_ess_bulk"}
    assert set(summary["timing"]) == {"compile_s", "sample_s"}
    for name in ("posterior.nc", "theta.png", "fit.png", "discrepancy.png", "report.md", "report.html"):
        assert (out / name).stat().st_size > 0, name


def write_config(tmp_path, physical_columns="t,T0,humidity,operator,temperature", stan="simulator.stan"):
    for path in [*COOLING.glob("*.stan"), COOLING / "runs.csv"]:  # the candidates' variants too
        shutil.copy(path, tmp_path / path.name)
    rows = (COOLING / "physical.csv").read_text().splitlines()
    rows[0] = physical_columns
    (tmp_path / "physical.csv").write_text("\n".join(rows) + "\n")
    config = (COOLING / "config.toml").read_text().replace('stan = "simulator.stan"', f'stan = "{stan}"')
    (tmp_path / "config.toml").write_text(config)
    return tmp_path / "config.toml"


def test_missing_column_exits_with_one_line(tmp_path):
    config = write_config(tmp_path, physical_columns="t,T0,humidity,operator,temp")
    done = run("calibrate", config, "--out", tmp_path / "out")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert lines[-1].startswith(f"stancal: error: physical data ({tmp_path / 'physical.csv'}): "
                                "missing column(s) ['temperature']")
    assert "Traceback" not in done.stderr


def test_missing_config_file(tmp_path):
    done = run("calibrate", tmp_path / "nope.toml", "--out", tmp_path / "out")
    assert done.returncode == 2
    assert "config file not found" in done.stderr


def test_stan_error_points_at_the_users_file_and_line(tmp_path):
    config = write_config(tmp_path, stan="broken.stan")
    (tmp_path / "broken.stan").write_text(
        "// cooling, with a typo\nvector simulator(matrix X, vector theta) {\n"
        "  return 20 + (X[:, 2] - 20) .* exp(-thta[1] * X[:, 1]);\n}\n")
    done = run("calibrate", config, "--out", tmp_path / "out", "--backend", "pystan")
    assert done.returncode == 2
    message = done.stderr.strip().splitlines()[-1]
    assert f"line 3 of {tmp_path / 'broken.stan'}" in message
    assert "thta" in message


def test_sbc_command_writes_ranks_and_verdicts(tmp_path):
    """`stancal sbc` end to end on a few simulations: a rank per simulation
    for every parameter and for the log-likelihood, an ECDF figure, and a
    verdict line per quantity; the fits' health summed up, with advice; a
    subset of the simulations refitted as in the whole run."""
    # health not asserted: 1 chain of 100 + 40 draws per fit checks the command's files and fields; that the
    # fits are short is what the run's health summary must say
    out = tmp_path / "sbc"
    done = run("sbc", COOLING / "config.toml", "--out", out, "--sims", 6, "--draws-per-fit", 20, "--chains", 1,
               "--warmup", 100, "--seed", 2, "--scheduler", "in-process")
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((out / "sbc.json").read_text())
    assert summary["simulations"] == 6 and summary["draws_per_fit"] == 20 and summary["failed_simulations"] == []
    parameters = summary["parameters"]
    assert {"theta[k]", "noise_sd", "delta_sd", "log_likelihood"} <= set(parameters)
    for name, row in parameters.items():
        assert 0 <= row["p_value"] <= 1 and row["verdict"].startswith(name) and row["verdict"] in done.stdout
    assert (out / "ecdf.png").is_file()
    folders = sorted((out / "fits").iterdir())
    assert len(folders) == 6
    for simulation, folder in enumerate(folders):
        # each rank again, from the truth and the thinned draws saved beside the fit: draws below the truth
        truth = json.loads((folder / "truth.json").read_text())["values"]
        draws = json.loads((folder / "ranked_draws.json").read_text())
        assert set(draws) == set(truth) == set(parameters)
        for name, row in parameters.items():
            assert len(draws[name]) == 20
            assert row["ranks"][simulation] == sum(d < truth[name] for d in draws[name]), (simulation, name)
        # and those are draws of the saved fit: the parameters' from its posterior, the
        # log-likelihood's sums of its pointwise log_lik at a draw
        tree = xr.open_datatree(folder / "posterior.nc")
        posterior = np.concatenate([np.ravel(v) for v in tree["posterior"].to_dataset().data_vars.values()])
        log_lik = np.asarray(tree["log_likelihood"]["y"])
        sums = log_lik.reshape(-1, log_lik.shape[-1]).sum(-1)
        assert all(np.isin(draws[name], posterior).all() for name in draws if name != "log_likelihood")
        assert all(np.isclose(d, sums, rtol=1e-12).any() for d in draws["log_likelihood"])
        assert 0.01 <= truth["theta[k]"] <= 0.2  # from the prior, within k's bounds
    health = summary["fits_health"]
    assert health["fits"] == 6 and health["fit_draws"] == 40 and health["ess_below_needed"] >= 1
    assert "warning: SBC's fits: " in done.stderr and "--subset with --warmup 1000 --draws 1000" in done.stderr
    # --subset: those simulations alone, each as in the whole run (the same fingerprint: here reused)
    part = run("sbc", COOLING / "config.toml", "--out", out, "--sims", 6, "--draws-per-fit", 20, "--chains", 1,
               "--warmup", 100, "--seed", 2, "--scheduler", "in-process", "--subset", 4, 1)
    assert part.returncode == 0, part.stderr[-3000:]
    assert "reused 2 of 2 fits finished earlier" in part.stderr
    again = json.loads((out / "sbc.json").read_text())
    assert again["simulations"] == 2 and again["parameters"]["noise_sd"]["ranks"] == \
        [parameters["noise_sd"]["ranks"][4], parameters["noise_sd"]["ranks"][1]]
