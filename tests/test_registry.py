"""The registry is the single source of truth of what can run: a program
registered under a new name, and nothing else, calibrates, predicts, saves,
loads and runs in the gap diagnosis."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from conftest import COOLING, assert_healthy, fit, no_stancal_warnings

import stancal
from stancal.fitting.plan import plan_scalar
from stancal.stan.registry import PROGRAMS, entry_methods, for_method

# 4 x (400 + 400): at 2 x (300 + 300) theta's R-hat was 1.0101
SAMPLING = {"chains": 4, "warmup": 400, "draws": 400, "seed": 5}


@pytest.fixture
def my_koh(tmp_path):
    """A user's copy of koh.stan, registered as method 'my_koh' (the same
    text, so the compiled module is the shipped one's: no compile)."""
    copy = tmp_path / "my_koh.stan"
    copy.write_text(PROGRAMS["koh"].path.read_text())
    row = stancal.register(replace(PROGRAMS["koh"], name="my_koh", stan_file=str(copy)))
    yield row
    del PROGRAMS["my_koh"]


def test_a_registered_copy_calibrates_predicts_saves_loads_and_runs_in_gap(my_koh, exact_cooling_data, tmp_path):
    simulator = COOLING / "simulator.stan"
    mine = fit(exact_cooling_data, simulator=simulator, method="my_koh", **SAMPLING)
    shipped = fit(exact_cooling_data, simulator=simulator, method="koh", **SAMPLING)
    assert_healthy(mine)
    assert_healthy(shipped)
    assert mine.method == "my_koh" and mine.program.origin[0][0] == str(my_koh.path)
    # the same program, data and seed: the copy's draws are the shipped program's, draw for draw
    np.testing.assert_array_equal(np.asarray(mine.idata["posterior"]["theta"]),
                                  np.asarray(shipped.idata["posterior"]["theta"]))
    points = pd.DataFrame({"t": [5.0, 30.0], "T0": [70.0, 80.0]})
    predicted = mine.predict(points)
    pd.testing.assert_frame_equal(predicted, shipped.predict(points))
    # the result carries its row: a process that never registered my_koh (a Dask worker) predicts with it
    pd.to_pickle((mine, points), tmp_path / "mine.pkl")
    script = ("import sys, pandas as pd; result, points = pd.read_pickle(sys.argv[1]); "
              "result.predict(points).to_pickle(sys.argv[2])")
    done = subprocess.run([sys.executable, "-c", script, tmp_path / "mine.pkl", tmp_path / "predicted.pkl"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    pd.testing.assert_frame_equal(pd.read_pickle(tmp_path / "predicted.pkl"), predicted)
    loaded = stancal.load_result(mine.save(tmp_path / "mine.nc"))
    assert loaded.method == "my_koh"
    pd.testing.assert_frame_equal(loaded.predict(points), predicted)
    # the row must reach the gap diagnosis; the candidate's own fit at these small settings may warn
    # (R-hat 1.025 on delta_sd and 2 of 1,600 divergent once koh.stan took the noise models): said, not hidden
    with no_stancal_warnings(allow="candidate 'quadratic'"):
        analysis = stancal.diagnose_gap(exact_cooling_data, [stancal.Candidate("quadratic", formula="I(t**2)")],
                                        simulator=simulator, method="my_koh", scheduler="in-process", **SAMPLING)
    assert analysis.baseline.method == "my_koh"
    assert_healthy(analysis.baseline)
    assert [c.candidate.name for c in analysis.candidates] == ["quadratic"]


def test_methods_and_their_hand_overs_come_from_the_rows(exact_cooling_data):
    assert entry_methods("scalar") == ["koh", "koh_emulator", "modular"]
    assert entry_methods("vector") == ["koh", "modular", "koh_emulator"]
    assert for_method("modular", "vector").name == "modular_vector"
    # the modular program hands counts to its latent version, which has its stage 1 from the row
    counts = stancal.CalibrationData(exact_cooling_data.physical.assign(temperature=lambda d: d.temperature.round()),
                                     ["t", "T0"], "temperature", {"k": (0.01, 0.2)},
                                     runs=exact_cooling_data.runs, likelihood="poisson")
    plan = plan_scalar(counts, None, "modular")
    assert plan.name == "koh_latent_emulator"
    assert [p.origin[0][0].rsplit("/", 1)[-1] for p in plan.stan_programs()] == ["emulator.stan",
                                                                                   "koh_latent_emulator.stan"]
    with pytest.raises(ValueError, match="discrepancy 'orthogonal' needs method 'koh'"):
        plan_scalar(exact_cooling_data, None, "modular", stancal.fitting.plan.model_options("orthogonal"))


def test_commands_take_the_outputs_their_programs_are_registered_for(tmp_path, capsys, monkeypatch):
    """Which output kinds compare and sbc take comes from Program.commands: a
    vector config is refused in one line; registering a vector program for
    compare would lift the refusal (no list elsewhere says otherwise)."""
    from stancal.cli import main
    from stancal.stan.registry import COMPARE, commands_taking

    config = COOLING.parent / "cooling_curves" / "config.toml"
    assert main(["compare", str(config), "--out", str(tmp_path / "out")]) == 2
    message = capsys.readouterr().err.strip().splitlines()[-1]
    assert "`stancal compare` does not take a vector output yet" in message
    assert not (tmp_path / "out").exists()
    monkeypatch.setitem(PROGRAMS, "compare_vector",
                        replace(PROGRAMS["koh_vector"], name="compare_vector", commands=frozenset({COMPARE})))
    assert commands_taking(COMPARE, "vector") == ["compare_vector"]
