"""The docs are tested: hook reference entries and the first-plugin guide."""

from __future__ import annotations

import inspect
import os
import re
from pathlib import Path

import slamfront.hookspecs as hookspecs
from slamfront.registry import PluginRegistry

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _hooks() -> dict[str, str]:
    hooks = {}
    for name, function in vars(hookspecs).items():
        if name.startswith("slamfront_") and callable(function):
            source = inspect.getsource(function)
            signature = re.search(r"def (\w+\(.*?\) -> .*?):\n", source, re.S).group(1)
            hooks[name] = " ".join(signature.split())
    return hooks


def test_every_hook_has_a_reference_entry_with_its_signature() -> None:
    reference = (DOCS / "hooks.md").read_text()
    hooks = _hooks()
    assert len(hooks) == 9
    for name, signature in hooks.items():
        assert f"### `{signature}`" in reference, f"docs/hooks.md lacks an entry for {signature}"
        function = getattr(hookspecs, name)
        assert function.__doc__ and ":returns:" in function.__doc__


def _files_in(markdown: str) -> dict[str, str]:
    """Code blocks whose info string names a file: ```python my_plugins.py"""
    return {m.group(2): m.group(3) for m in re.finditer(r"```(\w+) ([\w.]+)\n(.*?)```", markdown, re.S)}


def test_first_plugin_guide_works_as_written(tmp_path: Path, cli, monkeypatch) -> None:
    files = _files_in((DOCS / "writing_plugins.md").read_text())
    assert set(files) == {"my_plugins.py", "my_recipe.yaml"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    code, out, err = cli("run", "my_recipe.yaml", "-q")
    assert code == 0, err
    assert "logs/my_first_plugin/run.mcap" in out
    assert (tmp_path / "logs/my_first_plugin/report.md").read_text().count("cosine_match") >= 1
    code, out, _ = cli("plugins", "-p", "my_plugins", "--kind", "loop_detector")
    assert "cosine_match" in out and os.path.exists("logs/my_first_plugin/pr.png")


def test_the_hook_reference_names_every_built_in_plugin() -> None:
    reference = (DOCS / "hooks.md").read_text()
    built_ins = [info for info in PluginRegistry().all() if info.distribution == "slamfront"]
    assert built_ins
    missing = [f"{info.kind} {info.name}" for info in built_ins if f"`{info.name}`" not in reference]
    assert not missing, f"docs/hooks.md does not list these built-ins: {missing}"
