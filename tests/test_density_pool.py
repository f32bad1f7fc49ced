"""Moment matching's passes over the draws split between worker processes
(stancal.diagnosing.density_pool): the same values as the model's own
functions in this process, computed in the workers."""

from __future__ import annotations

import multiprocessing

import numpy as np
from conftest import ROOT

from stancal.diagnosing.density_pool import DensityPool
from stancal.diagnosing.moment_match import LOG_LIK, LOO_MEAN
from stancal.fitting.plan import make_plan
from stancal.problem.config import load_config
from stancal.stan.backends import get_backend
from stancal.stan.standata import build_stan_data, to_stan_json

SHIELD = ROOT / "case_studies" / "source_shield" / "config.toml"


def test_a_pool_gives_the_models_log_density_and_pointwise_values_from_its_workers():
    problem = load_config(SHIELD)  # 90 counts, a latent GP: the case whose matching was slow
    plan = make_plan(problem.data, problem.simulator)
    program = plan.main_program()
    stan_data = to_stan_json(build_stan_data(problem.data, plan.program.data, plan.options,
                                             problem.data.source.iloc[:0]))
    backend = get_backend("pystan")
    dimension = sum(int(np.prod(shape)) for shape in backend.parameter_shapes(program, stan_data).values())
    points = np.random.default_rng(3).uniform(-1, 1, size=(120, dimension))
    _, log_density = backend.log_density_functions(program, stan_data)
    here = backend.unconstrained_quantities_function(program, stan_data)(points)
    before = {p.pid for p in multiprocessing.active_children()}
    with DensityPool(2) as pool:
        spread_density, spread_quantities = pool.functions("pystan", program, stan_data, (LOG_LIK, LOO_MEAN))
        spread = spread_quantities(points)
        np.testing.assert_allclose(spread_density(points), log_density(points), rtol=1e-12)
        workers = {p.pid for p in multiprocessing.active_children()} - before
    assert len(workers) == 2  # the passes ran in two processes, not here
    for name in (LOG_LIK, LOO_MEAN):
        assert spread[name].shape == (120, len(problem.data.physical))
        np.testing.assert_allclose(spread[name], here[name], rtol=1e-12)
    assert np.isfinite(spread[LOG_LIK]).mean() > 0.9  # the points are mostly inside the support: a real check
    with DensityPool(1) as alone:  # one worker: nothing started, the caller's own functions serve
        assert alone.functions("pystan", program, stan_data, (LOG_LIK,)) is None


def test_a_script_without_a_main_guard_is_not_run_again_and_its_workers_end_with_it(tmp_path):
    """Spawned workers would run the user's script again to find its
    functions (as __mp_main__): a script that calls the gap diagnosis with no
    ``if __name__ == "__main__"`` guard would diagnose again in each worker.
    The pool starts its workers at once, with the script out of sight; and
    when the command is killed, its workers end within seconds."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "no_guard.py"
    script.write_text("import multiprocessing, time\n"
                      "from stancal.diagnosing.density_pool import DensityPool\n"
                      "print('script ran', flush=True)\n"
                      "with DensityPool(2):\n"
                      "    print(*(p.pid for p in multiprocessing.active_children()), flush=True)\n"
                      "    time.sleep(120)\n")
    said = tmp_path / "said.txt"  # a file, not a pipe: a worker left running would hold a pipe open

    def lines(count: int) -> list[str]:
        deadline = time.monotonic() + 120
        while len(said.read_text().splitlines()) < count and time.monotonic() < deadline:
            time.sleep(0.2)
        return said.read_text().splitlines()

    with said.open("w") as out:
        command = subprocess.Popen([sys.executable, str(script)], stdout=out, cwd=tmp_path,
                                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        first, pids = lines(2)[:2]
        workers = [int(pid) for pid in pids.split()]
        assert first == "script ran" and len(workers) == 2
    finally:
        command.send_signal(signal.SIGKILL)  # no clean-up runs: the workers must see it themselves
        command.wait()
    assert said.read_text().count("script ran") == 1  # not again in the 2 workers
    deadline = time.monotonic() + 10
    while any(alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [pid for pid in workers if alive(pid)]
    for pid in left:  # a failing run leaves nothing behind either
        os.kill(pid, signal.SIGKILL)
    assert not left


def alive(pid: int) -> bool:
    """The process runs (a zombie, ended but not yet reaped by init, counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _enter_a_pool(answer) -> None:
    try:
        with DensityPool(2) as pool:
            answer.put(("entered", pool.functions("pystan", None, {}, ())))
    except BaseException as err:  # noqa: BLE001  (the test reports what the daemon met)
        answer.put(("raised", repr(err)))


def test_a_daemonic_process_runs_the_passes_itself():
    """A stock Dask worker is a daemonic process (its nanny's child), which
    may not start processes: there the pool starts nothing and the caller's
    own functions serve, as with one core (review of issue 30)."""
    context = multiprocessing.get_context("fork")
    answer = context.Queue()
    daemon = context.Process(target=_enter_a_pool, args=(answer,), daemon=True)
    daemon.start()
    daemon.join(60)
    assert answer.get(timeout=5) == ("entered", None)
