"""slamfront as a user installs it: shipped files are package data, and the wheel works anywhere."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from slamfront.campaign.sweepfile import find_sweep, sweeps_dir
from slamfront.cli import shipped_cmd
from slamfront.recipe import build_pipeline, load_recipe, recipes_dir

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("framework", "plugins", "recipes", "sweeps", "foxglove", "setup.py", "pyproject.toml", "README.md", "LICENSE")
"""What the wheel is built from (everything setup.py and pyproject.toml name)."""


def test_the_listings_show_every_shipped_file(cli) -> None:
    code, out, _ = cli("recipes")
    assert code == 0 and [line.split()[0] for line in out.splitlines()] == sorted(
        p.stem for p in (REPO / "recipes").glob("*.yaml"))
    code, out, _ = cli("sweeps")
    assert code == 0 and [line.split()[0] for line in out.splitlines()] == sorted(
        p.stem for p in (REPO / "sweeps").glob("*.yaml"))
    code, out, _ = cli("layout")
    assert code == 0 and json.loads(Path(out.strip()).read_text())["layout"]


def test_an_installation_without_its_recipes_says_so(cli, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(shipped_cmd, "shipped_files", lambda kind: [])
    code, out, err = cli("recipes")
    assert code == 2 and out == "" and "no shipped recipes" in err and "reinstall" in err


def test_a_file_in_the_working_directory_wins_over_a_shipped_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                 cli) -> None:
    monkeypatch.chdir(tmp_path)
    assert load_recipe("demo")[1] == recipes_dir() / "demo.yaml"
    (tmp_path / "demo.yaml").write_text((recipes_dir() / "demo.yaml").read_text().replace("name: demo", "name: mine"))
    recipe, path = load_recipe("demo")
    assert path == Path("demo.yaml") and recipe.name == "mine"
    (tmp_path / "synthetic_nn.yaml").write_text("not: a sweep\n")
    assert find_sweep("synthetic_nn") == Path("synthetic_nn.yaml") != sweeps_dir() / "synthetic_nn.yaml"
    code, out, err = cli("layout", "-o", tmp_path / "layout.json")
    assert code == 0 and json.loads((tmp_path / "layout.json").read_text())["layout"]


def _frames_reaching_queries() -> int:
    """A frame count past the middle of the shipped paired demo (the quick one): taken from the
    recipe (its source's length), so it follows the recipe if it changes."""
    recipe, path = load_recipe("paired_demo")
    return math.ceil(0.6 * len(build_pipeline(recipe, str(path)).source))


def _venv_with_the_wheel(tmp_path: Path) -> Path:
    """Build the wheel from a copy of the sources, install it (no dependencies) into a fresh
    virtualenv that sees the test venv's dependencies but none of slamfront's editable installs."""
    source = tmp_path / "src"
    source.mkdir()
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(REPO / name, source / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input", "--quiet"]
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", tmp_path / "dist", source],
                   check=True, env=env, capture_output=True)
    wheel = next((tmp_path / "dist").glob("slamfront-*.whl"))
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", venv], check=True)
    subprocess.run([*pip, "--python", venv / "bin" / "python", "install", "--no-deps", "--no-index", wheel],
                   check=True, env=env, capture_output=True)
    # the dependencies: a folder of links to the test venv's packages, minus slamfront's own
    deps = tmp_path / "deps"
    deps.mkdir()
    own = ("slamfront", "__editable__", "_slamfront")
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        if not entry.name.lower().startswith(own) and not entry.name.endswith(".pth"):
            (deps / entry.name).symlink_to(entry)
    site = next((venv / "lib").glob("python3*/site-packages"))
    (site / "test_venv_dependencies.pth").write_text(f"{deps}\n")
    return venv


def test_the_wheel_installs_and_runs_from_any_directory(tmp_path: Path) -> None:
    venv = _venv_with_the_wheel(tmp_path)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "SLAMFRONT_DATA"}
    env.update(HOME=str(tmp_path / "home"), XDG_DATA_HOME=str(tmp_path / "home" / "data"))

    def slamfront(*args: object) -> str:
        done = subprocess.run([venv / "bin" / "slamfront", *map(str, args)], cwd=work, env=env,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, f"slamfront {' '.join(map(str, args))}: {done.stderr}"
        return done.stdout

    installed = subprocess.run([venv / "bin" / "python", "-c", "import slamfront; print(slamfront.__file__)"],
                               cwd=work, env=env, capture_output=True, text=True, check=True).stdout
    assert str(venv) in installed  # the wheel's copy, not this checkout
    metadata = subprocess.run([venv / "bin" / "python", "-c", "from importlib.metadata import metadata; "
                               "m = metadata('slamfront'); print(m['License-Expression']); print(*m.get_all('Project-URL'), "
                               "sep='\\n'); print(*m.get_all('License-File'), sep='\\n')"],
                              cwd=work, env=env, capture_output=True, text=True, check=True).stdout.splitlines()
    assert metadata[0] == "BSD-3-Clause" and "LICENSE" in metadata
    assert any(line.startswith("Source, https://") for line in metadata)
    listed = {line.split()[0] for line in slamfront("recipes").splitlines()}
    assert listed == {p.stem for p in (REPO / "recipes").glob("*.yaml")}
    n = _frames_reaching_queries()
    slamfront("run", "paired_demo", "--max-frames", n, "-q")
    metrics = json.loads((work / "logs" / "paired_demo" / "metrics.json").read_text())
    assert (work / "logs" / "paired_demo" / "run.mcap").stat().st_size > 0
    assert metrics["n_frames"] == n and metrics["n_queries"] > 0
    for sweep in (REPO / "sweeps").glob("*.yaml"):
        assert f"{sweep.stem}:" in slamfront("sweep", sweep.stem, "--dry-run")
    assert "nearest_neighbour" in slamfront("plugins")
    assert Path(slamfront("layout").strip()).is_relative_to(venv)
    assert slamfront("datasets", "path").strip() == str(tmp_path / "home" / "data" / "slamfront")
    assert "source: nordland" in slamfront("datasets")  # the slamfront.datasets entry points of the wheel
