"""The design loop on the pin fin: waves of history matching, each running
the simulator at the 20 runs it proposes, until NROY stops shrinking (a
wave that keeps more than 90 % of the last one's). Writes the last wave's
design folder (out/) and the docs' figures (docs/img/design_loop_*.png),
and prints the NROY fraction by wave.

    python case_studies/design_loop/run_waves.py
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from simulator import fin_temperature  # noqa: E402

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.reporting.design_report import write_design  # noqa: E402

WAVES, RUNS_PER_WAVE, STOP_SHRINK = 8, 20, 0.9


def main(out: Path = HERE / "out", images: Path | None = HERE.parent.parent / "docs" / "img") -> dict:
    problem = load_config(HERE / "config.toml")
    loop = stancal.run_waves(problem, simulator=fin_temperature, waves=WAVES, runs_per_wave=RUNS_PER_WAVE, seed=1,
                             stop_shrink=STOP_SHRINK)
    summary = write_design(loop.designs[-1], out, problem.units)
    loop.data.runs.to_csv(out / "all_runs.csv", index=False)  # the initial 40 and every wave's
    if images is not None:
        for name in ("nroy_pairs", "nroy_by_wave", "proposed_runs"):
            shutil.copy(out / f"{name}.png", images / f"design_loop_{name}.png")
    fractions = {w["number"]: w["nroy_fraction"] for w in summary["waves"]}
    print(json.dumps({"nroy_fraction_by_wave": fractions, "runs": summary["runs"]}, indent=1))
    return summary


if __name__ == "__main__":
    main()
