import warnings

import numpy as np
import pandas as pd
import pytest

from stancal import CalibrationData, DataError, InputRangeWarning


def physical(n=5):
    return pd.DataFrame({"x": np.linspace(0, 1, n), "z": np.arange(n, dtype=float),
                         "y": np.linspace(1, 2, n) ** 2})


def runs(n=6):
    return pd.DataFrame({"x": np.linspace(0, 1, n), "k": np.linspace(0.1, 0.9, n),
                         "y": np.linspace(0, 3, n)})


def make(**kw):
    args = {"physical": physical(), "inputs": ["x"], "output": "y", "theta": {"k": (0, 1)}}
    args.update(kw)
    return CalibrationData(**args)


def test_valid_problem_scales_to_unit_cube():
    d = make(covariates=["z"], runs=runs())
    assert d.scaling.to_unit(d.physical, ["x", "z"]).min() == 0
    assert d.scaling.to_unit(d.physical, ["x", "z"]).max() == 1
    assert d.scaling.y_center == pytest.approx(runs()["y"].mean())


def test_missing_column():
    with pytest.raises(DataError, match=r"physical data: missing column\(s\) \['w'\]"):
        make(inputs=["w"])


def test_duplicate_column():
    frame = pd.concat([physical(), physical()[["x"]]], axis=1)
    with pytest.raises(DataError, match=r"duplicate column\(s\) \['x'\]"):
        make(physical=frame)


def test_nan_names_column_and_rows():
    frame = physical()
    frame.loc[[1, 3], "x"] = np.nan
    with pytest.raises(DataError, match=r"column 'x' has NaN or inf in rows \[1, 3\]"):
        make(physical=frame)


def test_empty_output_without_bounds_names_rows():
    frame = physical()
    frame.loc[[1, 3], "y"] = np.nan
    with pytest.raises(DataError, match=r"output column 'y' is empty in rows \[1, 3\].*lower/upper"):
        make(physical=frame)


def test_inf_names_column_and_rows():
    frame = physical()
    frame.loc[2, "x"] = np.inf
    with pytest.raises(DataError, match=r"column 'x' has NaN or inf in rows \[2\]"):
        make(physical=frame)


def test_non_numeric_value():
    frame = physical().astype({"x": object})
    frame.loc[4, "x"] = "warm"
    with pytest.raises(DataError, match=r"column 'x' has non-numeric values in rows \[4\]"):
        make(physical=frame)


def test_theta_in_runs_outside_bounds():
    table = runs()
    table.loc[5, "k"] = 1.5
    with pytest.raises(DataError, match=r"simulator runs: column 'k' lies outside its bounds \[0.0, 1.0\] in rows \[5\]"):
        make(runs=table)


def test_runs_missing_theta_column():
    with pytest.raises(DataError, match=r"simulator runs: missing column\(s\) \['k'\]"):
        make(runs=runs().drop(columns="k"))


def test_fewer_than_three_points():
    with pytest.raises(DataError, match="2 rows; calibration needs at least 3"):
        make(physical=physical(2))


def test_constant_output():
    frame = physical().assign(y=1.0)
    with pytest.raises(DataError, match="output column 'y' is constant"):
        make(physical=frame)


def test_constant_run_output():
    with pytest.raises(DataError, match="simulator runs: output column 'y' is constant"):
        make(runs=runs().assign(y=2.0))


@pytest.mark.parametrize("bounds", [(1, 0), (0, np.inf), ("a", 1)])
def test_bad_theta_bounds(bounds):
    with pytest.raises(DataError, match="theta 'k'"):
        make(theta={"k": bounds})


def test_no_theta():
    with pytest.raises(DataError, match="at least one calibration parameter"):
        make(theta={})


def test_column_named_twice():
    with pytest.raises(DataError, match=r"\['x'\] named more than once"):
        make(covariates=["x"])


def test_theta_name_clashes_with_column():
    with pytest.raises(DataError, match=r"theta name\(s\) \['x'\] clash"):
        make(theta={"x": (0, 1)})


def test_warning_when_physical_inputs_outside_runs():
    table = runs().assign(x=np.linspace(0.2, 0.8, 6))
    with pytest.warns(InputRangeWarning, match=r"physical input 'x' lies outside .* rows \[0, 4\]"):
        make(runs=table)


def test_new_points_are_validated():
    d = make(covariates=["z"])
    with pytest.raises(DataError, match=r"prediction points: missing column\(s\) \['z'\]"):
        d.check_new_points(pd.DataFrame({"x": [0.5]}))


def test_round_trip_through_dict():
    # the physical x (0 to 1) lies inside the runs' range (0 to 1): no InputRangeWarning arises,
    # and one would be a regression
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputRangeWarning)
        d = make(covariates=["z"], runs=runs())
    again = CalibrationData.from_dict(d.to_dict())
    pd.testing.assert_frame_equal(again.physical, d.physical)
    assert again.parameters == d.parameters


# ---- categorical covariates and formula mean terms ---------------------------
def with_batch(labels=("a", "b", "a", "c", "b")):
    return physical().assign(batch=list(labels))


def test_categorical_covariate_enters_the_discrepancy_one_hot():
    d = make(physical=with_batch(), covariates=["z", "batch"])
    assert d.levels == {"batch": ["a", "b", "c"]}
    assert d.discrepancy_variables == {"x": ["x"], "z": ["z"], "batch": ["batch[a]", "batch[b]", "batch[c]"]}
    assert d.physical["batch[b]"].tolist() == [0, 1, 0, 0, 1]
    again = CalibrationData.from_dict(d.to_dict())
    assert again.levels == d.levels and again.discrepancy_inputs == d.discrepancy_inputs


def test_column_mixing_numbers_and_text_is_named():
    with pytest.raises(DataError, match=r"column 'batch' mixes numbers and text; numbers in rows \[1\]"):
        make(physical=with_batch(("a", "2", "a", "c", "b")), covariates=["batch"])


def test_unknown_level_at_new_points_is_named():
    d = make(physical=with_batch(), covariates=["batch"])
    new = pd.DataFrame({"x": [0.5, 0.2], "batch": ["a", "zz"]})
    with pytest.raises(DataError, match=r"prediction points: column 'batch' has levels not in .* rows \[1\]"):
        d.check_new_points(new)
    assert d.check_new_points(new.iloc[:1]).columns.tolist() == ["x", "batch[a]", "batch[b]", "batch[c]"]


def test_subset_keeps_every_level():
    d = make(physical=with_batch(), covariates=["batch"])
    assert d.subset([0, 2, 4]).discrepancy_inputs == d.discrepancy_inputs  # no level c


def test_mean_terms_scaled_and_checked():
    from stancal.problem.mean_terms import FormulaError, build_mean_terms

    frame = with_batch()
    terms = build_mean_terms("I(x**2) + C(batch)", frame)
    assert terms.names == ["I(x ** 2)", "C(batch)[T.b]", "C(batch)[T.c]"]
    np.testing.assert_allclose(np.sqrt(np.mean(terms.h**2, axis=0)), 1)
    np.testing.assert_allclose(terms.h[:, 0] * terms.scale[0], frame.x**2)
    with pytest.raises(FormulaError, match="not seen"):
        terms.at(pd.DataFrame({"x": [0.1], "batch": ["zz"]}))
    with pytest.raises(FormulaError, match="zero at every physical point"):
        build_mean_terms("I(x * 0)", frame)


def test_intercept_only_mean_terms():
    from stancal.problem.mean_terms import build_mean_terms

    terms = build_mean_terms(None, with_batch(), intercept=True)
    assert terms.names == ["Intercept"] and np.all(terms.h == 1)
    assert build_mean_terms("x", with_batch(), intercept=True).names == ["Intercept", "x"]


def test_terms_beside_a_constant_are_centred():
    """A nearly constant term (pressure, 1016 +- 5 hPa) must not be collinear
    with the constant: centred at the physical points' mean, it is orthogonal
    to it, and new points are centred the same way."""
    from stancal.problem.mean_terms import FormulaError, build_mean_terms

    frame = with_batch().assign(pressure=lambda f: 1016 + 5 * np.sin(np.arange(len(f))))
    terms = build_mean_terms("pressure", frame, intercept=True)
    np.testing.assert_allclose(terms.h[:, 0], 1)
    np.testing.assert_allclose(terms.h[:, 1].mean(), 0, atol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.mean(terms.h[:, 1] ** 2)), 1)
    new = pd.DataFrame({"pressure": [frame.pressure.mean(), frame.pressure.mean() + terms.scale[1]]})
    np.testing.assert_allclose(terms.at(new), [[1, 0], [1, 1]], atol=1e-9)
    with pytest.raises(FormulaError, match="constant at every physical point"):
        build_mean_terms("I(x * 0 + 3)", frame, intercept=True)
