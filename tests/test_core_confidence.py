"""The localization confidence: evidence columns, the logistic model and its fit, on synthetic numbers."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.confidence import EVIDENCE, GRID, coverage, evidence, fit_logistic, logistic
from slamfront.core.errors import CoreError


def test_coverage_counts_grid_cells_holding_a_point() -> None:
    assert coverage(np.zeros((0, 2)), 640, 480) == 0.0
    assert coverage(np.array([[1.0, 1.0], [2.0, 3.0]]), 640, 480) == 1 / GRID**2  # one corner cell
    corners = np.array([[0, 0], [639, 0], [0, 479], [639, 479], [639.9, 479.9]], dtype=float)
    assert coverage(corners, 640, 480) == 4 / GRID**2
    every = np.array([[(c + 0.5) * 160, (r + 0.5) * 120] for r in range(4) for c in range(4)])
    assert coverage(every, 640, 480) == 1.0


def test_evidence_columns() -> None:
    x = evidence([40, 0, 10], [50, 0, 10], [0.5, 0.0, 0.25], [10, 0, 30])
    assert x.shape == (3, len(EVIDENCE))
    np.testing.assert_allclose(x[0], [np.log(41), 0.8, 0.5, 0.75])
    np.testing.assert_allclose(x[1], [0.0, 0.0, 0.0, 0.0])  # nothing matched: no evidence, no division by zero
    assert x[2, 3] == 0.0  # a competitor at least as good: not distinctive at all


def test_logistic_is_stable_and_checks_shapes() -> None:
    p = logistic(np.array([[1000.0], [-1000.0], [0.0]]), np.array([1.0]), 0.0)
    np.testing.assert_allclose(p, [1.0, 0.0, 0.5])
    with pytest.raises(CoreError, match=r"\(N, 2\)"):
        logistic(np.zeros((3, 1)), np.ones(2), 0.0)


def test_fit_recovers_a_known_model() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4000, 2))
    truth_w, truth_b = np.array([2.0, -1.0]), 0.5
    labels = rng.random(4000) < logistic(x, truth_w, truth_b)
    weights, bias = fit_logistic(x, labels, l2=0.0)
    np.testing.assert_allclose(weights, truth_w, atol=0.2)
    assert bias == pytest.approx(truth_b, abs=0.15)
    with pytest.raises(CoreError, match="right and wrong"):
        fit_logistic(x, np.ones(4000, bool))
