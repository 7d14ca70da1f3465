"""The stress benchmark's case generator (benchmarks/stress_cases.py): cases follow from the master
seed alone, stay inside their window, and their ground truth follows the re-paced query."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _cases():
    spec = importlib.util.spec_from_file_location("stress_cases", BENCH / "stress_cases.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def test_the_same_master_seed_draws_the_same_cases_and_another_does_not() -> None:
    s = _cases()
    assert s.draw(7, 40) == s.draw(7, 40)
    assert s.draw(7, 40)["cases"] != s.draw(8, 40)["cases"]


def test_the_committed_case_list_is_the_one_its_master_seed_draws() -> None:
    s = _cases()
    seeds = json.loads((BENCH / "stress_seeds.json").read_text())
    assert seeds["cases"] == s.draw(seeds["master_seed"], seeds["n"])["cases"]
    assert len(seeds["cases"]) >= 200


def test_every_case_stays_in_its_window_and_every_family_is_drawn() -> None:
    s = _cases()
    cases = s.draw(3, 200)["cases"]
    seen = set()
    for case in cases:
        places = s.query_places(case)
        assert s.WINDOW[0] <= case["length"] <= s.WINDOW[1]
        assert 0 < len(places) <= s.MAX_QUERY
        assert places.min() >= 0 and places.max() <= case["length"] - 1
        seen.update(s.families(case))
    assert seen == {*s.FAMILIES, "unchanged"}


def test_the_ground_truth_follows_reversal_pace_and_stops() -> None:
    s = _cases()
    base = {"case": "x", "seed": 0, "length": 100}
    assert list(s.query_places({**base, "changes": {}})) == list(range(100))
    assert list(s.query_places({**base, "changes": {"reversed": True}})) == list(range(99, -1, -1))
    double = s.query_places({**base, "changes": {"pace": {"kind": "constant", "speed": 2.0}}})
    assert list(double) == list(range(0, 100, 2))
    stopped = s.query_places({**base, "changes": {"stops": [{"at": 10, "frames": 5}]}})
    assert len(stopped) == 105 and np.all(stopped[10:16] == 10)
    jumped = s.query_places({**base, "changes": {"jump": {"at": 0.5, "by": 0.3}}})
    assert np.max(np.diff(jumped)) >= 30


def test_a_case_is_laid_out_as_links_and_pairs(tmp_path: Path) -> None:
    s = _cases()
    for light in ("day", "dusk"):
        (tmp_path / light).mkdir()
        for k in range(50):
            (tmp_path / light / f"{k:03d}.png").write_bytes(b"")
    case = {"case": "x", "seed": 0, "reference": "dusk", "query": "day", "start": 10, "length": 30,
            "changes": {"reversed": True}}
    params = s.lay_out(case, {"day": tmp_path / "day", "dusk": tmp_path / "dusk"}, tmp_path / "case")
    references = sorted(Path(params["reference_folder"]).iterdir())
    assert len(references) == 30 and references[0].resolve() == (tmp_path / "dusk" / "010.png").resolve()
    first_query = sorted(Path(params["query_folder"]).iterdir())[0]
    assert first_query.resolve() == (tmp_path / "day" / "039.png").resolve()
    assert Path(params["pairs"]).read_text().splitlines()[1] == "0,29"
