"""The discrete Bayes filter over loop-closure hypotheses of Wang et al. 2017 (§1.3, after RTAB-Map).

The state S_t is -1 ("no loop at time t") or the id i of a place in working memory
("image t closes a loop with place i"). Each step (Wang et al. 2017, eqs. 6-12):

- **prediction** (eqs. 10-11) from the previous posterior:
  ``p(-1 | -1) = 0.9``, ``p(-1 | j) = 0.1``, ``p(i | -1) = 0.1 / M`` (M = number of
  hypotheses), ``p(i | j) = 0.9 f(i - j) / sum_{k=-16..16} f(k)`` with f a Gaussian of
  sigma 1.6 (eq. 12), zero beyond 16 places. Wang et al. 2017's eq. 11 is garbled in the
  published text ("0.9 f(i) / (j + 16)" over a sum "from j to t"); this reading, a
  Gaussian window of j +- 16 normalised to 0.9, is the one consistent with RTAB-Map
  and with the ``j + 16`` that survives. A hypothesis new in working memory had no
  posterior at t-1 (Wang et al. 2017 sets it to 0).
- **working memory changes** (RTAB-Map's ``BayesFilter``): the previous posterior of
  places that left working memory is dropped and the rest, with p(-1), renormalised
  to 1 (RTAB-Map drops it and normalises at the end: the same posterior); the part of
  j's Gaussian window that falls on ids not in working memory (places in STM or LTM,
  ids before the first place) goes to j itself, so each column of the transition
  still gives 0.9 to loops. The prediction always sums to 1.
- **likelihood** (eqs. 8-9) from the similarities ``sim_i`` of the image to each place,
  with mean mu and standard deviation sigma over the places:
  ``L(i) = (sim_i - sigma) / mu`` if ``sim_i >= mu + sigma`` else 1;
  ``L(-1) = mu / sigma + 1``.
- **update** (eqs. 6-7): ``posterior = eta * L * prediction``.
- **decision**: a loop is accepted when ``p(S_t = -1) < T_loop``, with the most probable
  place.

Edge cases Wang et al. 2017 leaves open, settled as RTAB-Map does (``Rtabmap::adjustLikelihood``):
when sigma is 0 (all similarities equal, e.g. one hypothesis or all zero) every
``L(i) = 1`` and ``L(-1) = 2``; ``ignore_zero_similarities`` computes mu and sigma over
the non-zero similarities only (RTAB-Map's default; Wang et al. 2017 uses all of them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamfront.core.errors import CoreError


@dataclass(frozen=True)
class BayesParameters:
    """The filter's constants (defaults: Wang et al. 2017's values)."""

    stay_no_loop: float = 0.9
    """p(S_t = -1 | S_{t-1} = -1)."""
    loop_to_no_loop: float = 0.1
    """p(S_t = -1 | S_{t-1} = j)."""
    no_loop_to_loop: float = 0.1
    """Total p(S_t = i | S_{t-1} = -1), spread evenly over the M hypotheses."""
    sigma: float = 1.6
    """Gaussian of the loop-to-loop transition, in places."""
    reach: int = 16
    """The Gaussian window is j - reach .. j + reach."""
    loop_threshold: float = 0.11
    """T_loop: accept a loop when p(S_t = -1) is below this."""
    ignore_zero_similarities: bool = False

    def __post_init__(self) -> None:
        for name in ("stay_no_loop", "loop_to_no_loop", "no_loop_to_loop", "loop_threshold"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise CoreError(f"{name} must be a probability, got {value}")
        if self.sigma <= 0 or self.reach < 0:
            raise CoreError("sigma must be > 0 and reach >= 0")

    def window(self) -> np.ndarray:
        """(2 reach + 1,) the loop-to-loop transition p(j + d | j) for d = -reach..reach (sums to 0.9)."""
        offsets = np.arange(-self.reach, self.reach + 1, dtype=np.float64)
        f = np.exp(-(offsets**2) / (2.0 * self.sigma**2)) / (np.sqrt(2.0 * np.pi) * self.sigma)
        return (1.0 - self.loop_to_no_loop) * f / f.sum()


@dataclass(frozen=True)
class Likelihood:
    """Observation model of one image: ``loop`` (M,) aligned with the hypotheses, ``no_loop``."""

    loop: np.ndarray
    no_loop: float
    mean: float
    std: float


def likelihood(similarities: np.ndarray, ignore_zero: bool = False) -> Likelihood:
    """Wang et al. 2017 eqs. 8-9 for the similarities (M,) of the current image to each hypothesis."""
    sims = np.asarray(similarities, dtype=np.float64)
    values = sims[sims > 0] if ignore_zero else sims
    if len(values) == 0:
        return Likelihood(np.ones(len(sims)), 2.0, 0.0, 0.0)
    mean, std = float(values.mean()), float(values.std())
    if std <= 1e-12 or mean <= 0:
        return Likelihood(np.ones(len(sims)), 2.0, mean, std)
    loop = np.where(sims >= mean + std, (sims - std) / mean, 1.0)
    return Likelihood(loop, mean / std + 1.0, mean, std)


@dataclass(frozen=True)
class BayesStep:
    """One filter update.

    :ivar hypotheses: (M,) int64 place ids, sorted.
    :ivar posterior: (M,) p(S_t = i) for each hypothesis.
    :ivar no_loop: p(S_t = -1).
    :ivar prediction: (M,) prior p(S_t = i | I^{t-1}); ``prediction_no_loop`` for -1.
    """

    hypotheses: np.ndarray
    posterior: np.ndarray
    no_loop: float
    prediction: np.ndarray
    prediction_no_loop: float
    likelihood: Likelihood
    accepted: bool

    @property
    def best(self) -> int:
        """The most probable place, -1 when there is no hypothesis."""
        return int(self.hypotheses[int(np.argmax(self.posterior))]) if len(self.hypotheses) else -1

    @property
    def best_probability(self) -> float:
        """The largest loop posterior (Wang et al. 2017's fig. 7), 0 when there is no hypothesis."""
        return float(self.posterior.max()) if len(self.posterior) else 0.0


class BayesFilter:
    """The recursive filter; hypotheses may change between steps (memory management)."""

    def __init__(self, parameters: BayesParameters | None = None) -> None:
        self.parameters = parameters or BayesParameters()
        self._window = self.parameters.window()
        self._hypotheses = np.zeros(0, np.int64)
        self._posterior = np.zeros(0)
        self._no_loop = 1.0

    @property
    def no_loop(self) -> float:
        return self._no_loop

    def reset(self) -> None:
        """Back to certainty that there is no loop."""
        self._hypotheses = np.zeros(0, np.int64)
        self._posterior = np.zeros(0)
        self._no_loop = 1.0

    def predict(self, hypotheses: np.ndarray) -> tuple[np.ndarray, float]:
        """Wang et al. 2017 eqs. 10-11: the prior over ``hypotheses`` (sorted place ids) and over -1."""
        p = self.parameters
        hypotheses = np.asarray(hypotheses, dtype=np.int64)
        if len(hypotheses) > 1 and np.any(np.diff(hypotheses) <= 0):
            raise CoreError("hypotheses must be sorted, unique place ids")
        # the previous posterior over the places still searched, renormalised with p(-1)
        kept = np.isin(self._hypotheses, hypotheses)
        previous_ids, previous = self._hypotheses[kept], self._posterior[kept]
        total = self._no_loop + float(previous.sum())
        previous_no_loop = self._no_loop / total if total > 0 else 1.0
        previous = previous / total if total > 0 else np.zeros(len(previous_ids))
        no_loop = p.stay_no_loop * previous_no_loop + p.loop_to_no_loop * float(previous.sum())
        if len(hypotheses) == 0:
            return np.zeros(0), no_loop
        prediction = np.full(len(hypotheses), p.no_loop_to_loop / len(hypotheses) * previous_no_loop)
        if len(previous_ids):
            # spread each previous hypothesis j over j +- reach: a convolution on a
            # dense grid of place ids covering the hypotheses and their windows
            lo = int(hypotheses[0]) - p.reach
            hi = int(hypotheses[-1]) + p.reach
            grid = np.zeros(hi - lo + 1)
            grid[previous_ids - lo] = previous
            prediction += np.convolve(grid, self._window, mode="same")[hypotheses - lo]
            # what j's window puts on ids that are not hypotheses stays on j (RTAB-Map)
            searched = np.zeros(hi - lo + 1)
            searched[hypotheses - lo] = 1.0
            covered = np.convolve(searched, self._window, mode="same")[previous_ids - lo]
            at = np.searchsorted(hypotheses, previous_ids)
            prediction[at] += previous * (self._window.sum() - covered)
        return prediction, no_loop

    def update(self, hypotheses: np.ndarray, similarities: np.ndarray) -> BayesStep:
        """One step with the current image's similarities (M,) to ``hypotheses`` (M,)."""
        hypotheses = np.asarray(hypotheses, dtype=np.int64)
        similarities = np.asarray(similarities, dtype=np.float64)
        if hypotheses.shape != similarities.shape:
            raise CoreError(f"{len(hypotheses)} hypotheses but {len(similarities)} similarities")
        prediction, prediction_no_loop = self.predict(hypotheses)
        observed = likelihood(similarities, self.parameters.ignore_zero_similarities)
        loop = observed.loop * prediction
        no_loop = observed.no_loop * prediction_no_loop
        eta = loop.sum() + no_loop
        if eta <= 0:  # nothing left: start over from "no loop"
            loop, no_loop, eta = np.zeros(len(hypotheses)), 1.0, 1.0
        self._hypotheses = hypotheses.copy()
        self._posterior = loop / eta
        self._no_loop = float(no_loop / eta)
        return BayesStep(
            hypotheses=self._hypotheses.copy(),
            posterior=self._posterior.copy(),
            no_loop=self._no_loop,
            prediction=prediction,
            prediction_no_loop=prediction_no_loop,
            likelihood=observed,
            accepted=len(hypotheses) > 0 and self._no_loop < self.parameters.loop_threshold,
        )
