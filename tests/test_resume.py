"""A stopped command resumes (stancal.fitting.resume): a rerun into the same
output folder reuses the fits finished there with the same inputs and runs
only the others; SBC stopped half way and rerun gives the uninterrupted
run's result."""

import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import COOLING, ROOT, no_stancal_warnings

import stancal
from stancal.diagnosing.gap import diagnose_gap
from stancal.fitting.cluster import IN_PROCESS, FitRunner, FitTask
from stancal.fitting.plan import make_plan
from stancal.fitting.resume import RECORD, SEED_RECORD, Resume, canonical, fingerprint, keep_whole
from stancal.problem.candidates import Candidate

CALLS: list[str] = []  # the fake fits that ran, by name


def fake_fit(value: float, seed: int, out_dir: Path) -> float:
    """A stand-in for a fit: writes its 'draws', and finds no record of an
    earlier fit in its folder while it runs (a stale one is removed first)."""
    assert not (Path(out_dir) / RECORD).exists()
    CALLS.append(Path(out_dir).name)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    (Path(out_dir) / "draws.json").write_text(json.dumps(value * seed))
    return value * seed


def restore_fake(task: FitTask, folder: Path, kept) -> float:
    return json.loads((folder / "draws.json").read_text())


def fake_tasks(out: Path, seeds=(1, 2, 3)) -> list[FitTask]:
    return [FitTask(f"fit {i}", fake_fit, {"value": 1.5, "seed": seed, "out_dir": out / f"{i}"})
            for i, seed in enumerate(seeds)]


def run_fakes(out: Path, tasks: list[FitTask]) -> list:
    CALLS.clear()
    with FitRunner(IN_PROCESS, progress=False) as runner:
        return Resume(out, 7).map(runner, tasks, keep=keep_whole, restore=restore_fake)


def test_a_rerun_runs_only_the_fits_not_finished(tmp_path, caplog):
    """A fit is finished only once its record is written, after its files:
    a folder with draws but no record (stopped while writing) runs again."""
    first = run_fakes(tmp_path, fake_tasks(tmp_path))
    assert CALLS == ["0", "1", "2"] and first == [1.5, 3.0, 4.5]
    assert all((tmp_path / f"{i}" / RECORD).is_file() for i in range(3))
    (tmp_path / "1" / RECORD).unlink()  # its draws are there, its record is not
    with caplog.at_level(logging.INFO, logger="stancal"):
        again = run_fakes(tmp_path, fake_tasks(tmp_path))
    assert CALLS == ["1"] and again == first
    assert f"reused 2 of 3 fits finished earlier in {tmp_path}" in caplog.text


def test_a_fit_with_other_inputs_runs_again_and_says_which(tmp_path, caplog):
    run_fakes(tmp_path, fake_tasks(tmp_path))
    with caplog.at_level(logging.INFO, logger="stancal"):
        again = run_fakes(tmp_path, fake_tasks(tmp_path, seeds=(1, 5, 3)))
    assert CALLS == ["1"] and again == [1.5, 7.5, 4.5]
    changed = [r.getMessage() for r in caplog.records if "fitting again" in r.getMessage()]
    assert changed == ["fitting again what changed since it was written: fit 1 (seed)"]
    # the new record is the new fit's: a third run reuses all three
    run_fakes(tmp_path, fake_tasks(tmp_path, seeds=(1, 5, 3)))
    assert CALLS == []


def test_a_record_whose_files_are_gone_runs_again(tmp_path, caplog):
    run_fakes(tmp_path, fake_tasks(tmp_path))
    (tmp_path / "2" / "draws.json").unlink()
    with caplog.at_level(logging.INFO, logger="stancal"):
        again = run_fakes(tmp_path, fake_tasks(tmp_path))
    assert CALLS == ["2"] and again == [1.5, 3.0, 4.5]
    assert "fit 2 (its files cannot be read: [Errno 2] No such file or directory" in caplog.text


def test_a_failed_fit_leaves_no_record(tmp_path):
    tasks = [FitTask("fit 0", fake_fit, {"value": "x", "seed": 1.5, "out_dir": tmp_path / "0"})]
    (failure,) = run_fakes(tmp_path, tasks)
    assert "TypeError" in str(failure) and not (tmp_path / "0" / RECORD).exists()


def test_the_seed_is_kept_for_a_rerun_without_one(tmp_path):
    first = Resume(tmp_path, None)
    with FitRunner(IN_PROCESS, progress=False) as runner:
        first.map(runner, [], restore=restore_fake)
    assert json.loads((tmp_path / SEED_RECORD).read_text()) == {"seed": first.seed}
    assert Resume(tmp_path, None).seed == first.seed and Resume(tmp_path, 11).seed == 11


def test_a_file_counts_by_its_content_not_its_name(tmp_path):
    (tmp_path / "a.stan").write_text("real x;")
    (tmp_path / "b.stan").write_text("real x;")
    assert canonical(tmp_path / "a.stan") == canonical(tmp_path / "b.stan")
    (tmp_path / "b.stan").write_text("real y;")
    assert canonical(tmp_path / "a.stan") != canonical(tmp_path / "b.stan")


FINGERPRINT_SCRIPT = """
import json, sys
import pandas as pd
import pytest
from stancal import CalibrationData
from stancal.fitting.cluster import FitTask
from stancal.fitting.plan import make_plan
from stancal.fitting.resume import fingerprint
root = sys.argv[1]
data = CalibrationData(pd.read_csv(f"{root}/physical.csv"), ["t", "T0"], "temperature", {"k": (0.01, 0.2)},
                       covariates=["humidity", "operator"])
plan = make_plan(data, f"{root}/simulator.stan")
print(json.dumps(fingerprint(FitTask("fit", print, {"data": data, "plan": plan, "seed": 3, "out_dir": root}))))
"""


def test_fingerprints_agree_across_processes():
    """The data (with its categorical levels) and the plan hash the same in
    another process, whose string hashing (set order) differs."""
    data = stancal.CalibrationData(pd.read_csv(COOLING / "physical.csv"), ["t", "T0"], "temperature",
                                   {"k": (0.01, 0.2)}, covariates=["humidity", "operator"])
    plan = make_plan(data, str(COOLING / "simulator.stan"))
    here = fingerprint(FitTask("fit", print, {"data": data, "plan": plan, "seed": 3, "out_dir": "elsewhere"}))
    there = subprocess.run([sys.executable, "-c", FINGERPRINT_SCRIPT, str(COOLING)], capture_output=True, text=True,
                           env={**os.environ, "PYTHONHASHSEED": "12345", "PYTHONPATH": str(ROOT)}, check=True)
    assert json.loads(there.stdout) == here
    other = fingerprint(FitTask("fit", print, {"data": data.with_output(data.physical["temperature"] + 0.1),
                                               "plan": plan, "seed": 3}))
    assert {k for k in here if here[k] != other[k]} == {"data"}


# ---- the commands ----------------------------------------------------------------
SBC = [sys.executable, "-m", "stancal.cli", "sbc", str(COOLING / "config.toml"), "--sims", "4",
       "--draws-per-fit", "20", "--chains", "1", "--warmup", "100", "--seed", "5", "--scheduler", IN_PROCESS]


def _without_timing(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k != "seconds"}


def test_a_stopped_sbc_resumes_to_the_same_result(tmp_path):
    """SBC killed (its process group, as Ctrl-C or a scheduler would) once
    half of its simulations are finished, then rerun: the finished ones are
    reused untouched, and sbc.json is the uninterrupted run's."""
    # health not asserted: 1 chain of 100 + 40 draws per fit checks the resumption, not the sampler
    whole = subprocess.run([*SBC, "--out", str(tmp_path / "whole")], capture_output=True, text=True)
    assert whole.returncode == 0, whole.stderr[-3000:]
    out = tmp_path / "stopped"
    started = subprocess.Popen([*SBC, "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True)
    deadline = time.time() + 300
    while len(list(out.glob(f"fits/*/{RECORD}"))) < 2 and started.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    assert started.poll() is None, "the run ended before it could be stopped half way"
    os.killpg(started.pid, signal.SIGKILL)
    started.wait()
    finished = sorted(out.glob(f"fits/*/{RECORD}"))
    assert 2 <= len(finished) < 4 and not (out / "sbc.json").exists()
    written = {p.parent: (p.parent / "posterior.nc").stat().st_mtime_ns for p in finished}
    rerun = subprocess.run([*SBC, "--out", str(out)], capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert f"reused {len(finished)} of 4 fits finished earlier" in rerun.stderr
    assert {folder: (folder / "posterior.nc").stat().st_mtime_ns for folder in written} == written
    assert _without_timing(json.loads((out / "sbc.json").read_text())) == \
        _without_timing(json.loads((tmp_path / "whole" / "sbc.json").read_text()))


def _flat(tree, path: str = "") -> dict:
    """A nested summary as {path: leaf}."""
    if isinstance(tree, dict):
        return {k: v for key, value in tree.items() for k, v in _flat(value, f"{path}.{key}").items()}
    if isinstance(tree, list):
        return {k: v for i, value in enumerate(tree) for k, v in _flat(value, f"{path}[{i}]").items()}
    return {path: tree}


def assert_same_summary(again: dict, first: dict) -> None:
    """The same summary but for timing; a reused fit is read back from its
    netCDF file, whose arrays are summed in another memory order than the
    sampled ones (relative differences of 1e-15)."""
    again, first = (_flat({k: v for k, v in s.items() if k != "timing"}) for s in (again, first))
    assert again.keys() == first.keys()
    for key, value in first.items():
        if isinstance(value, float):
            assert again[key] == pytest.approx(value, rel=1e-12, abs=1e-12, nan_ok=True), key
        else:
            assert again[key] == value, key


def _sampled(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("sampling ")]


def test_a_gap_rerun_reuses_its_fits_and_refits(tmp_path, caplog):
    """gap rerun into the same folder: no fit or refit samples again, their
    files stay untouched, and the diagnosis is the same."""
    data = stancal.CalibrationData(pd.read_csv(COOLING / "physical.csv"), ["t", "T0"], "temperature",
                                   {"k": (0.01, 0.2)}, covariates=["humidity", "operator"])
    options = {"simulator": COOLING / "simulator.stan", "kfold": 2, "chains": 1, "warmup": 100, "draws": 100,
               "seed": 1, "out_dir": tmp_path, "scheduler": IN_PROCESS}
    candidates = [Candidate("humidity", formula="humidity")]
    # health not asserted: 1 chain of 100 + 100 checks the resumption; trouble is expected and reported
    allow = "diverged|effective sample size|R-hat|maximum tree depth|E-BFMI|Pareto"
    with caplog.at_level(logging.INFO, logger="stancal"), no_stancal_warnings(allow=allow):
        first = diagnose_gap(data, candidates, **options)
    assert len(_sampled(caplog)) == 6  # the baseline and the candidate, each with 2 folds' refits
    files = sorted(tmp_path.glob("**/posterior.nc"))
    written = {p: p.stat().st_mtime_ns for p in files}
    assert len(files) == 6 and len(list(tmp_path.glob(f"**/{RECORD}"))) == 6
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="stancal"), no_stancal_warnings(allow=allow):
        again = diagnose_gap(data, candidates, **options)
    assert _sampled(caplog) == []
    assert "reused 2 of 2 fits" in caplog.text and "reused 4 of 4 fits" in caplog.text
    assert {p: p.stat().st_mtime_ns for p in files} == written
    assert_same_summary(again.to_json(), first.to_json())


def test_a_compare_rerun_reuses_its_fit(tmp_path, caplog):
    # L2's integral over the input box needs a discrepancy over the simulator's inputs only
    data = stancal.CalibrationData(pd.read_csv(COOLING / "physical.csv"), ["t", "T0"], "temperature",
                                   {"k": (0.01, 0.2)})
    options = {"simulator": COOLING / "simulator.stan", "methods": ("koh", "l2"), "chains": 1, "warmup": 100,
               "draws": 100, "seed": 1, "out_dir": tmp_path, "scheduler": IN_PROCESS}
    allow = "diverged|effective sample size|R-hat|maximum tree depth|E-BFMI"  # 1 chain of 100 + 100
    with no_stancal_warnings(allow=allow):
        first = stancal.compare_methods(data, **options)
    caplog.clear()  # the first run's lines, had an earlier test left stancal's logger at INFO
    with caplog.at_level(logging.INFO, logger="stancal"), no_stancal_warnings(allow=allow):
        again = stancal.compare_methods(data, **options)
    assert _sampled(caplog) == [] and "reused 1 of 1 fits" in caplog.text
    # seconds: l2's are koh's fit (kept) plus its projection (timed again)
    pd.testing.assert_frame_equal(again.table().drop(columns="seconds"), first.table().drop(columns="seconds"),
                                  rtol=1e-12)
    assert again.table().loc["koh", "seconds"] == first.table().loc["koh", "seconds"]
