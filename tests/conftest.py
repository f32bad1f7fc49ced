"""Shared fixtures. Every Stan program is compiled once per run (PyStan caches
it), and each fit that several tests read is made once per session."""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import stancal

ROOT = Path(__file__).resolve().parent.parent
COOLING = ROOT / "case_studies" / "cooling"
sys.path.insert(0, str(COOLING))
from make_data import K_TRUE, newton  # noqa: E402  (the case study's own physics)

# fits made once per session and read by several test files
SESSION_FITS = ("koh_fit", "koh_emulator_fit", "modular_fit", "cooling_gap")
# `./run tests` runs two pytest-xdist workers. Each test file runs on one worker, and
# the files that read one session fit share a worker, so that no fit is made twice
# (pytest_collection_modifyitems checks this table against the fixtures the tests use)
WORKER_GROUPS = {"test_backends.py": "cooling_fits", "test_predict.py": "cooling_fits",
                 "test_recovery.py": "cooling_fits", "test_reporting.py": "cooling_fits"}


def _group(file_name: str) -> str:
    return WORKER_GROUPS.get(file_name, file_name)


def pytest_xdist_make_scheduler(config, log):
    """xdist's load-by-scope scheduling, with a file's scope its group."""
    from xdist.scheduler import LoadScopeScheduling

    class ByGroup(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _group(nodeid.split("::", 1)[0].rsplit("/", 1)[-1])

    return ByGroup(config, log)


def pytest_collection_modifyitems(items):
    """Refuse to run when files that read one session fit are in different
    worker groups: each worker would make the fit again."""
    for fit in SESSION_FITS:
        files = set()
        for item in items:
            callspec = getattr(item, "callspec", None)  # a fit named by a parameter (request.getfixturevalue)
            named = {v for v in (callspec.params.values() if callspec else ()) if isinstance(v, str)}
            if fit in set(item.fixturenames) | named:
                files.add(item.path.name)
        if len({_group(f) for f in files}) > 1:
            raise pytest.UsageError(f"tests/conftest.py: {sorted(files)} read the session fit {fit!r}; "
                                    "put them in one WORKER_GROUPS group")


def cooling_data(seed: int) -> stancal.CalibrationData:
    """Data from the exact simulator at k = 0.05 with noise sd 0.3, plus the shipped runs."""
    rng = np.random.default_rng(seed)
    t = np.tile(np.linspace(2, 60, 12), 2)
    T0 = np.repeat([60.0, 90.0], 12)
    physical = pd.DataFrame({"t": t, "T0": T0,
                             "temperature": newton(t, T0, K_TRUE) + 0.3 * rng.standard_normal(t.size)})
    runs = pd.read_csv(COOLING / "runs.csv")
    # every physical input lies inside the runs' range (t 0.96-61.5, T0 55.4-94.5):
    # an InputRangeWarning here would be a regression, so it is an error
    with warnings.catch_warnings():
        warnings.simplefilter("error", stancal.InputRangeWarning)
        return stancal.CalibrationData(physical, ["t", "T0"], "temperature", {"k": (0.01, 0.2)}, runs=runs)


@pytest.fixture(scope="session")
def exact_cooling_data() -> stancal.CalibrationData:
    return cooling_data(seed=7)


# ---- the design loop's toy problem (test_design_*.py, test_emulator_checks.py) ----------------------------------
TOY_TRUTH = {"a": 0.6, "b": -0.4}
TOY_BOUNDS = {"a": (0.0, 1.0), "b": (-1.0, 1.0)}


def toy_simulator(frame: pd.DataFrame) -> np.ndarray:
    """A cheap stand-in for an expensive simulator: f(x; a, b) = a sin(3x) + b x."""
    return (frame["a"] * np.sin(3 * frame["x"]) + frame["b"] * frame["x"]).to_numpy()


def toy_data(runs: int = 30, seed: int = 1, noise: float = 0.02) -> stancal.CalibrationData:
    from scipy.stats import qmc

    x = np.linspace(0, 1, 8)
    physical = pd.DataFrame({"x": x})
    physical["y"] = toy_simulator(physical.assign(**TOY_TRUTH)) + np.random.default_rng(seed).normal(0, noise, len(x))
    unit = qmc.LatinHypercube(d=3, seed=seed).random(runs)
    table = pd.DataFrame(qmc.scale(unit, [0, 0, -1], [1, 1, 1]), columns=["x", "a", "b"])
    table.loc[:1, "x"] = [0.0, 1.0]  # the runs span the physical inputs: no point needs extrapolation
    table["y"] = toy_simulator(table)
    return stancal.CalibrationData(physical, ["x"], "y", TOY_BOUNDS, runs=table)


# Read by several files and by no test changed (history_match's and run_waves' results are only read). Not in
# SESSION_FITS / WORKER_GROUPS: at about a second each, building them once per xdist worker is cheaper than
# tying the four design files to one worker.
@pytest.fixture(scope="session")
def toy_match():
    """history_match(toy_data(), seed=2): one wave on 30 runs."""
    return stancal.history_match(toy_data(), seed=2)


@pytest.fixture(scope="session")
def toy_two_waves():
    """Two waves of 30 runs after 12: wave 1's proposals lie inside its NROY, so wave 2 has the 10 per
    dimension of (x, a, b) it needs to refocus."""
    return stancal.run_waves(toy_data(runs=12), simulator=toy_simulator, waves=2, runs_per_wave=30, seed=1)


def direct_theta_trace(cut, theta: np.ndarray, x: np.ndarray, length: float | None = None, step: float = 1e-3) -> float:
    """The experiments criterion computed directly (stancal.designing.experiments): the mean over ``theta``
    (unit cube) of trace((12 I + G' V^-1 G)^-1), G by central differences at every value of ``x`` (old and
    new), V the discrepancy's covariance plus the emulator's variance (mean over ``theta``) and the noise."""
    from stancal.designing.experiments import DISCREPANCY_LENGTH, discrepancy_covariance

    Q = theta.shape[1]
    variance = np.mean([cut.emulator.at(x, t[None])[1][0] for t in theta], axis=0)
    V = discrepancy_covariance(cut, x, x, DISCREPANCY_LENGTH if length is None else length) + np.diag(variance + cut.targets.noise_variance.mean())
    traces = []
    for t in theta:
        up, down = (np.clip(t + step * e, 0, 1) for e in (np.eye(Q), -np.eye(Q)))
        gradient = np.column_stack([(cut.emulator.at(x, up[q][None])[0] - cut.emulator.at(x, down[q][None])[0])[0]
                                    / (up[q] - down[q])[q] for q in range(Q)])
        traces.append(np.trace(np.linalg.inv(12 * np.eye(Q) + gradient.T @ np.linalg.solve(V, gradient))))
    return float(np.mean(traces))


def case_study_module(folder: Path, name: str = "make_data"):
    """A case study's module (make_data.py, reference.py, ...), loaded by
    path under ``<folder>_<name>`` (each case study has its own make_data),
    once per process; registered before it runs, as dataclasses need."""
    key = f"{folder.name}_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, folder / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]


def fit(data, **kwargs):
    """Small but honest sampling settings for tests. Sampler warnings are not
    hidden: recovery tests assert the fit's health with assert_healthy."""
    settings = {"chains": 2, "warmup": 400, "draws": 400, "seed": 11}
    settings.update(kwargs)
    return stancal.calibrate(data, **settings)


RHAT_LIMIT = 1.01
BFMI_LIMIT = 0.3  # Betancourt (2016): E-BFMI below 0.3 flags poor exploration of the energy


def se(x1: np.ndarray, x2: np.ndarray, sd: float, length_scale) -> np.ndarray:
    """The squared exponential kernel, written out (the numpy references of the Stan densities)."""
    r2 = (((x1[:, None, :] - x2[None, :, :]) / np.asarray(length_scale)) ** 2).sum(-1)
    return sd**2 * np.exp(-0.5 * r2)


def assert_log_density_is(program, stan_data: dict, points: list[dict], reference) -> None:
    """The compiled ``program``'s log density without the Jacobian at each
    parameter point against ``reference(stan_data, point)``, the model
    written out in numpy: their differences agree to 1e-8 (the constants
    Stan's ~ drops cancel in a difference)."""
    import stan

    from stancal.stan.backends.pystan_compile import compile_programs

    compile_programs([program])
    model = stan.build(program.code, data=stan_data, random_seed=1)
    stan_lp = [model.log_prob(model.unconstrain_pars(p), adjust_transform=False) for p in points]
    np.testing.assert_allclose(np.diff(stan_lp), np.diff([reference(stan_data, p) for p in points]),
                               rtol=1e-8, atol=1e-8)


def e_bfmi(energy: np.ndarray) -> np.ndarray:
    """E-BFMI per chain, sum(diff(E)^2) / sum((E - mean E)^2), from a
    (chain, draw) array of the Hamiltonian's energy (computed here, not read
    from the library's Diagnostics, so that the check is independent)."""
    energy = np.asarray(energy, dtype=float)
    return (np.square(np.diff(energy, axis=1)).sum(axis=1)
            / np.square(energy - energy.mean(axis=1, keepdims=True)).sum(axis=1))


def assert_healthy(result, divergences: int = 0, treedepth_share: float = 0.05, rhat: float = RHAT_LIMIT) -> None:
    """The health of a fit, for scalar and vector results alike: R-hat <= 1.01
    over every diagnosed parameter, at most ``divergences`` divergent
    transitions (a test that allows any says why), at most ``treedepth_share``
    of the transitions at the maximum tree depth, and E-BFMI >= 0.3 in every
    chain (from the energy in ``result.idata``, and as the library records it).
    ``rhat``: a looser bar, for a test that says why."""
    d = result.diagnostics
    assert d is not None, "the result carries no sampler diagnostics"
    assert d.max_rhat <= rhat, f"R-hat {d.max_rhat:.4f} at {d.worst_rhat}"
    assert d.divergences <= divergences, f"{d.divergences} divergences of {d.draws}"
    assert d.treedepth_hits <= treedepth_share * d.draws, \
        f"{d.treedepth_hits} of {d.draws} transitions at the maximum tree depth (> {treedepth_share:.0%})"
    energy = result.idata["sample_stats"]["energy"].transpose("chain", "draw")
    bfmi = e_bfmi(np.asarray(energy))
    assert np.all(bfmi >= BFMI_LIMIT), f"E-BFMI {np.round(bfmi, 3).tolist()} < {BFMI_LIMIT}"
    assert not d.low_bfmi_chains, f"the library flags low E-BFMI in chains {d.low_bfmi_chains}"


def assert_gap_summary_healthy(summary: dict, claims: tuple[str, ...], divergences: int = 0) -> None:
    """A `stancal gap` run's gap.json: the baseline and the candidates named in
    ``claims`` (the fits a test's claims rest on) pass the health bar; every
    other candidate's trouble is reported in its own warnings, never hidden.
    (Decoy candidates that stand in for the discrepancy's level or share a
    ridge with it are hard to sample: the cooling humidity decoy's fit had
    R-hat 1.10 and 145 of 1,400 divergences at 2 x (400 + 700).)"""
    assert_healthy_summary(summary["baseline"]["diagnostics"], divergences)
    for c in summary["candidates"]:
        if c["name"] in claims:
            assert_healthy_summary(c["diagnostics"], divergences)
        else:
            assert_trouble_reported(c["diagnostics"])


def assert_trouble_reported(diagnostics: dict) -> None:
    """Every breach of the health bar is named in the fit's warnings."""
    warned = " ".join(diagnostics.get("warnings", []))
    if diagnostics["max_rhat"] > RHAT_LIMIT:
        assert "R-hat" in warned, diagnostics
    if diagnostics["divergences"]:
        assert "diverged" in warned, diagnostics
    if diagnostics.get("treedepth_hits"):
        assert "maximum tree depth" in warned, diagnostics


def assert_healthy_summary(diagnostics: dict, divergences: int = 0, treedepth_share: float = 0.05) -> None:
    """The same bar for a fit known only by the diagnostics a command wrote to
    JSON (summary.json, gap.json). Tree depth and E-BFMI from their own keys
    where the JSON has them (treedepth_hits with draws, low_bfmi_chains), and
    otherwise from the sampler's warnings, which state the tree-depth hits as
    "h of n transitions" and name any chain whose E-BFMI is below 0.3."""
    assert diagnostics, "no diagnostics recorded"
    assert diagnostics["max_rhat"] <= RHAT_LIMIT, diagnostics
    assert diagnostics["divergences"] <= divergences, diagnostics
    if "treedepth_hits" in diagnostics and "draws" in diagnostics:
        assert diagnostics["treedepth_hits"] <= treedepth_share * diagnostics["draws"], diagnostics
    if "low_bfmi_chains" in diagnostics:
        assert not diagnostics["low_bfmi_chains"], diagnostics
    for warning in diagnostics.get("warnings", []):
        hits = re.search(r"(\d+) of (\d+) transitions hit the maximum tree depth", warning)
        assert hits is None or int(hits[1]) <= treedepth_share * int(hits[2]), warning
        assert "E-BFMI" not in warning, warning


STANCAL_WARNINGS = (stancal.SamplerWarning, stancal.MultimodalWarning, stancal.GapWarning,
                    stancal.InputRangeWarning, stancal.ConfoundingWarning)


@contextmanager
def no_stancal_warnings(allow: str | None = None):
    """Asserts that the block raises none of stancal's warnings (a sampler,
    mode, gap or input-range warning is a finding, never noise) but those
    whose message matches ``allow`` (the caller says why it expects them);
    any other warning is passed on to pytest's summary, not hidden."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    ours = [w for w in caught if issubclass(w.category, STANCAL_WARNINGS)]
    for w in caught:  # not stancal's: to pytest's summary (stancal's allowed ones the caller expects)
        if w not in ours:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    ours = [w for w in ours if not (allow and re.search(allow, str(w.message)))]
    assert not ours, [f"{w.category.__name__}: {w.message}" for w in ours]


@pytest.fixture(scope="session")
def koh_fit(exact_cooling_data):
    # 4 x (1000 + 1000): with 2 or 4 chains of 400 + 400, R-hat of theta reached 1.015 and 1.012
    # on a freshly compiled module
    return fit(exact_cooling_data, simulator=COOLING / "simulator.stan", method="koh", prior=True, chains=4,
               warmup=1000, draws=1000)


@pytest.fixture(scope="session")
def koh_emulator_fit(exact_cooling_data):
    return fit(exact_cooling_data, method="koh_emulator", draws=800)  # 400 left R-hat 1.014 on delta_sd


@pytest.fixture(scope="session")
def modular_fit(exact_cooling_data):
    # 2 x 400 draws left R-hat 1.012 on theta (at HEAD and after the split alike); 2 x 800: 1.008
    return fit(exact_cooling_data, method="modular", draws=800)


# more draws for the cheap simulator keep Pareto k estimates steady
# R-hat of 1.01 needs a few thousand draws here: at 2 x (400 + 700) the baseline's R-hat was 1.017,
# at 4 x (400 + 400) the quadratic loss variant's 1.012; at adapt_delta 0.9 the baseline had 3
# divergences of 4,000 and the humidity decoy 24
COOLING_SAMPLING = {"chains": 4, "warmup": 500, "draws": 1000, "adapt-delta": 0.95, "seed": 3}


@pytest.fixture(scope="session")
def cooling_gap(tmp_path_factory):
    """`stancal gap` on the cooling case study, on the default local cluster
    (test_gap reads its ranking; test_cluster reruns it on another cluster)."""
    out = tmp_path_factory.mktemp("gap") / "cooling"
    done = subprocess.run(
        [sys.executable, "-m", "stancal.cli", "gap", str(COOLING / "config.toml"), "--out", str(out),
         *(str(a) for k, v in COOLING_SAMPLING.items() for a in (f"--{k}", v))],
        capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads((out / "gap.json").read_text()), out


@pytest.fixture
def no_compile(monkeypatch):
    """Planning runs as it would; compiling or checking a Stan program, on
    either backend, fails the test (input checked before any compile)."""
    from stancal.stan.backends.cmdstanpy_backend import CmdStanPyBackend
    from stancal.stan.backends.pystan_backend import PyStanBackend

    def reached(self, *args, **kwargs):
        raise AssertionError("the bad input reached a compile")
    for backend in (PyStanBackend, CmdStanPyBackend):
        for name in ("compile", "check"):
            monkeypatch.setattr(backend, name, reached)
