"""Seconds per gradient of koh_emulator.stan with runs of two fidelities
(every level's GP sampled with theta, docs/multifidelity.md's joint path)
against the same program with one fidelity and as many runs, by the total
number of runs: what sets koh_emulator's limit on runs of all fidelities
(stancal.stan.registry.JOINT_FIDELITY_RUN_LIMIT).

The problem is tests/test_multifidelity.py's two-level cooling one (12
readings; the cheap runs Newton's law, the expensive ones with a radiative
loss), with 15 expensive runs and the rest cheap; one fidelity: that many
expensive runs. The compiled module is loaded from the store
(benchmarks/gradient_speed.py) and ``log_prob_grad`` timed at one point,
the median of ``--repeats`` passes of ``--calls`` calls.

    STANCAL_CACHE=/work/clangstore nice -n 10 .venv/bin/python benchmarks/joint_fidelity_cost.py \
        [--runs 50 100 200 300 400] [--calls 10] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
from gradient_speed import plain, services, stored_module_file  # noqa: E402
from test_multifidelity import problem, radiating, runs_of  # noqa: E402

EXPENSIVE = 15


def point(data: dict) -> dict:
    """One parameter point of koh_emulator.stan: every level's GP near stage 1's values on this problem."""
    low = data["L"] - 1
    return {"theta_unit": [0.45], "noise_sd": [0.05], "delta_sd": [0.2], "delta_input_length_scale": [0.5],
            "emulator_mean": 0.0, "emulator_sd": 0.3, "emulator_length_scale": [0.6, 0.8], "emulator_nugget": 0.01,
            "level_rho": [0.9] * low, "low_emulator_mean": [0.0] * low, "low_emulator_sd": [1.0] * low,
            "low_emulator_length_scale": [[0.6, 0.8]] * low, "low_emulator_nugget": [0.01] * low,
            "nu": [], "noise_weight": [], "noise_gp_sd": [], "noise_length_scale": [], "noise_z": [],
            "rho_free": [], "beta": [], "delta_relevance": [], "bias_sd": [], "bias_length_scale": []}


def stan_data(runs: int, fidelities: int):
    import stancal
    from stancal.problem.options import ModelOptions
    from stancal.stan.registry import PROGRAMS
    from stancal.stan.source import flatten
    from stancal.stan.standata import build_stan_data, to_stan_json

    data = problem(low=runs - EXPENSIVE, high=EXPENSIVE)
    if fidelities == 1:
        data = stancal.CalibrationData(data.source, ["t"], "excess", {"k": (0.5, 2.0)},
                                       runs=runs_of(radiating, runs, 2))
    row = PROGRAMS["koh_emulator"]  # the registry's row, past the plan's limit on runs: what the limit is for
    return flatten(row.path), plain(to_stan_json(build_stan_data(data, row.data, ModelOptions(),
                                                                 data.physical.iloc[:2])))


def seconds_per_gradient(runs: int, fidelities: int, calls: int, repeats: int) -> float:
    program, data = stan_data(runs, fidelities)
    module = services(stored_module_file(Path(os.environ["STANCAL_CACHE"]), program.code))
    unconstrained = module.transform_inits(data, point(data))
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        for _ in range(calls):
            module.log_prob_grad(data, unconstrained, True)
        times.append((time.perf_counter() - started) / calls)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, nargs="+", default=[50, 100, 200, 300, 400])
    parser.add_argument("--calls", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print("runs  one fidelity (ms/gradient)  two fidelities (ms/gradient)  ratio")
    for runs in args.runs:
        one, two = (seconds_per_gradient(runs, f, args.calls, args.repeats) * 1e3 for f in (1, 2))
        print(f"{runs:4d}  {one:26.2f}  {two:28.2f}  {two / one:5.2f}")


if __name__ == "__main__":
    main()
