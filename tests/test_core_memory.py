"""Memory management: STM/WM/LTM moves, weights, retrieval, and the working-memory bound."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.errors import CoreError
from slamfront.core.memory import MemoryManager, MemoryParameters, working_memory_bound


def test_places_pass_through_stm_into_wm() -> None:
    memory = MemoryManager(MemoryParameters(stm_size=3, time_budget_s=0))
    moved = [memory.add(place) for place in range(5)]
    assert moved == [[], [], [], [0], [1]]
    assert memory.stm == [2, 3, 4] and memory.working().tolist() == [0, 1]
    assert memory.flush() == [2, 3, 4] and memory.n_stm == 0 and memory.n_wm == 5
    with pytest.raises(CoreError, match="already"):
        memory.add(3)


def test_transfer_takes_lowest_weight_then_oldest_and_spares_the_immune() -> None:
    memory = MemoryManager(MemoryParameters(stm_size=0, time_budget_s=0.1))
    for place in range(6):
        memory.add(place)
    for place in (0, 0, 1, 4):
        memory.merge(place)  # weights: 0 -> 2, 1 -> 1, 4 -> 1
    assert memory.transfer(0.05, entered=1, immune=set()) == []  # within budget
    # over budget with one place entered: transfer 2, lowest weights (2, 3, 5: weight 0), oldest first
    assert memory.transfer(0.2, entered=1, immune={2}) == [3, 5]
    assert memory.working().tolist() == [0, 1, 2, 4] and memory.n_ltm == 2
    assert memory.transfer(0.2, entered=2, immune={2}) == [1, 4, 0]  # weight 1 (oldest first), then 2


def test_retrieval_brings_nearest_neighbours_back() -> None:
    memory = MemoryManager(MemoryParameters(stm_size=0, time_budget_s=0, max_working_memory=2, max_retrieved=2,
                                            retrieval_radius=3))
    for place in range(10):
        memory.add(place)
    assert memory.transfer(0.0, entered=0, immune={8, 9}) == [0, 1, 2, 3, 4, 5, 6, 7]
    assert memory.retrieve(5) == [4, 6]  # nearest first, at most 2
    assert memory.retrieve(5) == [3, 7]
    assert memory.retrieve(5) == [2]  # 8 is already in WM, 1 is beyond the radius
    assert memory.immune_around(5) == {2, 3, 4, 6, 7, 8}
    assert memory.in_long_term(1) and memory.in_working(6)


def test_a_cap_keeps_wm_at_its_size() -> None:
    memory = MemoryManager(MemoryParameters(stm_size=2, time_budget_s=0, max_working_memory=5))
    for place in range(100):
        memory.add(place)
        memory.transfer(0.0, entered=1, immune=set())
        assert memory.n_wm <= 5
    assert memory.n_wm == 5 and memory.n_ltm == 93


def test_wm_never_exceeds_its_bound_on_a_long_stream() -> None:
    """10,000 images, time = base + per_place * |WM searched|, revisits that retrieve from LTM."""
    parameters = MemoryParameters(stm_size=10, time_budget_s=0.7, max_retrieved=2, retrieval_radius=3)
    base, per_place = 0.05, 0.002
    bound = working_memory_bound(parameters.time_budget_s, base, per_place, parameters.max_retrieved)
    assert bound == 325 + 1 + 2
    memory = MemoryManager(parameters)
    rng = np.random.default_rng(0)
    searched = []
    for place in range(10_000):
        entered = memory.add(place)
        if rng.random() < 0.05:
            memory.merge(int(rng.integers(0, place + 1)))  # some places get weight
        working = memory.working()
        searched.append(len(working))
        elapsed = base + per_place * len(working)
        retrieved: list[int] = []
        immune: set[int] = set()
        if len(working) and place > 2000:
            # a revisit of an old stretch: the best hypothesis pulls its LTM neighbours back
            best = int(working[rng.integers(0, len(working))])
            retrieved = memory.retrieve(best)
            immune = memory.immune_around(best) | set(retrieved)
        memory.transfer(elapsed, entered=len(entered) + len(retrieved), immune=immune)
    searched_array = np.array(searched)
    assert searched_array.max() <= bound
    assert searched_array.max() >= bound - 3  # the bound is tight: retrieval does push WM to it
    assert memory.n_ltm > 9000
    # the time model then stays within budget except by at most the bound's margin
    assert base + per_place * searched_array.max() <= parameters.time_budget_s + per_place * (1 + 2)


def test_bound_needs_a_cost_model() -> None:
    with pytest.raises(CoreError):
        working_memory_bound(0.7, 0.1, 0.0, 2)
    assert working_memory_bound(0.1, 0.2, 0.01, 0) == 1  # even the fixed cost is over budget
