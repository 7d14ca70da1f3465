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


def _local_module(tmp_path, monkeypatch, name: str, text: str) -> str:
    """A plugin module file in the working directory, importable by ``name``."""
    (tmp_path / f"{name}.py").write_text(text)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def test_a_hookimpl_with_an_unexpected_argument_is_one_line_naming_module_and_hook(
    cli, tmp_path, monkeypatch
) -> None:
    name = _local_module(tmp_path, monkeypatch, "extra_argument_plugins", (
        "import slamfront\n\n@slamfront.hookimpl\ndef slamfront_descriptors(config):\n    return []\n"
    ))
    code, _, err = cli("plugins", "-p", name)
    assert code == 2 and "Traceback" not in err and "AssertionError" not in err
    assert err.strip() == (
        "slamfront: error: plugin module 'extra_argument_plugins': hook slamfront_descriptors(config): "
        "the hook is called with no arguments; remove 'config'"
    )
    registry = PluginRegistry(load_entry_points=False)
    with pytest.raises(PluginError, match="extra_argument_plugins"):
        registry.register_module(name)
    assert registry.modules() == []  # nothing half-registered


def test_a_misspelt_hook_suggests_the_hook(cli, tmp_path, monkeypatch) -> None:
    name = _local_module(tmp_path, monkeypatch, "misspelt_hook_plugins", (
        "import slamfront\n\n@slamfront.hookimpl\ndef slamfront_loop_detector():\n    return []\n"
    ))
    code, _, err = cli("plugins", "-p", name)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "plugin module 'misspelt_hook_plugins': slamfront_loop_detector: no hook is called " \
           "'slamfront_loop_detector'; did you mean 'slamfront_loop_detectors'" in err


INVALID_AND_VALID = '''
import slamfront


class Good(slamfront.Descriptor):
    """A local descriptor."""

    name = "good_local"


class NoDoc(slamfront.Descriptor):
    name = "nodoc"


class NotADescriptor:
    """Not derived from slamfront.Descriptor."""

    name = "not_a_descriptor"


@slamfront.hookimpl
def slamfront_descriptors():
    return [Good, NoDoc, NotADescriptor]
'''


def test_invalid_plugins_come_first_and_local_modules_are_labelled(cli, tmp_path, monkeypatch) -> None:
    name = _local_module(tmp_path, monkeypatch, "mixed_local_plugins", INVALID_AND_VALID)
    code, out, _ = cli("plugins", "-p", name)
    assert code == 0
    lines = out.splitlines()
    assert lines[0] == "invalid plugins, skipped (fix these to use them):"
    assert "mixed_local_plugins: descriptor plugin 'nodoc' (NoDoc) has no docstring" in lines[1]
    assert "does not derive from slamfront.Descriptor" in lines[2]
    good = next(line for line in lines if line.lstrip().startswith("good_local"))
    assert f"[local module mixed_local_plugins ({tmp_path / 'mixed_local_plugins.py'})]" in good
    assert "not installed" not in out
    code, out, err = cli("plugins", "-p", name, "--json")
    listed = {p["name"]: p for p in json.loads(out)}
    assert listed["good_local"]["origin"].startswith("local module mixed_local_plugins")
    assert listed["colour_histogram"]["origin"].startswith("slamfront-example-plugin ")
    assert "invalid plugin skipped: mixed_local_plugins: descriptor plugin 'nodoc'" in err


def _installed_but_broken(tmp_path) -> dict[str, str]:  # type: ignore[no-untyped-def]
    """An environment (for a subprocess) where a plugin package is installed whose module is gone."""
    import os

    info = tmp_path / "site" / "brokenplugins-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: brokenplugins\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[slamfront]\nbroken = brokenplugins_gone\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "site"), os.environ.get("PYTHONPATH", "")])}


def test_a_broken_plugin_package_stops_only_what_uses_it(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import subprocess
    import sys

    import yaml

    from tests.helpers import small_synthetic_recipe

    env = _installed_but_broken(tmp_path)
    recipe = small_synthetic_recipe(frames_per_traversal=8)
    (tmp_path / "uses_none.yaml").write_text(yaml.safe_dump(recipe))
    recipe["loop_detector"]["plugin"] = "from_the_broken_package"
    (tmp_path / "uses_it.yaml").write_text(yaml.safe_dump(recipe))

    def slamfront(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "slamfront", *args], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=300)

    done = slamfront("run", "uses_none.yaml", "-q", "-o", "out")
    assert done.returncode == 0, done.stderr
    (warning,) = [line for line in done.stderr.splitlines() if "brokenplugins" in line]
    assert "warning" in warning and "brokenplugins_gone" in warning and "does not use it" in warning
    done = slamfront("run", "uses_it.yaml", "-q", "-o", "out2")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "from_the_broken_package" in done.stderr and "brokenplugins 1.0" in done.stderr
    done = slamfront("plugins")
    assert done.returncode == 2 and "synthetic" in done.stdout
    assert "error: entry point 'broken' of brokenplugins 1.0 (brokenplugins_gone) cannot be imported" in done.stderr


def test_listing_the_built_in_plugins_loads_none_of_the_libraries_they_compute_with() -> None:
    # `slamfront plugins` imports every plugin module; OpenCV, Open3D, GTSAM, SciPy and numba
    # load when a plugin computes (slamfront.lazy), not when it is listed
    import subprocess
    import sys

    heavy = ("cv2", "open3d", "gtsam", "scipy", "numba", "matplotlib")
    code = (
        "import sys, importlib.metadata as m\n"
        "from slamfront.registry import PluginRegistry\n"
        "builtins = [e.value for e in m.entry_points(group='slamfront') if e.dist.name == 'slamfront']\n"
        "registry = PluginRegistry(modules=builtins, load_entry_points=False)\n"
        "assert len(registry.all()) > 20\n"
        "for info in registry.all():\n"
        "    info.cls.Config.model_json_schema()\n"
        f"print(' '.join(n for n in {heavy!r} if type(sys.modules.get(n)).__name__ == 'module'))\n"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert loaded == []
