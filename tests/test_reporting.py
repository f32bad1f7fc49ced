"""The figures and pages of a report: bands per series under the data,
theta densities over the posterior's own range, units on the axes, labels
inside the canvas, report.html self-contained, and true stage times. The
figures are drawn from synthetic draws (no Stan), so these take seconds."""

from __future__ import annotations

import base64
import logging
import re
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import COOLING, newton

import stancal
from stancal.problem.config import ConfigError, load_config
from stancal.reporting.gap_report import plot_importance, plot_main_effects
from stancal.reporting.plots import plot_discrepancy, plot_fit, plot_theta, plot_vector_curves, pyplot

UNITS = {"t": "min", "T0": "°C", "temperature": "°C", "k": "1/min", "humidity": "%"}


def cooling_table(series: tuple[float, ...] = (60.0, 75.0, 90.0), per_series: int = 6) -> pd.DataFrame:
    rng = np.random.default_rng(3)
    t = np.tile(np.linspace(5, 60, per_series), len(series))
    T0 = np.repeat(series, per_series)
    return pd.DataFrame({"t": t, "T0": T0, "humidity": rng.uniform(30, 70, t.size),
                         "operator": rng.choice(["ana", "ben"], t.size),
                         "temperature": newton(t, T0, 0.05) + 0.3 * rng.standard_normal(t.size)})


class SyntheticResult:
    """What the figures read from a calibration, made of synthetic draws:
    theta ~ N(0.05, 0.002) on the prior box [0.01, 0.2], and zeta, f and
    delta from Newton's law at any points it is asked to predict at."""

    method = "koh"
    modes: list = []
    options = SimpleNamespace(discrepancy="gp", functional=(), functional_inputs=())

    def __init__(self, physical: pd.DataFrame) -> None:
        self.data = stancal.CalibrationData(physical, ["t", "T0"], "temperature", {"k": (0.01, 0.2)},
                                            covariates=["humidity", "operator"])
        theta = np.random.default_rng(1).normal(0.05, 0.002, (2, 500, 1))
        self.idata = {"posterior": {"theta": theta}}
        self.asked: list[pd.DataFrame] = []

    def predict(self, new_points: pd.DataFrame | None = None, max_draws: int | None = None) -> pd.DataFrame:
        points = self.data.source if new_points is None else new_points
        self.asked.append(points)
        self.max_draws = max_draws
        t, T0 = points["t"].to_numpy(), points["T0"].to_numpy()
        f, zeta = newton(t, T0, 0.055), newton(t, T0, 0.05)
        table = points.reset_index(drop=True).copy()
        for name, mid, half in (("f", f, 0.2), ("zeta", zeta, 0.5), ("delta", zeta - f, 0.5), ("y", zeta, 0.9)):
            table[f"{name}_q05"], table[f"{name}_q50"], table[f"{name}_q95"] = mid - half, mid, mid + half
        return table


@pytest.fixture
def synthetic() -> SyntheticResult:
    return SyntheticResult(cooling_table())


def legend_texts(ax) -> list[str]:
    """The texts of the axes' legend, or of its figure's legend."""
    legend = ax.get_legend() or ax.figure.legends[0]
    return [t.get_text() for t in legend.get_texts()]


def outside_canvas(fig) -> list[str]:
    """The parts of a drawn figure (each axes with its labels and tick
    labels, the figure's titles) that reach beyond the figure's edges."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    parts = [(ax.get_xlabel() or ax.get_title() or "axes", ax.get_tightbbox(renderer)) for ax in fig.axes
             if ax.get_visible()]
    parts += [(t.get_text(), t.get_window_extent(renderer)) for t in fig.texts if t.get_text().strip()]
    return [name for name, e in parts
            if e.x0 < box.x0 - 1 or e.y0 < box.y0 - 1 or e.x1 > box.x1 + 1 or e.y1 > box.y1 + 1]


def test_fit_draws_a_band_per_series_under_the_data(synthetic):
    fig = plot_fit(synthetic, units=UNITS)
    ax = fig.axes[0]
    bands = [c for c in ax.collections if c.__class__.__name__ in ("PolyCollection", "FillBetweenPolyCollection")]
    assert len(bands) == 3  # T0 = 60, 75, 90
    labels = legend_texts(ax)
    for T0 in ("60", "75", "90"):
        assert any(f"T0 = {T0} °C" in label and "90 % band" in label for label in labels), labels
    points = [c for c in ax.collections if c.__class__.__name__ == "PathCollection" and len(c.get_offsets())]
    assert points and min(p.get_zorder() for p in points) > max(b.get_zorder() for b in bands)
    # a curve, not the data points joined: zeta is predicted on a fine grid along t per series
    grid = synthetic.asked[-1]
    assert grid.groupby("T0")["t"].nunique().min() >= 20 > synthetic.data.physical["t"].nunique()
    assert synthetic.max_draws is not None  # thinned: generated quantities cost a Stan call per draw
    pyplot().close(fig)


def test_too_many_series_fall_back_to_intervals_at_the_data_points():
    from stancal.reporting.series import MAX_SERIES, fit_curves

    result = SyntheticResult(cooling_table(series=tuple(50.0 + 5 * i for i in range(MAX_SERIES + 1)), per_series=10))
    curves = fit_curves(result)
    assert not curves.on_grid and len(curves.table) == len(result.data.physical)
    fig = plot_fit(result, curves=curves)
    assert any("90 % interval" in label for label in legend_texts(fig.axes[0]))
    pyplot().close(fig)


def test_theta_density_spans_the_posterior_not_the_prior(synthetic):
    fig = plot_theta(synthetic, units=UNITS)
    ax = fig.axes[0]
    low, high = ax.get_xlim()
    assert 0.01 < low < 0.05 < high < 0.07  # N(0.05, 0.002): well inside the prior's [0.01, 0.2]
    assert ax.get_ylabel().startswith("posterior density")
    dashed = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert dashed and any("prior" in label for label in legend_texts(ax))
    assert any("90 % interval" in label for label in legend_texts(ax))
    pyplot().close(fig)


def test_many_thetas_wrap_into_rows(synthetic, tmp_path):
    """Eleven θ (the Al-5083 case) were eleven panels in one row, each too
    narrow to read at a page's width: four a row now, every one labelled,
    the empty places hidden."""
    names = [f"theta_{i}" for i in range(11)]
    synthetic.data = SimpleNamespace(parameters=[SimpleNamespace(name=n, lower=0.0, upper=1.0) for n in names])
    synthetic.idata = {"posterior": {"theta": np.random.default_rng(2).uniform(0.3, 0.6, (2, 300, 11))}}
    fig = plot_theta(synthetic)
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_xlabel() for ax in shown] == names
    assert {ax.get_subplotspec().colspan.start for ax in shown} == {0, 1, 2, 3}  # 4 columns
    assert {ax.get_subplotspec().rowspan.start for ax in shown} == {0, 1, 2}  # 3 rows
    assert not outside_canvas(fig)
    pyplot().close(fig)
    plot_theta(synthetic, tmp_path / "theta.png")
    assert (tmp_path / "theta.png").stat().st_size > 0


def test_axes_carry_the_units_of_the_config(synthetic):
    from stancal.reporting.series import fit_curves

    curves = fit_curves(synthetic, UNITS)
    for plot in (plot_fit, plot_discrepancy):
        fig = plot(synthetic, units=UNITS, curves=curves)
        assert fig.axes[0].get_xlabel() == "t [min]"
        assert fig.axes[0].get_ylabel().endswith("temperature [°C]")
        pyplot().close(fig)
    fig = plot_theta(synthetic, units=UNITS)
    assert fig.axes[0].get_xlabel() == "k [1/min]"
    assert fig.axes[0].get_ylabel() == "posterior density [min]"  # per 1/min
    pyplot().close(fig)


def test_no_label_leaves_the_canvas(synthetic):
    from stancal.reporting.series import fit_curves

    curves = fit_curves(synthetic, UNITS)
    for fig in [plot_fit(synthetic, units=UNITS, curves=curves), plot_discrepancy(synthetic, units=UNITS, curves=curves),
                plot_theta(synthetic, units=UNITS)]:
        assert outside_canvas(fig) == []
        width, height = fig.get_size_inches() * fig.dpi
        assert width / height < 3  # not a strip (discrepancy.png was 2200 x 385 px)
        pyplot().close(fig)


def test_importance_keeps_its_label_and_states_the_level():
    location = SimpleNamespace(importance={
        name: {"mean": m, "q05": m / 2, "q95": min(1, 1.5 * m)}
        for name, m in (("t", 0.8), ("T0", 0.3), ("humidity", 0.05), ("operator", 0.02))})
    fig = plot_importance(location)
    assert outside_canvas(fig) == []  # the x label was cut off
    assert "90 % interval" in legend_texts(fig.axes[0])
    pyplot().close(fig)


def test_main_effects_name_the_units_in_a_readable_grid():
    band = pd.DataFrame({"value": np.linspace(5, 60, 9), "mean": 0.1, "q05": -0.2, "q95": 0.4})
    levels = pd.DataFrame({"value": ["ana", "ben"], "mean": 0.1, "q05": -0.2, "q95": 0.4})
    effects = {v: SimpleNamespace(variable=v, categorical=v == "operator", band=lambda v=v: levels if v == "operator"
                                  else band, regions=lambda: []) for v in ("t", "T0", "humidity", "operator")}
    fig = plot_main_effects(SimpleNamespace(main_effects=effects), units=UNITS, output="temperature")
    assert [ax.get_xlabel() for ax in fig.axes] == ["t [min]", "T0 [°C]", "humidity [%]", "operator"]
    assert fig.axes[0].get_ylabel().endswith("[°C]")
    assert any("90 % band" in label for label in legend_texts(fig.axes[0]))
    assert outside_canvas(fig) == []
    width, height = fig.get_size_inches()
    assert width / height < 3  # where.png was 1584 x 396 px, four panels in a row
    pyplot().close(fig)


def test_vector_curves_carry_units_and_the_band_level():
    names, along = ["a", "b"], np.linspace(0, 60, 7)
    zeta = np.random.default_rng(0).normal(40, 1, (2, 50, 2, 7))
    physical = pd.DataFrame({"cooldown": np.repeat(names, 7), "t": np.tile(along, 2), "temperature": 40.0})
    data = SimpleNamespace(output_index=["t"], experiments=pd.DataFrame(index=names), physical=physical,
                           experiment="cooldown", output="temperature")
    result = SimpleNamespace(data=data, method="koh_vector",
                             idata={"predictions": {"t": along, "zeta": zeta, "f": zeta - 1}})
    fig = plot_vector_curves(result, units=UNITS)
    assert fig.axes[0].get_xlabel() == "t [min]" and fig.axes[0].get_ylabel() == "temperature [°C]"
    assert any("90 % band" in label for label in legend_texts(fig.axes[0]))
    assert outside_canvas(fig) == []
    pyplot().close(fig)


def test_units_table_is_read_and_checked(tmp_path):
    assert load_config(COOLING / "config.toml").units["t"] == "min"
    base = (COOLING / "config.toml").read_text().split("[units]")[0]
    for name in ("physical.csv", "runs.csv", "simulator.stan"):
        shutil.copy(COOLING / name, tmp_path / name)
    config = tmp_path / "config.toml"
    config.write_text(base + '[units]\ntt = "min"\n')
    with pytest.raises(ConfigError, match=r"\[units\] names 'tt'"):
        load_config(config)
    config.write_text(base + "[units]\nt = 3\n")
    with pytest.raises(ConfigError, match=r"\[units\] t must be a string"):
        load_config(config)
    config.write_text(base)
    assert load_config(config).units == {}


def report_folder(tmp_path: Path, synthetic) -> Path:
    """report.md with two figures beside it, as the report writers leave them."""
    plot_fit(synthetic, tmp_path / "fit.png", UNITS)
    plot_theta(synthetic, tmp_path / "theta.png", UNITS)
    (tmp_path / "report.md").write_text(
        "# Calibration report\n\n| parameter | mean |\n|---|---|\n| k | 0.05 |\n\n"
        "- compiled earlier\n\n## Figures\n\n![theta](theta.png)\n![fit](fit.png)\n")
    return tmp_path / "report.md"


def test_report_html_is_self_contained(tmp_path, synthetic):
    from stancal.reporting.html import write_html

    page = write_html(report_folder(tmp_path, synthetic)).read_text()
    references = re.findall(r'(?:src|href)="([^"]*)"', page)
    assert references and all(r.startswith("data:") for r in references)
    images = re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]+)"', page)
    assert [alt for alt, _ in images] == ["theta", "fit"]  # every figure of the md, in its order
    for alt, encoded in images:
        assert base64.b64decode(encoded) == (tmp_path / f"{alt}.png").read_bytes()
    assert "<table>" in page and "<td>0.05</td>" in page


@pytest.mark.slow
def test_report_html_renders_in_chromium(tmp_path, synthetic):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("headless Chromium is not installed (Debian: apt-get install chromium)")
    from stancal.reporting.html import write_html

    page = write_html(report_folder(tmp_path, synthetic))
    # a copy that, once loaded, writes into its title whether every image decoded
    probe = tmp_path / "probe.html"
    probe.write_text(page.read_text().replace("</body>", (
        "<script>window.addEventListener('load', () => { const images = [...document.images];"
        "document.title = 'images ' + images.filter(i => i.complete && i.naturalWidth > 0).length"
        " + '/' + images.length; });</script></body>")))
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0",
             "--virtual-time-budget=5000"]
    done = subprocess.run([chromium, *flags, "--dump-dom", probe.as_uri()], capture_output=True, text=True,
                          timeout=120)
    assert "<title>images 2/2</title>" in done.stdout, done.stderr[-2000:]
    assert not re.findall(r"CONSOLE.*(?:error|Uncaught)", done.stderr, flags=re.IGNORECASE)
    shot = tmp_path / "shot.png"
    subprocess.run([chromium, *flags, f"--screenshot={shot}", "--window-size=1000,1400", page.as_uri()],
                   capture_output=True, timeout=120, check=True)
    import matplotlib.image

    pixels = matplotlib.image.imread(shot)[..., :3]
    assert pixels.std() > 0.05  # text, a table and figures, not a blank page


def test_stage_times_say_when_the_program_was_compiled_earlier():
    from stancal.reporting.report import stage_times

    assert stage_times({"compile_s": 0.0, "sample_s": 12.3}) == \
        "compiled earlier (the program came from the cache), sampling 12.3 s"
    assert stage_times({"compile_s": 473.2, "sample_s": 12.3}) == "compile 473.2 s, sampling 12.3 s"


def test_compile_reports_the_seconds_it_built_for(monkeypatch, caplog):
    """compile_programs returns the time spent building, and 0.0 when every
    program was built earlier (the report then says 'compiled earlier'); a
    batch it builds says once which compiler builds it."""
    import time

    from stancal.stan.backends import pystan_compile
    from stancal.stan.source import FlatProgram

    program = FlatProgram("parameters { real x; }\nmodel { x ~ std_normal(); }\n", (("x.stan", 1), ("x.stan", 2)))
    monkeypatch.setattr(pystan_compile, "is_compiled", lambda code: True)
    assert pystan_compile.compile_programs([program]) == 0.0
    built: list[str] = []
    monkeypatch.setattr(pystan_compile, "is_compiled", lambda code: False)
    monkeypatch.setattr(pystan_compile, "stored_module", lambda code: Path("/nonexistent/module.so"))
    monkeypatch.setattr(pystan_compile, "prepare_toolchain", lambda: pystan_compile.PYTHONS_COMPILER)
    monkeypatch.setattr(pystan_compile, "_compile_in_subprocess",
                        lambda p, toolchain: (time.sleep(0.2), built.append(p.code)))
    monkeypatch.setattr(pystan_compile, "_install", lambda code, module: None)
    with caplog.at_level(logging.WARNING, logger="stancal"):
        assert pystan_compile.compile_programs([program]) >= 0.2
    assert built == [program.code]
    assert caplog.text.count("Compiling 1 Stan program with PyStan and g++, 1 at a time") == 1


def test_a_failed_compile_stops_the_queue_and_says_so(monkeypatch, caplog):
    """Three programs on two workers, the first failing: its error is raised,
    the program still queued never starts (a real build is minutes), and the
    failed one's line says it failed instead of ticking on."""
    import time

    from stancal.stan import progress
    from stancal.stan.backends import pystan_compile
    from stancal.stan.backends.base import StanRuntimeError
    from stancal.stan.source import FlatProgram

    programs = [FlatProgram(f"parameters {{ real x{i}; }}\n", ((f"p{i}.stan", 1),)) for i in range(3)]
    started: list[str] = []

    def build(program, toolchain):
        started.append(program.code)
        time.sleep(0.2 if program is programs[0] else 0.6)
        if program is programs[0]:
            raise StanRuntimeError("compiling p0.stan with g++ failed: planted")
        return True

    monkeypatch.setattr(pystan_compile, "is_compiled", lambda code: False)
    monkeypatch.setattr(pystan_compile, "stored_module", lambda code: Path("/nonexistent/module.so"))
    monkeypatch.setattr(pystan_compile, "prepare_toolchain", lambda: pystan_compile.PYTHONS_COMPILER)
    monkeypatch.setattr(pystan_compile, "_compile_in_subprocess", build)
    monkeypatch.setattr(pystan_compile.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(progress, "terminal_stream", lambda: None)
    with caplog.at_level(logging.INFO, logger="stancal"), pytest.raises(StanRuntimeError, match="planted"):
        pystan_compile.compile_programs(programs)
    assert started == [programs[0].code, programs[1].code]  # p2.stan, queued, never started
    said = [r.getMessage() for r in caplog.records]
    assert "compiling p0.stan (1/3): failed after 0 s" in said, said


def test_curves_of_a_fit_are_predicted_at_thinned_draws(koh_fit):
    """The figures' curves come from generated quantities on a fine grid,
    at GRID_DRAWS thinned draws: their bands agree with all 4,000 draws'."""
    from stancal.reporting.series import GRID_DRAWS, fit_curves

    curves = fit_curves(koh_fit, UNITS)
    assert curves.on_grid and curves.labels == ["T0 = 60 °C", "T0 = 90 °C"]
    assert curves.table.groupby("series")["t"].nunique().min() >= 25
    points = curves.table[["t", "T0"]].iloc[::20]
    full, thin = koh_fit.predict(points), koh_fit.predict(points, max_draws=GRID_DRAWS)
    width = (full["zeta_q95"] - full["zeta_q05"]).to_numpy()
    # the median of 200 draws is within about 0.1 posterior sd (0.03 band widths) of all draws'
    assert np.all(np.abs(thin["zeta_q50"] - full["zeta_q50"]).to_numpy() < 0.25 * width)
    assert np.all(np.abs(thin["y_q95"] - full["y_q95"]).to_numpy() < 0.5 * width)


def test_curves_run_along_the_input_of_a_functional_theta(synthetic):
    """Reality varies along a functional theta's input (the beam's
    temperature) even when it is a covariate: the curves run along it."""
    from stancal.reporting.series import along_input, series_rows

    assert along_input(synthetic.data) == "t"
    assert along_input(synthetic.data, ("humidity",)) == "humidity"
    assert series_rows(synthetic.data, "humidity") is None  # every (t, T0) its own series: too many


def test_a_calibration_reports_the_compile_its_command_ran(exact_cooling_data, monkeypatch, tmp_path):
    """The compile happens before sampling: its seconds are those that
    compile() spent, not the few spent loading the module for sampling (the
    report said 'compile 0.6 s' after 473 s of compiling)."""
    from conftest import no_stancal_warnings

    from stancal.reporting.report import write_calibration
    from stancal.stan.backends.pystan_backend import PyStanBackend

    compile_once = PyStanBackend.compile
    monkeypatch.setattr(PyStanBackend, "compile", lambda self, programs: compile_once(self, programs) + 473.0)
    # a short fit checks the timing, not the posterior: its health warnings are expected
    with no_stancal_warnings(allow="diverged|effective sample size|R-hat|maximum tree depth|E-BFMI"):
        result = stancal.calibrate(exact_cooling_data, simulator=COOLING / "simulator.stan", method="koh",
                                   chains=2, warmup=100, draws=100, seed=3)
    assert result.timing["compile_s"] == pytest.approx(473.0, abs=0.01)  # the program was in the cache
    assert result.timing["sample_s"] > 0
    write_calibration(result, tmp_path, [])
    assert "compile 473.0 s, sampling" in (tmp_path / "report.md").read_text()


def test_the_comparison_report_names_a_method_whose_loo_is_unreliable():
    """arviz's Pareto k warning is not repeated by psis_score: the compare
    report says it, per method, with the number."""
    from stancal.reporting.compare_report import unreliable_lines

    table = pd.DataFrame({"max_pareto_k": [0.31, 0.92, None]}, index=["koh", "l2", "scaled"])
    lines = unreliable_lines(table)
    assert lines[0].startswith("**l2's ELPD is unreliable**: Pareto k up to 0.92 > 0.7") and lines[1:] == [""]
    assert unreliable_lines(table.iloc[[0]]) == []
