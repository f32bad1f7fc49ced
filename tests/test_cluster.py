"""Many fits on Dask (stancal.fitting.cluster): retries and named failures, the
same results whatever runs the fits, one build per program per machine,
a real cluster started as people start one (a scheduler and two stock
`dask worker`s on 127.0.0.1) that loses a worker in the middle of a gap
diagnosis, and a killed command that leaves nothing running."""

from __future__ import annotations

import itertools
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import psutil
import pytest
from conftest import COOLING, ROOT

from stancal.fitting.cluster import IN_PROCESS, FitFailure, FitRunner, FitTask
from stancal.fitting.seeds import MAX_SEED, fit_seed

VENV_BIN = Path(sys.executable).parent


def flaky(counter: str, fail_times: int) -> int:
    """Fails the first ``fail_times`` calls (counted in a file, so across processes), then returns the count."""
    path = Path(counter)
    calls = int(path.read_text()) + 1 if path.exists() else 1
    path.write_text(str(calls))
    if calls <= fail_times:
        raise ValueError(f"row {calls} is bad")
    warnings.warn(f"fitted after {calls} calls", UserWarning, stacklevel=2)
    return calls


def test_fit_seeds_depend_on_the_command_seed_and_the_fit_only():
    names = ["baseline", "candidate 'wind'", "simulation 0", "simulation 1"]
    seeds = [fit_seed(3, name) for name in names]
    assert seeds == [fit_seed(3, name) for name in names]
    assert len(set(seeds)) == len(names) and all(0 <= s < MAX_SEED for s in seeds)
    assert fit_seed(4, "baseline") != seeds[0]


@pytest.mark.parametrize("scheduler", [IN_PROCESS, None], ids=["in-process", "local-cluster"])
def test_a_failed_fit_is_retried_once_then_named(scheduler, tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(Path(__file__).parent))  # the workers import flaky from here
    tasks = [FitTask("fit a", flaky, {"counter": str(tmp_path / "a"), "fail_times": 1}),
             FitTask("fit b", flaky, {"counter": str(tmp_path / "b"), "fail_times": 5}),
             FitTask("fit c", flaky, {"counter": str(tmp_path / "c"), "fail_times": 0})]
    with FitRunner(scheduler, workers=2) as runner, pytest.warns(UserWarning, match="fitted after") as caught:
        outcomes = runner.map(tasks)
    assert outcomes[0] == 2 and outcomes[2] == 1  # a: failed once, then ran again
    assert outcomes[1] == FitFailure("fit b", "ValueError: row 2 is bad")  # b: tried twice, then named
    assert (tmp_path / "b").read_text() == "2"
    # the workers' warnings are said where the command runs, each naming its fit
    assert sorted(str(w.message) for w in caught) == ["fit a: fitted after 2 calls", "fit c: fitted after 1 calls"]
    assert runner.progress.done == runner.progress.total == 3


def _start(command: list[str], log: Path) -> subprocess.Popen:
    # no special setting: `dask worker` starts a nanny and a daemonic worker process, as dask-jobqueue does
    return subprocess.Popen(command, stdout=log.open("w"), stderr=subprocess.STDOUT,
                            start_new_session=True)  # its own process group: killed with its worker process


@pytest.fixture
def cluster(tmp_path):
    """A scheduler and two stock workers (a nanny each, as many threads as
    cores) on 127.0.0.1; stopped after the test."""
    address_file = tmp_path / "scheduler.json"
    scheduler = _start([str(VENV_BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
                        "--dashboard-address", ":0", "--scheduler-file", str(address_file)], tmp_path / "scheduler.log")
    processes = [scheduler]
    try:
        for _ in range(100):
            if address_file.exists() and address_file.read_text().strip():
                break
            time.sleep(0.2)
        address = json.loads(address_file.read_text())["address"]
        workers = [_start([str(VENV_BIN / "dask"), "worker", address, "--host", "127.0.0.1", "--no-dashboard"],
                          tmp_path / f"worker{i}.log") for i in range(2)]
        processes += workers
        yield address, workers
    finally:
        for process in reversed(processes):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)
        for process in processes:
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)


# cluster and local runs must agree, not be good fits: half the cooling data, one candidate,
# short chains (its Pareto k leaves a few exact refits, more fits to share out)
SMALL_SAMPLING = {"chains": 2, "warmup": 150, "draws": 300, "seed": 3}


def _small_gap_problem(folder: Path) -> Path:
    """The cooling case study's every other row, with its humidity candidate."""
    folder.mkdir()
    rows = (COOLING / "physical.csv").read_text().splitlines()
    (folder / "physical.csv").write_text("\n".join([rows[0], *rows[1::2]]) + "\n")
    (folder / "config.toml").write_text(f"""
[physical]
csv = "physical.csv"
inputs = ["t", "T0"]
output = "temperature"
covariates = ["humidity", "operator"]
[simulator]
stan = "{COOLING / 'simulator.stan'}"
[simulator.theta]
k = [0.01, 0.2]
[model]
discrepancy = "gp"
kernel = "se"
[candidates]
humidity = "humidity"
""")
    return folder / "config.toml"


def _gap_command(config: Path, out: Path, scheduler: str | None, sampling: dict) -> list[str]:
    """`stancal gap`, on the default local cluster if ``scheduler`` is None."""
    return [sys.executable, "-m", "stancal.cli", "gap", str(config), "--out", str(out),
            *(["--scheduler", scheduler] if scheduler else []),
            *(str(a) for k, v in sampling.items() for a in (f"--{k}", v))]


def _assert_same(there, here, where: str = "gap.json") -> None:
    """Equal, numbers to 1e-9 (the same draws; BLAS may sum in another order in a worker)."""
    if isinstance(here, dict):
        assert sorted(there) == sorted(here), where
        for key in here:
            _assert_same(there[key], here[key], f"{where}/{key}")
    elif isinstance(here, list):
        assert len(there) == len(here), where
        for i, (a, b) in enumerate(zip(there, here, strict=True)):
            _assert_same(a, b, f"{where}/{i}")
    elif isinstance(here, float):
        assert there == pytest.approx(here, rel=1e-9, abs=1e-12, nan_ok=True), where
    else:
        assert there == here, where


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_gap_on_stock_workers_that_lose_one_matches_the_local_run(cluster, tmp_path):
    """A gap diagnosis on a cluster of stock `dask worker`s (daemonic, with a
    nanny, several threads), whose first worker is killed once the first fit
    is done, completes with the same gap.json as the run in this process."""
    address, workers = cluster
    config = _small_gap_problem(tmp_path / "problem")
    here = subprocess.run(_gap_command(config, tmp_path / "here", "in-process", SMALL_SAMPLING),
                          capture_output=True, text=True, cwd=ROOT)
    assert here.returncode == 0, here.stderr[-3000:]
    log = tmp_path / "gap.log"
    run = subprocess.Popen(_gap_command(config, tmp_path / "there", address, SMALL_SAMPLING),
                           stdout=subprocess.PIPE, stderr=log.open("w"), text=True, cwd=ROOT)
    deadline = time.time() + 600
    while "fits 1/" not in log.read_text() and run.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    assert run.poll() is None, log.read_text()[-3000:]  # still running: a fit is done, others are not
    os.killpg(workers[0].pid, signal.SIGKILL)
    run.communicate(timeout=900)
    assert run.returncode == 0, log.read_text()[-3000:]
    on_cluster, local = ({key: value for key, value in json.loads((tmp_path / folder / "gap.json").read_text()).items()
                          if key != "timing"} for folder in ("there", "here"))
    assert on_cluster["failed"] == [] and len(local["candidates"]) == 1
    _assert_same(on_cluster, local)


def _workers_sampling(command: psutil.Process) -> bool:
    """Some worker of the command's local cluster has chain processes (forked: the worker's command line)."""
    try:
        return any(chain.cmdline() == worker.cmdline() for worker in command.children() for chain in worker.children())
    except psutil.NoSuchProcess:
        return False


def _alive(process: psutil.Process) -> bool:
    try:
        return process.status() != psutil.STATUS_ZOMBIE  # a zombie has ended; its new parent may not reap it
    except psutil.NoSuchProcess:
        return False


def _files(folder: Path) -> dict[str, int]:
    return {str(p): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("stop", [signal.SIGKILL, pytest.param(signal.SIGTERM, marks=pytest.mark.slow),
                                  pytest.param(signal.SIGINT, marks=pytest.mark.slow)], ids=lambda s: s.name)
def test_a_killed_command_leaves_nothing_running(stop, tmp_path):
    """Stop a gap diagnosis while its local cluster samples: its scheduler,
    workers and chain processes end within seconds and write nothing more
    (SIGKILL: the command itself cleans nothing up)."""
    config = _small_gap_problem(tmp_path / "problem")
    out, temporary = tmp_path / "out", tmp_path / "tmp"
    temporary.mkdir()
    run = subprocess.Popen(_gap_command(config, out, None, {**SMALL_SAMPLING, "draws": 100_000}),
                           stdout=subprocess.DEVNULL, stderr=(tmp_path / "gap.log").open("w"), cwd=ROOT,
                           env={**os.environ, "TMPDIR": str(temporary)})
    command = psutil.Process(run.pid)
    deadline = time.time() + 300
    while not _workers_sampling(command) and run.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    assert run.poll() is None and _workers_sampling(command), (tmp_path / "gap.log").read_text()[-3000:]
    started = command.children(recursive=True)
    run.send_signal(stop)
    run.wait(timeout=60)
    deadline = time.time() + 15
    while any(_alive(p) for p in started) and time.time() < deadline:
        time.sleep(0.2)
    survivors = [" ".join(p.cmdline())[:120] for p in started if _alive(p)]
    for process in started:  # not to leave them to the next test if this one fails
        if _alive(process):
            process.kill()
    assert not survivors, survivors
    written = _files(out) if out.exists() else {}
    time.sleep(2)
    assert (_files(out) if out.exists() else {}) == written
    assert list(temporary.glob("stancal-*")) == []  # the cluster's scratch folder (the workers' httpstan caches)


def _write_forever(folder: Path, pid_file: Path) -> None:
    """A chain's process as httpstan runs one: it writes into its worker's
    cache (under the scratch folder) until it notices its worker's end."""
    from stancal.stan.backends.base import end_when_orphaned

    end_when_orphaned(os.getppid())
    pid_file.write_text(str(os.getpid()))
    for n in itertools.count():
        try:
            (folder / f"draws-{n}").write_text("x")
        except FileNotFoundError:  # its folder removed: a real chain fails here too, and is ended
            time.sleep(0.001)


def _worker_removing_scratch(scratch: Path, pid_file: Path) -> None:
    """A cluster's worker whose command is gone, with a chain still writing."""
    from stancal.fitting.cluster import remove_scratch

    chain = multiprocessing.get_context("fork").Process(target=_write_forever, args=(scratch / "httpstan", pid_file))
    chain.start()
    while len(list((scratch / "httpstan").iterdir())) < 100:
        time.sleep(0.01)
    remove_scratch(scratch)
    os._exit(0)


def test_the_scratch_folder_is_removed_though_chains_still_write_into_it(tmp_path):
    """A SIGKILLed gap diagnosis once left its cluster's scratch folder
    behind: each worker removed it as soon as the command was gone, while
    the worker's chain processes, which end only when they notice their
    worker's end, still wrote their httpstan cache into it. A worker's
    clean-up ends its own chains first."""
    scratch, pid_file = tmp_path / "stancal-cluster-x", tmp_path / "chain.pid"
    (scratch / "httpstan").mkdir(parents=True)
    worker = multiprocessing.get_context("fork").Process(target=_worker_removing_scratch, args=(scratch, pid_file))
    worker.start()
    worker.join(20)  # the chain holds the worker's end of the pipe join waits on: it returns when both end
    chain = int(pid_file.read_text())
    deadline = time.time() + 5
    while psutil.pid_exists(chain) and _alive(psutil.Process(chain)) and time.time() < deadline:
        time.sleep(0.1)
    alive = psutil.pid_exists(chain) and _alive(psutil.Process(chain))
    if alive:  # not to leave it writing if this test fails
        psutil.Process(chain).kill()
    assert worker.exitcode == 0 and not alive
    assert not scratch.exists(), sorted(p.name for p in scratch.rglob("*"))[:5]


def test_a_scheduler_slow_to_start_is_stopped_and_named():
    """On a loaded machine the local scheduler took 54 s to write its address
    (load average 20). distributed's own start gives it 30 s, then reads the
    scheduler's stderr to its end, which never comes while the scheduler
    lives: the command hung for an hour. stancal's start kills it and says so
    (a deadline of a millisecond stands in for the slow start)."""
    import asyncio

    from stancal.fitting.local_cluster import PatientScheduler

    scheduler = PatientScheduler(timeout=0.001)

    async def start() -> None:
        await asyncio.wait_for(scheduler.start(), 60)  # the bug: asyncio.TimeoutError after a minute

    with pytest.raises(RuntimeError, match=r"Dask scheduler did not start within 0 s"):
        asyncio.run(start())
    assert scheduler.process is None or scheduler.process.returncode is not None
