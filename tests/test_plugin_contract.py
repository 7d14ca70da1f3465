"""Built-ins are ordinary plugins: message types and evaluations come through hooks, tools
that read logs learn types from the installed packages, and the framework names no
built-in plugin's message or evaluation."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import types
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import pytest

import slamfront
from slamfront.errors import PluginError
from slamfront.mcaplog.validate import validate_log
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.message_types import FRAMEWORK, MessageTypes, installed_message_types
from slamfront.messages import SHARED_MESSAGES, LoopVerdict, Message, PoseGraphRecord
from slamfront.registry import PluginRegistry

ROOT = Path(__file__).resolve().parents[1]
FRAMEWORK_DIR = ROOT / "framework" / "slamfront"
BUILT_IN_SCHEMAS = {
    # plugin-private types keep the schema names they had inside slamfront.messages: older logs decode
    "slamfront.BowStatistics", "slamfront.SequenceDecision", "slamfront.PlaceThreshold", "slamfront.PoseEstimate",
    "slamfront.KeyframeAdded", "slamfront.KeyframeMap", "slamfront.CloudRegistration",
    "slamfront.RegisteredTrajectory", "slamfront.LoopConstraint", "slamfront.PoseGraphState",
}


def slamfront_cli(*args: object, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """``slamfront ARGS`` in a fresh process, as a user runs it."""
    return subprocess.run([sys.executable, "-m", "slamfront", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600)


def _module(name: str, **hooks: object) -> types.ModuleType:
    module = types.ModuleType(name)
    for hook, function in hooks.items():
        setattr(module, hook, slamfront.hookimpl(function))  # type: ignore[arg-type]
    return module


@dataclass(frozen=True, eq=False)
class Ping(Message):
    """A test message."""

    schema_name: ClassVar[str] = "tests.Ping"
    frame: int
    label: str = ""


@dataclass(frozen=True, eq=False)
class OtherPing(Message):
    """Another class claiming the same schema name."""

    schema_name: ClassVar[str] = "tests.Ping"
    frame: int


def test_built_in_packages_declare_their_message_types_through_the_hook() -> None:
    installed = installed_message_types()
    for cls in SHARED_MESSAGES:
        assert installed.get(cls.schema_name) is cls and installed.origin(cls.schema_name) == FRAMEWORK
    for name in BUILT_IN_SCHEMAS:
        cls = installed.get(name)
        assert cls is not None and cls.__module__.startswith("slamfront_plugins."), name
        assert installed.origin(name).startswith("slamfront "), installed.origin(name)
    example = installed.get("slamfront_example.ColourSummary")
    assert example is not None and installed.origin(example.schema_name).startswith("slamfront-example-plugin ")
    # the framework's mixins let it read back ends' own messages without naming them
    assert issubclass(installed.get("slamfront.LoopConstraint"), LoopVerdict)
    assert issubclass(installed.get("slamfront.PoseGraphState"), PoseGraphRecord)


def test_two_packages_declaring_one_schema_name_is_an_error_naming_both() -> None:
    first = _module("first_plugins", slamfront_message_types=lambda: [Ping])
    second = _module("second_plugins", slamfront_message_types=lambda: [OtherPing])
    registry = PluginRegistry(modules=[first, second], load_entry_points=False)
    with pytest.raises(PluginError, match=r"'tests.Ping'.*first_plugins.*second_plugins|'tests.Ping'.*second_plugins.*first_plugins"):
        registry.message_types()
    same_twice = PluginRegistry(modules=[first, _module("again", slamfront_message_types=lambda: [Ping])],
                                load_entry_points=False)
    assert same_twice.message_types().get("tests.Ping") is Ping
    shadowing = _module("shadowing", slamfront_message_types=lambda: [_framework_clash()])
    with pytest.raises(PluginError, match=r"'slamfront.LoopResult'.*slamfront \(framework\).*shadowing"):
        PluginRegistry(modules=[shadowing], load_entry_points=False).message_types()


def _framework_clash() -> type[Message]:
    @dataclass(frozen=True, eq=False)
    class LoopResult(Message):
        """Not the shared one."""

        schema_name: ClassVar[str] = "slamfront.LoopResult"
        frame: int

    return LoopResult


def test_a_declared_message_type_is_a_message_dataclass_with_a_schema_name_of_its_own() -> None:
    class NotADataclass(Message):
        """No fields."""

        schema_name: ClassVar[str] = "tests.NotADataclass"

    @dataclass(frozen=True, eq=False)
    class Unnamed(Message):
        """Inherits the base's schema name."""

        frame: int

    for bad, why in ((int, "does not derive"), (NotADataclass, "not a dataclass"), (Unnamed, "no schema_name")):
        module = _module("bad_messages", slamfront_message_types=_returning([bad]))
        with pytest.raises(PluginError, match=f"local module bad_messages: .*{why}"):
            PluginRegistry(modules=[module], load_entry_points=False).message_types()


def _returning(declared: list) -> object:
    def slamfront_message_types() -> list:
        return declared

    return slamfront_message_types


def test_evaluations_come_fresh_for_each_run_from_the_hook() -> None:
    class Counter(slamfront.Evaluation):
        title = "count"

    calls: list[frozenset[str]] = []

    def slamfront_evaluations(kinds: frozenset[str]) -> list[slamfront.Evaluation]:
        calls.append(kinds)
        return [Counter()] if "descriptor" in kinds else []

    registry = PluginRegistry(modules=[_module("counting", slamfront_evaluations=slamfront_evaluations)],
                              load_entry_points=False)
    first, second = registry.evaluations({"source", "descriptor"}), registry.evaluations(["descriptor"])
    assert len(first) == len(second) == 1 and first[0] is not second[0]
    assert registry.evaluations({"source"}) == [] and calls[0] == frozenset({"source", "descriptor"})
    broken = _module("broken_evaluations", slamfront_evaluations=lambda: [object()])
    with pytest.raises(PluginError, match="broken_evaluations.*does not derive from slamfront.Evaluation"):
        PluginRegistry(modules=[broken], load_entry_points=False).evaluations({"source"})


def _built_in_names() -> set[str]:
    """Class and schema names of the built-in packages' message types and evaluations."""
    names = set(BUILT_IN_SCHEMAS)
    for schema in BUILT_IN_SCHEMAS:
        names.add(installed_message_types().require(schema).__name__)
    registry = PluginRegistry()
    kinds = {"source", "descriptor", "place_map", "loop_detector", "localizer", "registration", "backend"}
    names |= {type(e).__name__ for e in registry.evaluations(kinds) if type(e).__module__.startswith("slamfront_plugins")}
    return names


def test_no_framework_module_names_a_built_in_plugins_message_or_evaluation() -> None:
    forbidden = _built_in_names()
    assert {"BowStatistics", "BowEvaluation", "LocalizationEvaluation", "PoseGraphState"} <= forbidden
    found = []
    for path in sorted(FRAMEWORK_DIR.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                modules = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                found += [f"{path.name}: imports {m}" for m in modules if m.startswith("slamfront_plugins")]
            words: list[str] = []
            if isinstance(node, ast.Name):
                words = [node.id]
            elif isinstance(node, ast.Attribute):
                words = [node.attr]
            elif isinstance(node, ast.alias):
                words = [node.name.rpartition(".")[2]]
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                words = node.value.replace("`", " ").replace(".", " . ").split()
                words += [w for w in node.value.split() if w.startswith("slamfront.")]
            found += [f"{path.relative_to(FRAMEWORK_DIR)}:{node.lineno}: {w}" for w in words if w in forbidden]
    assert not found, found


def test_the_shared_contract_is_small() -> None:
    assert len((FRAMEWORK_DIR / "messages.py").read_text().splitlines()) < 400


def _log_with_pings(path: Path, tamper: bool = False) -> Path:
    schema = json.dumps(Ping.json_schema()).encode()
    with RunLogWriter(path, "zstd", 1 << 20, "tests", None) as log:
        for frame in range(3):
            if tamper and frame == 1:  # a label that is a number: the embedded schema says string
                log.write_raw("/descriptor/ping", Ping.schema_name, "jsonschema", schema, "json",
                              b'{"frame":1,"label":12345}', frame)
            else:
                log.write("/descriptor/ping", Ping(frame=frame, label=f"p{frame}"), frame)
    return path


def test_a_message_type_no_package_declares_is_checked_against_the_embedded_schema(tmp_path: Path) -> None:
    log = _log_with_pings(tmp_path / "pings.mcap")
    declared = MessageTypes([(Ping, "tests")])
    assert validate_log(log, types=declared).valid
    validation = validate_log(log, types=MessageTypes())
    assert validation.valid and validation.not_installed == {"/descriptor/ping": "tests.Ping"}
    assert validation.n_messages == 3
    tampered = _log_with_pings(tmp_path / "tampered.mcap", tamper=True)
    problems = validate_log(tampered, types=MessageTypes(), max_problems=5).problems
    assert any("does not match the schema the log embeds for tests.Ping: at label" in p for p in problems), problems


def test_an_embedded_schema_is_data_nothing_is_fetched_and_no_regular_expression_runs(tmp_path: Path) -> None:
    from slamfront.mcaplog.validate import EmbeddedSchema

    hostile = {"type": "object", "properties": {"a": {"$ref": "https://example.invalid/schema.json"},
                                                "b": {"type": "string", "pattern": "^(a+)+$"}}}
    schema = EmbeddedSchema("x.Hostile", json.dumps(hostile).encode())
    assert schema.check(json.dumps({"b": "a" * 40 + "!"}).encode()) is None  # the pattern is not evaluated
    assert "cannot be evaluated" in schema.check(b'{"a": 1}')  # the remote $ref is never fetched
    assert "not JSON" in EmbeddedSchema("x.Broken", b"{").check(b"{}")
    assert schema.check(b"[" * 100_000) is not None  # absurd nesting is a problem, not a crash


def test_the_example_plugin_logs_its_own_message_and_evaluation_and_validates_in_a_fresh_process(
    tmp_path: Path,
) -> None:
    out = tmp_path / "colour"
    run = slamfront_cli("run", "paired_demo", "--set", "descriptor.plugin=colour_histogram", "--set",
                        "descriptor.params={}", "--max-frames", "60", "-o", out, "-q", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["colour_grey_frames"] == 0 and 0 < metrics["colour_mean_saturation"] < 1
    assert "## Colour" in (out / "report.md").read_text()
    inspected = slamfront_cli("inspect", out, "--validate", cwd=tmp_path)
    assert inspected.returncode == 0, inspected.stdout + inspected.stderr
    assert "/descriptor/colour_summary" in inspected.stdout and "slamfront_example.ColourSummary" in inspected.stdout
    assert "not installed" not in inspected.stdout and "valid:" in inspected.stdout
