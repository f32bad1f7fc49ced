"""The command line follows conventions: sampling options checked before
anything, --help with text and defaults, paths relative to the caller's
folder, progress shown, each sampler warning said once, by name, with
advice the reader can act on."""

import contextlib
import io
import os
import re
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import COOLING, no_stancal_warnings

ROOT = Path(__file__).resolve().parent.parent
COMMANDS = ("calibrate", "gap", "compare", "sbc", "compile", "design")
SAMPLING_COMMANDS = ("calibrate", "gap", "compare", "sbc", "design")


def cli(capsys, *args) -> tuple[int, str, str]:
    """stancal in this process (an import of stancal costs seconds in a subprocess)."""
    from stancal.cli import main

    try:
        code = main([str(a) for a in args])
    except SystemExit as stop:  # --help
        code = stop.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# ---- sampling options: one definition, checked before anything ----------------
@pytest.mark.parametrize(("command", "flag", "value", "message"), [
    ("calibrate", "--draws", -5, "--draws must be at least 1; got -5"),
    ("calibrate", "--adapt-delta", 1.2, "--adapt-delta must lie strictly between 0 and 1; got 1.2"),
    ("gap", "--chains", 0, "--chains must be at least 1; got 0"),
    ("compare", "--max-treedepth", 0, "--max-treedepth must be at least 1; got 0"),
    ("sbc", "--warmup", 0, "--warmup must be at least 1; got 0"),
    ("sbc", "--seed", -1, "--seed must be at least 0; got -1"),
])
def test_a_bad_sampling_option_is_one_line_before_anything(capsys, tmp_path, command, flag, value, message):
    out = tmp_path / "out"
    # the config does not even exist: the option is checked before it is read
    code, _, err = cli(capsys, command, tmp_path / "no_config.toml", "--out", out, flag, value)
    assert code == 2, err
    assert err.strip() == f"stancal: error: {message}"
    assert not out.exists()  # nothing written


@pytest.mark.parametrize("command", SAMPLING_COMMANDS)
def test_every_sampling_command_takes_the_sampling_options(capsys, command):
    from stancal.problem.sampling import NAMES

    _, text, _ = cli(capsys, command, "--help")
    for name in NAMES:
        assert f"--{name.replace('_', '-')} " in text, f"{command} lacks --{name}"


def test_python_callers_get_the_same_check_before_any_plan_or_compile(monkeypatch):
    import stancal
    from stancal.diagnosing import gap, sbc
    from stancal.fitting import calibrate as calibrate_module
    from stancal.problem.candidates import Candidate
    from stancal.problem.config import load_config

    def no_plan(*args, **kwargs):
        raise AssertionError("planned or compiled before the sampler's options were checked")

    monkeypatch.setattr(calibrate_module, "plan_scalar", no_plan)
    monkeypatch.setattr(gap, "make_plan", no_plan)
    data = load_config(COOLING / "config.toml").data
    with pytest.raises(ValueError, match=r"^draws must be at least 1; got -5$"):
        stancal.calibrate(data, draws=-5)
    with pytest.raises(ValueError, match=r"^adapt_delta must lie strictly between 0 and 1; got 1$"):
        stancal.calibrate(data, adapt_delta=1)
    with pytest.raises(ValueError, match=r"^chains must be a whole number; got 2.5$"):
        gap.diagnose_gap(data, [Candidate("h", formula="humidity")], chains=2.5)
    with pytest.raises(ValueError, match=r"^max_treedepth must be at least 1; got 0$"):
        stancal.compare_methods(data, max_treedepth=0)
    with pytest.raises(ValueError, match=r"^draws x chains = 10 is fewer than the 100 draws per fit"):
        sbc.simulation_based_calibration(data, draws=5)


# ---- --help: text and a default for every option ------------------------------
def _options(help_text: str) -> dict[str, str]:
    """Each option's entry in a --help page: flags -> the rest of its text."""
    section = help_text.split("options:", 1)[1]
    entries, current = {}, None
    for line in section.splitlines():
        if re.match(r"^  -", line):
            flags, _, rest = line.strip().partition("  ")
            current = flags
            entries[current] = rest.strip()
        elif current and line.startswith(" " * 10):
            entries[current] += " " + line.strip()
    return entries


@pytest.mark.parametrize("command", COMMANDS)
def test_help_gives_every_option_text_and_its_default(capsys, command):
    code, text, err = cli(capsys, command, "--help")
    assert code == 0, err
    options = _options(text)
    assert len(options) > 2
    for flags, text in options.items():
        if flags.startswith("-h, --help"):
            continue
        words = re.sub(r"\((default: .*?|required)\)$", "", text).strip()
        assert words, f"{command} {flags}: no help text"
        assert re.search(r"default: |\(required\)$", text), f"{command} {flags}: no default stated: {text!r}"


# ---- paths are the caller's ----------------------------------------------------
@pytest.fixture
def repository(tmp_path):
    """A copy of the run script in a folder set up as ./run leaves it (a
    venv whose stancal and python are this interpreter's), so that the test
    runs the script without installing anything."""
    repo = tmp_path / "repo"
    (repo / ".venv" / "bin").mkdir(parents=True)
    shutil.copy(ROOT / "run", repo / "run")
    shutil.copy(ROOT / "pyproject.toml", repo / "pyproject.toml")
    (repo / ".venv" / "bin" / "python").symlink_to(sys.executable)
    stancal = repo / ".venv" / "bin" / "stancal"
    stancal.write_text(f"#!/bin/sh\nexec {sys.executable} -m stancal.cli \"$@\"\n")
    stancal.chmod(0o755)
    (repo / ".venv" / ".stancal-installed").touch()
    return repo


def test_run_calibrate_reads_paths_from_the_callers_folder(repository, tmp_path):
    caller = tmp_path / "elsewhere"
    (caller / "study").mkdir(parents=True)
    (caller / "study" / "config.toml").write_text("[physical\n")  # found, and read: its error is its content's
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    started = time.perf_counter()
    done = subprocess.run([str(repository / "run"), "calibrate", "study/config.toml", "--out", "out"],
                          cwd=caller, capture_output=True, text=True, env=env)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith(
        "stancal: error: study/config.toml: not valid TOML"), done.stderr
    assert not (caller / "out").exists() and not (repository / "out").exists()
    assert time.perf_counter() - started < 60  # no compile, no sampling


# ---- sampler warnings: once, by name, naming the fit, advice for the reader ----
def test_a_sampler_warning_is_said_once_by_name_with_advice_for_the_command_line(capsys, caplog, tmp_path):
    # 2 x (20 + 40) draws: far too short, so R-hat and ESS are reported (measured: both, at this seed)
    code, _, err = cli(capsys, "calibrate", COOLING / "config.toml", "--out", tmp_path / "out", "--chains", 2,
                       "--warmup", 20, "--draws", 40, "--seed", 3, "--backend", "pystan")
    assert code == 0, err
    warned = [line.removeprefix("warning: ") for line in err.splitlines() if line.startswith("warning: ")]
    assert any("effective sample size" in w for w in warned), err
    logged = [r.getMessage() for r in caplog.records if r.name == "stancal"]  # in-process, logs go to caplog
    for message in warned:  # once: no log line repeats it
        assert err.count(message) == 1 and message not in logged, f"said more than once: {message}"
    sampler = [w for w in warned if re.match(r"(R-hat|effective sample size|\d+ of \d+ transitions)", w)]
    assert sampler, err
    for message in sampler:
        assert "theta[" not in message and "result." not in message, message
        assert re.search(r"--(warmup|draws|adapt-delta|max-treedepth) \d", message), message


def test_warnings_name_parameters_as_the_config_does():
    import numpy as np
    import xarray as xr

    from stancal.results.diagnostics import component_name

    theta = xr.DataArray(np.zeros(2), dims=["theta_name"], coords={"theta_name": ["k", "omega"]})
    assert component_name(theta.rename("theta"), 1) == "omega"
    per_experiment = xr.DataArray(np.zeros((2, 1)), dims=["experiment", "experiment_theta_name"],
                                  coords={"experiment": ["run 1", "run 2"], "experiment_theta_name": ["k"]})
    assert component_name(per_experiment.rename("theta_experiment"), 1) == "k[run 2]"
    scale = xr.DataArray(np.zeros(2), dims=["delta_input"], coords={"delta_input": ["t", "T0"]})
    assert component_name(scale.rename("delta_length_scale"), 1) == "delta_length_scale[T0]"
    assert component_name(xr.DataArray(0.0, name="noise_sd"), 0) == "noise_sd"


def warn_like_a_fit() -> int:
    """A fit whose sampler diverged 3 times: its checks' warnings, as check_fit says them."""
    import xarray as xr

    from stancal.results import diagnostics

    rng = np.random.default_rng(1)
    posterior = xr.Dataset({"theta": (("chain", "draw", "theta_name"), rng.normal(size=(4, 500, 1)))},
                           coords={"theta_name": ["k"]})
    diverging = np.zeros((4, 500), dtype=bool)
    diverging[0, :3] = True
    stats = xr.Dataset({"diverging": (("chain", "draw"), diverging),
                        "energy": (("chain", "draw"), rng.normal(size=(4, 500))),
                        "tree_depth": (("chain", "draw"), np.full((4, 500), 3))})
    diagnostics.report(diagnostics.check_sampler(posterior, stats, 10, ["theta"]))
    return 1


@pytest.mark.parametrize(("reader", "advice_text"), [("cli", "--adapt-delta 0.95"), ("python", "adapt_delta=0.95")])
def test_a_fit_runners_warnings_name_their_fit_and_suit_the_reader(reader, advice_text):
    from stancal.fitting.cluster import IN_PROCESS, FitRunner, FitTask
    from stancal.problem import advice

    tasks = [FitTask("the baseline", warn_like_a_fit), FitTask("candidate 'humidity'", warn_like_a_fit)]
    with advice.spoken_to(reader), warnings.catch_warnings(record=True) as caught, \
            FitRunner(IN_PROCESS, progress=False) as runner:
        warnings.simplefilter("always")
        runner.map(tasks)
    said = [str(w.message) for w in caught]
    assert [m.split(": ", 1)[0] for m in said] == ["the baseline", "candidate 'humidity'"]
    assert all(m.split(": ", 1)[1].startswith("3 of 2000 transitions diverged") and advice_text in m for m in said)


# ---- progress ------------------------------------------------------------------
class Terminal(io.StringIO):
    """A terminal stand-in that keeps what was drawn on it after stancal closes it."""

    def close(self) -> None:
        pass


# what PyStan writes to sys.stderr while 2 chains of 100 + 100 iterations run (stan/model.py, a
# stream without ANSI support: a newline, then the line), with Stan's messages among the lines
PYSTAN_LINES = ["Sampling:   0%", "\n", "Sampling:   0%", "\n", "Sampling:   0% (1/400)", "\n",
                "Sampling:  26% (102/400)", "\n", "Sampling:  50% (202/400)", "\n",
                "Sampling:  75% (301/400)\n", "Sampling: 100% (400/400)", "\n",
                "Sampling: 100% (400/400), done.", "\n", "Messages received during sampling:\n",
                "  Gradient evaluation took 1e-05 seconds\n"]


def test_pystans_progress_lines_drive_a_bar_on_a_terminal(monkeypatch):
    from stancal.stan import progress

    terminal = Terminal()
    monkeypatch.setattr(progress, "terminal_stream", lambda: terminal)
    held = io.StringIO()
    with contextlib.redirect_stderr(held), progress.sampling_progress("sampling koh.stan", 400) as bar, \
            progress.progress_lines(bar):
        seen = []
        for text in PYSTAN_LINES:
            sys.stderr.write(text)
            seen.append(bar.done)
    assert seen[5] == 1 and seen[7] == 102 and seen[9] == 202 and bar.done == 400
    assert bar.bar.n == 400 and "400/400" in terminal.getvalue().split("\r")[-1]
    # Stan's messages are not progress: they go on to the stream held back
    assert "Sampling" not in held.getvalue() and "Gradient evaluation took" in held.getvalue()


def test_without_a_terminal_progress_is_a_line_per_quarter(monkeypatch, caplog):
    from stancal.stan import progress

    monkeypatch.setattr(progress, "terminal_stream", lambda: None)
    with caplog.at_level("INFO", logger="stancal"), contextlib.redirect_stderr(io.StringIO()), \
            progress.sampling_progress("sampling koh.stan", 400) as bar, progress.progress_lines(bar):
        for text in PYSTAN_LINES:
            sys.stderr.write(text)
    lines = [r.getMessage() for r in caplog.records if "sampling koh.stan" in r.getMessage()]
    assert [line.split(" (")[0] for line in lines] == [f"sampling koh.stan: {p} %" for p in (25, 50, 75)]
    # a fit among many (a fit runner's task) shows none
    caplog.clear()
    with progress.quiet(), progress.sampling_progress("sampling koh.stan", 400) as bar:
        assert bar is None


def test_a_compile_ticks_from_its_own_start_until_it_is_done(monkeypatch, caplog):
    """Each program's time counts from when its build starts: a program
    queued behind others (more programs than cores) shows 'queued', not the
    time it waited, and logs nothing until it starts."""
    from stancal.stan import progress

    terminal = Terminal()
    monkeypatch.setattr(progress, "terminal_stream", lambda: terminal)
    with progress.ticking(["koh.stan (1/2)", "koh_latent.stan (2/2)"]) as ticker:
        ticker.start("koh.stan (1/2)")
        time.sleep(1.5)  # a tick a second
        ticker.done("koh.stan (1/2)")
        ticker.start("koh_latent.stan (2/2)")
        time.sleep(1.2)
        ticker.done("koh_latent.stan (2/2)")
    drawn = terminal.getvalue()
    assert "compiling koh_latent.stan (2/2): queued" in drawn
    assert "compiling koh.stan (1/2): 00:01, done" in drawn and "compiling koh_latent.stan (2/2): 00:01, done" in drawn
    # two finishing out of order: the lines stay in order, each drawn last as done (closing each bar
    # as it finished left a stray copy of a line under the bars on a real terminal)
    terminal = Terminal()
    with progress.ticking(["koh.stan (1/2)", "koh_latent.stan (2/2)"]) as ticker:
        ticker.start("koh.stan (1/2)")
        ticker.start("koh_latent.stan (2/2)")
        time.sleep(0.2)
        ticker.done("koh_latent.stan (2/2)")
        time.sleep(0.2)
        ticker.done("koh.stan (1/2)")
    drawn = terminal.getvalue()
    ends = [drawn.rindex(f"compiling {name}: 00:00, done") for name in ("koh.stan (1/2)", "koh_latent.stan (2/2)")]
    assert ends[0] < ends[1] and drawn.rindex("compiling") == ends[1], drawn
    monkeypatch.setattr(progress, "terminal_stream", lambda: None)
    monkeypatch.setattr(progress, "COMPILE_LOG_EVERY_S", 0.5)
    with caplog.at_level("INFO", logger="stancal"), progress.ticking(["koh.stan (1/2)", "koh_latent.stan (2/2)"]) as ticker:
        ticker.start("koh.stan (1/2)")
        time.sleep(1.2)
        ticker.done("koh.stan (1/2)")
        ticker.start("koh_latent.stan (2/2)")
        time.sleep(1.2)
        ticker.done("koh_latent.stan (2/2)")
    said = [r.getMessage() for r in caplog.records]
    first = next(i for i, m in enumerate(said) if re.fullmatch(r"compiling koh.stan \(1/2\): done in [12] s", m))
    assert any(re.fullmatch(r"compiling koh.stan \(1/2\): \d s so far", m) for m in said[:first]), said
    assert not any("koh_latent" in m for m in said[:first]), said  # queued: no tick yet
    assert re.fullmatch(r"compiling koh_latent.stan \(2/2\): done in [12] s", said[-1]), said  # 1.2 s, or more


def test_a_real_fit_drives_the_bar_to_its_total(monkeypatch, tmp_path):
    import stancal
    from stancal.problem.config import load_config
    from stancal.stan import progress

    bars = []
    terminal = Terminal()

    class Recorded(progress.SamplingProgress):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            bars.append(self)

    monkeypatch.setattr(progress, "terminal_stream", lambda: terminal)
    monkeypatch.setattr(progress, "SamplingProgress", Recorded)
    problem = load_config(COOLING / "config.toml")
    # 2 x (30 + 20) iterations: too short to mix, and said so; the bar is what is tested here
    with no_stancal_warnings(allow="R-hat|effective sample size|diverged|tree depth|E-BFMI|theta modes"):
        stancal.calibrate(problem.data, simulator=problem.simulator, chains=2, warmup=30, draws=20, seed=2,
                          backend="pystan")
    assert len(bars) == 1 and bars[0].total == 2 * (30 + 20)
    assert bars[0].done == bars[0].bar.n == 100, terminal.getvalue()
    assert "100/100" in terminal.getvalue()


def _warns_twice(library_file: str) -> int:
    """A fit that raises one warning of stancal's own and one from another library."""
    from stancal.results.diagnostics import SamplerWarning

    warnings.warn_explicit("a deprecated call inside a dependency", DeprecationWarning, library_file, 7)
    warnings.warn_explicit("R-hat up to 1.2 (k)", SamplerWarning, str(Path(stancal_file())), 1)
    return 3


def stancal_file() -> str:
    import stancal.fitting.calibrate

    return stancal.fitting.calibrate.__file__


def test_a_fits_warnings_name_it_but_another_librarys_pass_as_raised(tmp_path):
    """The runner names the fit in stancal's warnings; a dependency's warning
    (PyStan's marshmallow deprecations, say) is replayed unprefixed, so the
    filters that hide it outside a fit still match it."""
    from stancal.fitting.cluster import IN_PROCESS, FitTask, fit_runner

    with warnings.catch_warnings(record=True) as caught, fit_runner(IN_PROCESS) as runner:
        warnings.simplefilter("always")
        assert runner.map([FitTask("candidate 'x'", _warns_twice, {"library_file": str(tmp_path / "lib.py")})]) == [3]
    said = {(w.category.__name__, str(w.message)) for w in caught}
    assert ("DeprecationWarning", "a deprecated call inside a dependency") in said
    assert ("SamplerWarning", "candidate 'x': R-hat up to 1.2 (k)") in said


def test_main_leaves_the_callers_logging_as_it_was(tmp_path):
    """main() sets stancal's logger to INFO for its run only: a script or test
    that calls it keeps its own level (a later caplog saw a whole earlier run)."""
    import logging

    from stancal.cli import main

    logger = logging.getLogger("stancal")
    before = logger.level
    assert main(["calibrate", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "out")]) == 2
    assert logger.level == before


def test_gap_takes_the_discrepancy_from_the_flag_or_the_config(tmp_path, monkeypatch, capsys):
    """`stancal gap --discrepancy` (issue 29) reaches every fit's plan; without
    it the config's [model] discrepancy does (gap ignored it before); 'none',
    which leaves no gap to measure, is refused in one line."""
    import stancal.diagnosing.gap
    from stancal.cli import main

    seen = []

    def planned(data, candidates, **options):
        seen.append(options["discrepancy"])
        raise ValueError("stopped before sampling")

    monkeypatch.setattr(stancal.diagnosing.gap, "diagnose_gap", planned)
    config = COOLING / "config.toml"
    assert main(["gap", str(config), "--out", str(tmp_path / "a"), "--discrepancy", "orthogonal"]) == 2
    assert main(["gap", str(config), "--out", str(tmp_path / "b")]) == 2
    assert seen == ["orthogonal", "gp"]
    study = tmp_path / "study"
    shutil.copytree(COOLING, study)
    text = (study / "config.toml").read_text().replace('discrepancy = "gp"', 'discrepancy = "none"')
    (study / "config.toml").write_text(text)
    capsys.readouterr()
    assert main(["gap", str(study / "config.toml"), "--out", str(tmp_path / "c")]) == 2
    assert "leaves none to measure" in capsys.readouterr().err
    assert seen == ["orthogonal", "gp"] and not (tmp_path / "c").exists()


def test_gap_takes_every_model_key_of_the_config(tmp_path, monkeypatch):
    """`stancal gap` fits the config's model: its noise model (issue 33: the
    candidates are compared under the same noise), kernel, mean terms and
    the rest of [model] reach diagnose_gap (it passed only the kernel, the
    discrepancy and the approximation before, so a per-source config was
    diagnosed with iid noise)."""
    import stancal.diagnosing.gap
    from stancal.cli import main

    seen = {}

    def planned(data, candidates, **options):
        seen.update(options)
        raise ValueError("stopped before sampling")

    monkeypatch.setattr(stancal.diagnosing.gap, "diagnose_gap", planned)
    study = tmp_path / "two_instruments"
    shutil.copytree(ROOT / "case_studies" / "two_instruments", study)
    shutil.copytree(COOLING, tmp_path / "cooling")  # its simulator
    text = (study / "config.toml").read_text()
    assert 'noise = "per_source"' in text and 'discrepancy = "none"' in text
    text = text.replace('noise = "per_source"', 'noise = "per_source"\nmean_formula = "I(t**2)"')
    (study / "config.toml").write_text(text.replace('discrepancy = "none"', 'discrepancy = "gp"')
                                       + '\n[candidates]\nstart = "T0"\n')
    assert main(["gap", str(study / "config.toml"), "--out", str(tmp_path / "out")]) == 2
    assert seen["noise"] == "per_source" and seen["mean_formula"] == "I(t**2)", seen
    assert seen["biased_sources"] == ["camera"] and seen["discrepancy"] == "gp"


def test_a_gap_in_a_discrepancy_that_cannot_take_the_covariates_stops_before_any_fit(tmp_path, capsys):
    """The orthogonal discrepancy integrates over the simulator inputs' box: with
    the cooling case's covariates, gap refuses it once, before compiling or
    fitting (each fit failed on its own before)."""
    from stancal.cli import main

    assert main(["gap", str(COOLING / "config.toml"), "--out", str(tmp_path / "out"), "--discrepancy",
                 "orthogonal", "--scheduler", "in-process"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot take the covariates ['humidity', 'operator']" in err[0]
    assert not (tmp_path / "out").exists()
