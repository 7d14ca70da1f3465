"""The Bayes filter against posteriors computed by hand from Wang et al. 2017's eqs. 6-12."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slamfront.core.bayes_filter import BayesFilter, BayesParameters, likelihood
from slamfront.core.errors import CoreError


def test_likelihood_eqs_8_and_9() -> None:
    # sims 0.5, 0.1, 0.1: mu = 0.7/3, sigma = sqrt(((0.5-mu)^2 + 2 (0.1-mu)^2) / 3)
    mu = 0.7 / 3
    sigma = math.sqrt(((0.5 - mu) ** 2 + 2 * (0.1 - mu) ** 2) / 3)
    observed = likelihood(np.array([0.5, 0.1, 0.1]))
    assert observed.mean == pytest.approx(mu) and observed.std == pytest.approx(sigma)
    # only 0.5 >= mu + sigma (= 0.4219): L = (0.5 - sigma) / mu; the others 1
    np.testing.assert_allclose(observed.loop, [(0.5 - sigma) / mu, 1.0, 1.0])
    assert observed.no_loop == pytest.approx(mu / sigma + 1.0)
    assert observed.no_loop == pytest.approx(2.237436867076458)


def test_likelihood_when_sigma_is_zero() -> None:
    for sims in ([0.3], [0.0, 0.0, 0.0], [0.2, 0.2]):
        observed = likelihood(np.array(sims))
        assert observed.loop.tolist() == [1.0] * len(sims) and observed.no_loop == 2.0
    # RTAB-Map's variant: statistics over the non-zero similarities only
    assert likelihood(np.array([0.0, 0.0, 0.4, 0.2]), ignore_zero=True).mean == pytest.approx(0.3)


def test_two_updates_against_hand_computed_posteriors() -> None:
    bayes = BayesFilter()
    # step 1 from certainty of "no loop": prediction p(-1) = 0.9, p(i) = 0.1 / 3
    step = bayes.update(np.array([0, 1, 2]), np.array([0.5, 0.1, 0.1]))
    np.testing.assert_allclose(step.prediction, [0.1 / 3] * 3)
    assert step.prediction_no_loop == pytest.approx(0.9)
    # eta = 1 / (1.3347 * 0.1/3 + 2 * 0.1/3 + 2.2374 * 0.9)
    np.testing.assert_allclose(step.posterior, [0.020938489277026635, 0.01568737434404501, 0.01568737434404501])
    assert step.no_loop == pytest.approx(0.9476867620348833)
    assert step.best == 0 and not step.accepted

    # step 2: place 3 enters WM (no posterior at t-1). Prediction of place i:
    # 0.1/4 * p(-1) + sum_j p(j) * 0.9 f(i - j) / sum_{k=-16..16} f(k), f ~ N(0, 1.6^2)
    step = bayes.update(np.array([0, 1, 2, 3]), np.array([0.05, 0.6, 0.1, 0.05]))
    np.testing.assert_allclose(
        step.prediction, [0.03289833497316482, 0.03397328292386468, 0.03225945848340934, 0.029009790494801856]
    )
    assert step.prediction_no_loop == pytest.approx(0.9 * 0.9476867620348833 + 0.1 * (1 - 0.9476867620348833))
    np.testing.assert_allclose(
        step.posterior, [0.0187439095486834, 0.035631149846600256, 0.01837990805296864, 0.01652840149826318]
    )
    assert step.no_loop == pytest.approx(0.9107166310534845)
    assert step.best == 1 and step.best_probability == pytest.approx(0.035631149846600256)
    assert step.posterior.sum() + step.no_loop == pytest.approx(1.0)


def test_transition_window_sums_to_0_9_and_follows_the_gaussian() -> None:
    window = BayesParameters().window()
    assert len(window) == 33 and window.sum() == pytest.approx(0.9)
    assert window[16 + 1] / window[16] == pytest.approx(math.exp(-1 / (2 * 1.6**2)))
    bayes = BayesFilter()
    bayes.update(np.array([10]), np.array([1.0]))  # one hypothesis: sigma 0, posterior from the prior
    prior, no_loop = bayes.predict(np.array([9, 10, 11, 40]))
    previous = 1.0 - bayes.no_loop
    assert no_loop == pytest.approx(0.9 * bayes.no_loop + 0.1 * previous)
    spread = prior - 0.1 / 4 * bayes.no_loop
    np.testing.assert_allclose(spread[:3], previous * window[15:18])
    assert spread[3] == pytest.approx(0.0)  # 30 places away: beyond the window


def test_a_consistent_revisit_is_accepted_and_a_lost_one_released() -> None:
    bayes = BayesFilter(BayesParameters(loop_threshold=0.11))
    places = np.arange(50)
    accepted_at = None
    no_loop = []
    for t in range(12):
        sims = np.full(50, 0.01)
        sims[20 + t] = 0.6  # the robot drives along places 20, 21, ...: the Gaussian follows it
        step = bayes.update(places, sims)
        no_loop.append(step.no_loop)
        if step.accepted and accepted_at is None:
            accepted_at = t
        assert step.best == 20 + t
    # one image is not enough (p(-1) = 0.89 after the first), a sequence of them is
    assert np.all(np.diff(no_loop) < 0) and no_loop[0] > 0.8
    assert accepted_at == 4 and no_loop[-1] < 0.11
    for _ in range(6):  # new territory: nothing stands out, the belief returns to "no loop"
        step = bayes.update(places, np.full(50, 0.01))
    assert not step.accepted and step.no_loop > 0.8


def test_no_hypotheses_means_no_loop_and_bad_input_is_refused() -> None:
    bayes = BayesFilter()
    step = bayes.update(np.zeros(0, np.int64), np.zeros(0))
    assert step.no_loop == 1.0 and step.best == -1 and not step.accepted and step.best_probability == 0.0
    with pytest.raises(CoreError, match="sorted"):
        bayes.update(np.array([3, 1]), np.array([0.1, 0.2]))
    with pytest.raises(CoreError, match="similarities"):
        bayes.update(np.array([1, 3]), np.array([0.1]))
    with pytest.raises(CoreError, match="probability"):
        BayesParameters(loop_threshold=1.5)
