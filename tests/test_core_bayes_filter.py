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
    # 0.1/4 * p(-1) + sum_j p(j) * 0.9 f(i - j) / sum_{k=-16..16} f(k), f ~ N(0, 1.6^2);
    # what j's window puts outside places 0..3 stays on j (RTAB-Map's transition)
    window = BayesParameters().window()
    previous, previous_no_loop = step.posterior, step.no_loop
    expected = np.full(4, 0.1 / 4 * previous_no_loop)
    for j in range(3):
        for i in range(4):
            expected[i] += previous[j] * window[16 + i - j]
        expected[j] += previous[j] * (0.9 - sum(window[16 + i - j] for i in range(4)))
    step = bayes.update(np.array([0, 1, 2, 3]), np.array([0.05, 0.6, 0.1, 0.05]))
    np.testing.assert_allclose(step.prediction, expected)
    assert step.prediction_no_loop == pytest.approx(0.9 * 0.9476867620348833 + 0.1 * (1 - 0.9476867620348833))
    assert step.prediction.sum() + step.prediction_no_loop == pytest.approx(1.0)
    observed = step.likelihood
    unnormalised = np.r_[observed.loop * expected, observed.no_loop * step.prediction_no_loop]
    np.testing.assert_allclose(step.posterior, unnormalised[:4] / unnormalised.sum())
    assert step.no_loop == pytest.approx(unnormalised[4] / unnormalised.sum())
    assert step.best == 1 and step.best_probability == pytest.approx(step.posterior.max())
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
    # places 9 and 11 get their share; what falls on ids 0..8 and 12..26 (not searched) stays on 10
    np.testing.assert_allclose(spread[:3], previous * (window[15:18] + [0.0, 0.9 - window[15:18].sum(), 0.0]))
    assert spread[3] == pytest.approx(0.0)  # 30 places away: beyond the window
    assert prior.sum() + no_loop == pytest.approx(1.0)


def test_mass_of_places_outside_working_memory_is_renormalised_not_dropped() -> None:
    """Whatever leaves or enters WM between steps, the prediction sums to 1 (RTAB-Map's transition)."""
    rng = np.random.default_rng(5)
    bayes = BayesFilter()
    places = np.arange(60)
    working = places[rng.random(60) < 0.7]
    for _ in range(40):
        similarities = rng.random(len(working)) * 0.2
        similarities[rng.integers(len(working))] = 0.9
        step = bayes.update(working, similarities)
        assert step.prediction.sum() + step.prediction_no_loop == pytest.approx(1.0)
        assert step.posterior.sum() + step.no_loop == pytest.approx(1.0)
        working = places[rng.random(60) < 0.7]  # some places leave WM, others come back
    # a hypothesis that left WM takes its mass away; the remaining belief keeps its proportions
    bayes = BayesFilter()
    bayes.update(np.array([0, 40]), np.array([0.9, 0.1]))
    before = bayes._posterior.copy(), bayes.no_loop
    prior, no_loop = bayes.predict(np.array([40]))
    kept = before[0][1] / (before[0][1] + before[1])
    assert no_loop == pytest.approx(0.9 * (1 - kept) + 0.1 * kept)
    assert prior[0] == pytest.approx(0.1 * (1 - kept) + 0.9 * kept)  # all of its window stays on 40


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
