import numpy as np
import pytest

from stancal.problem.design import latin_hypercube_with_corners


def test_design_spans_the_box_and_stratifies_the_rest():
    design = latin_hypercube_with_corners([0.0, 10.0], [1.0, 20.0], runs=24, seed=1)
    assert design.shape == (24, 2)
    for corner in ([0, 10], [0, 20], [1, 10], [1, 20]):
        assert any(np.allclose(row, corner) for row in design)
    inner = design[4:]
    # one run in each of the 20 strata of every dimension
    assert sorted(np.floor(inner[:, 0] * 20).astype(int)) == list(range(20))
    assert sorted(np.floor((inner[:, 1] - 10) / 10 * 20).astype(int)) == list(range(20))


def test_too_few_runs_for_the_corners():
    with pytest.raises(ValueError, match="3 runs cannot hold the 4 corners"):
        latin_hypercube_with_corners([0, 0], [1, 1], runs=3, seed=1)
