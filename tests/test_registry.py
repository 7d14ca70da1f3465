"""Plugin discovery: built-ins and third parties through the same entry-point group."""

from __future__ import annotations

import json
import types

import pytest

import slamfront
from slamfront.errors import PluginError
from slamfront.plugin import KINDS
from slamfront.registry import PluginRegistry


def test_builtins_come_from_the_entry_point_group() -> None:
    registry = PluginRegistry()
    assert "synthetic" in registry.names("source")
    assert "downsampled" in registry.names("descriptor")
    assert registry.get("source", "synthetic").distribution == "slamfront"
    # the runtime holds no list of built-ins: without entry points there is nothing
    assert PluginRegistry(load_entry_points=False).all() == []


def test_every_plugin_is_declared_fully() -> None:
    for info in PluginRegistry().all():
        assert info.kind in KINDS
        assert info.cls.summary(), info.name
        for name, field in info.cls.Config.model_fields.items():
            assert field.annotation is not None, f"{info.name}.{name} has no type"


def test_example_third_party_plugin_is_listed(cli) -> None:
    code, out, _ = cli("plugins", "--json")
    assert code == 0
    listed = {(p["kind"], p["name"]): p for p in json.loads(out)}
    example = listed[("descriptor", "colour_histogram")]
    assert example["distribution"] == "slamfront-example-plugin"
    assert example["config_schema"]["properties"]["hue_bins"]["default"] == 16
    assert ("loop_detector", "nearest_neighbour") in listed


def _module_with(hook_name: str, classes: list[type]) -> types.ModuleType:
    module = types.ModuleType(f"fake_{hook_name}_{id(classes)}")

    def hook() -> list[type]:
        return classes

    hook.__name__ = hook_name
    setattr(module, hook_name, slamfront.hookimpl(hook))
    return module


def test_invalid_declarations_are_skipped_with_a_reason() -> None:
    class NoDoc(slamfront.Descriptor):
        name = "nodoc"

    NoDoc.__doc__ = None
    registry = PluginRegistry(modules=[_module_with("slamfront_descriptors", [NoDoc, int])], load_entry_points=False)
    assert registry.names("descriptor") == []
    assert any("no docstring" in s for s in registry.skipped)
    assert any("does not derive" in s for s in registry.skipped)
    with pytest.raises(PluginError, match="skipped as invalid"):
        registry.get("descriptor", "nodoc")


def test_duplicate_names_are_an_error() -> None:
    class A(slamfront.Descriptor):
        """A."""

        name = "same"

    class B(slamfront.Descriptor):
        """B."""

        name = "same"

    with pytest.raises(PluginError, match="two descriptor plugins are named 'same'"):
        PluginRegistry(
            modules=[_module_with("slamfront_descriptors", [A]), _module_with("slamfront_descriptors", [B])],
            load_entry_points=False,
        )


def test_unknown_hook_in_a_plugin_module_is_rejected() -> None:
    module = types.ModuleType("typo_module")

    @slamfront.hookimpl
    def slamfront_descriptor() -> list[type]:  # missing "s": not a hook
        return []

    module.slamfront_descriptor = slamfront_descriptor
    registry = PluginRegistry(load_entry_points=False)
    with pytest.raises(PluginError, match="typo_module"):
        registry.register_module(module)
