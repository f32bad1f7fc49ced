import time

import pytest

from stancal.stan.backends import get_backend
from stancal.stan.backends.cmdstanpy_backend import cmdstan_available

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
    from conftest import COOLING, K_TRUE, assert_healthy, fit

    result = fit(exact_cooling_data, simulator=COOLING / "simulator.stan", method="koh",
                 backend="cmdstanpy")
    k = result.theta_summary()["k"]
    assert result.backend == "cmdstanpy"
    assert_healthy(result)
    assert k["q05"] < K_TRUE < k["q95"]


def test_a_cached_build_prints_nothing(koh_fit, capfd):
    """PyStan prints stanc's warnings about the flat program on every build;
    stancal shows the user's own once, at compile time (test_stan_source)."""
    import pandas as pd

    from stancal.stan.backends.pystan_backend import PyStanBackend
    from stancal.stan.registry import PROGRAMS
    from stancal.stan.standata import build_stan_data, to_stan_json

    point = pd.DataFrame({"t": [10.0], "T0": [70.0]})
    data = to_stan_json(build_stan_data(koh_fit.data, PROGRAMS[koh_fit.method].data, koh_fit.options, point))
    capfd.readouterr()
    PyStanBackend()._build(koh_fit.program, data, seed=1)
    printed = capfd.readouterr()
    assert printed.out == "" and printed.err == ""


def test_draws_written_for_cmdstans_standalone_generated_quantities_read_back(tmp_path):
    """CmdStan reruns generated quantities from Stan CSV files; stancal writes
    them from stored draws. cmdstanpy's own reader (no CmdStan needed) must
    get every element back in place, matrices column-major."""
    import cmdstanpy
    import numpy as np

    from stancal.stan.backends.cmdstanpy_backend import write_stan_csv

    rng = np.random.default_rng(1)
    draws = {"theta_unit": rng.uniform(size=(2, 5, 1)), "noise_sd": rng.uniform(size=(2, 5)),
             "m": rng.normal(size=(2, 5, 2, 3))}
    files = [str(write_stan_csv(tmp_path / f"chain-{c}.csv", draws, c, seed=3)) for c in range(2)]
    fit = cmdstanpy.from_csv(files)
    assert fit.chains == 2 and fit.num_draws_sampling == 5
    for name, values in draws.items():
        np.testing.assert_array_equal(fit.stan_variable(name).reshape(values.shape), values)


def test_the_cmdstanpy_backend_runs_without_pystan():
    """Generated quantities under cmdstanpy go through CmdStan, not PyStan."""
    import ast
    from pathlib import Path

    from stancal.stan.backends import cmdstanpy_backend

    tree = ast.parse(Path(cmdstanpy_backend.__file__).read_text())
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert not {m for m in imported if m.split(".")[0] in ("stan", "httpstan") or "pystan" in m}, imported


def test_programs_compile_side_by_side_quietly_into_the_cache(capfd):
    """compile() builds uncached programs in worker processes (one per core)
    into httpstan's cache, where sampling then finds them; g++ prints nothing.
    A new environment (httpstan's cache lacks the program) gets the module
    from the machine's store instead of compiling again."""
    import httpstan.cache

    from stancal.stan.backends.pystan_backend import PyStanBackend
    from stancal.stan.backends.pystan_compile import is_compiled, model_name, stored_module
    from stancal.stan.source import FlatProgram

    programs = [FlatProgram(f"parameters {{ real {name}; }}\nmodel {{ {name} ~ std_normal(); }}\n",
                            (("side_by_side.stan", 1), ("side_by_side.stan", 2)))
                for name in ("first", "second")]
    for program in programs:  # built before the store existed: build again, so that the store gets it
        if not stored_module(program.code).is_file():
            httpstan.cache.delete_model_directory(model_name(program.code))
    capfd.readouterr()
    PyStanBackend().compile(programs)
    assert all(is_compiled(p.code) for p in programs)
    assert all(stored_module(p.code).is_file() for p in programs)
    assert "g++" not in capfd.readouterr().err

    httpstan.cache.delete_model_directory(model_name(programs[1].code))  # as a fresh venv sees it
    assert not is_compiled(programs[1].code)
    started = time.perf_counter()
    sample = PyStanBackend().sample(programs[1], {}, chains=1, warmup=50, draws=50, seed=1, inits=None,
                                    adapt_delta=0.8, max_treedepth=10)
    assert time.perf_counter() - started < 30  # from the store, not built again
    assert sample.draws["second"].shape == (1, 50)


def test_stanc_waits_for_a_busy_machine(monkeypatch, tmp_path):
    """httpstan gives stanc one second, which a loaded machine exceeds
    (issue 29: subprocess.TimeoutExpired while compiles ran beside it);
    stancal's stanc gives the same output and waits. A stanc slowed by 1.5 s
    stands in for the busy machine."""
    import subprocess

    import httpstan.compile

    from stancal.stan.backends import pystan_compile

    slow = tmp_path / "stanc"
    slow.write_text(f"#!/bin/sh\nsleep 1.5\nexec {pystan_compile.stanc_binary()} \"$@\"\n")
    slow.chmod(0o755)
    code = "parameters { real x; } model { x ~ normal(0, 1); }"
    fast_cpp, fast_warnings = pystan_compile.stanc(code, "m")
    monkeypatch.setattr(pystan_compile, "stanc_binary", lambda: slow)
    cpp, warnings = pystan_compile.stanc(code, "m")
    assert warnings == fast_warnings and "class m " in cpp and len(cpp.splitlines()) == len(fast_cpp.splitlines())
    with monkeypatch.context() as patched:  # httpstan's own call, with the same slow stanc, gives up
        patched.setattr(httpstan.compile.importlib.resources, "path", lambda *a: _Here(slow))
        with pytest.raises(subprocess.TimeoutExpired):
            httpstan.compile.compile(code, "m")


class _Here:
    """A context manager giving a fixed path (importlib.resources.path's shape)."""

    def __init__(self, path):
        self.path = path

    def __enter__(self):
        return self.path

    def __exit__(self, *exc):
        return False
