"""Discovering plugins: the ``slamfront`` entry-point group is the registry.

Built-ins and third-party packages are found the same way: pluggy loads every module
named in the ``slamfront`` entry-point group, calls their hooks, and the classes they
return are indexed by (kind, name). A recipe may also name importable modules in
``plugin_modules`` (a one-file plugin in the working directory, say).

Set ``SLAMFRONT_TRACE_HOOKS=1`` to print every hook call, its implementations and results.
"""

from __future__ import annotations

import difflib
import importlib
import inspect
import os
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from types import ModuleType

import pluggy
from pydantic import BaseModel

from slamfront import hookspecs
from slamfront.errors import PluginError
from slamfront.plugin import KIND_BASES, KINDS, Kind, Plugin

ENTRY_POINT_GROUP = "slamfront"

HOOK_OF_KIND: dict[Kind, str] = {
    "source": "slamfront_sources",
    "descriptor": "slamfront_descriptors",
    "place_map": "slamfront_place_maps",
    "loop_detector": "slamfront_loop_detectors",
    "localizer": "slamfront_localizers",
    "registration": "slamfront_registrations",
    "backend": "slamfront_backends",
}


@dataclass(frozen=True)
class PluginInfo:
    """A discovered plugin class and where it came from."""

    kind: Kind
    name: str
    cls: type[Plugin]
    module: str
    distribution: str
    """The installed package that registered it (``slamfront`` for built-ins)."""
    distribution_version: str

    @property
    def version(self) -> str:
        return self.cls.version


class PluginRegistry:
    """Every plugin slamfront can use in this environment.

    :param modules: extra plugin modules to register (import names or module objects),
        in addition to the entry-point group.
    :param load_entry_points: read the ``slamfront`` entry-point group (tests turn it off
        to work with a controlled set).
    """

    def __init__(
        self, modules: Iterable[str | ModuleType] = (), load_entry_points: bool = True
    ) -> None:
        self.skipped: list[str] = []
        self._plugins: dict[tuple[Kind, str], PluginInfo] = {}
        self._manager = pluggy.PluginManager(hookspecs.PROJECT)
        self._manager.add_hookspecs(hookspecs)
        if os.environ.get("SLAMFRONT_TRACE_HOOKS"):
            self._manager.trace.root.setwriter(sys.stderr.write)
            self._manager.enable_tracing()
        if load_entry_points:
            try:
                self._manager.load_setuptools_entrypoints(ENTRY_POINT_GROUP)
                self._manager.check_pending()
            except Exception as exc:
                raise PluginError(f"loading the {ENTRY_POINT_GROUP!r} entry points failed: {exc}") from exc
        for module in modules:
            self._register(module)
        self._collect()

    def register_module(self, module: str | ModuleType) -> None:
        """Register one more plugin module (by import name or object)."""
        self._register(module)
        self._collect()

    def _register(self, module: str | ModuleType) -> None:
        if isinstance(module, str):
            # one-file plugins live in the working directory, as with `python -m`
            if os.getcwd() not in sys.path:
                sys.path.insert(0, os.getcwd())
            try:
                module = importlib.import_module(module)
            except ImportError as exc:
                raise PluginError(f"plugin module {module!r} cannot be imported: {exc}") from exc
        if not self._manager.is_registered(module):
            try:
                self._manager.register(module)
                self._manager.check_pending()  # a misspelt hook name is an error, not a no-op
            except pluggy.PluginValidationError as exc:
                self._manager.unregister(module)
                raise PluginError(f"plugin module {module.__name__!r}: {exc}") from exc

    def _distribution_of(self) -> dict[str, tuple[str, str]]:
        found = {}
        for plugin, dist in self._manager.list_plugin_distinfo():
            found[plugin.__name__] = (dist.project_name, dist.version)
        return found

    def _collect(self) -> None:
        self.skipped = []
        self._plugins = {}
        dists = self._distribution_of()
        for kind in KINDS:
            hook = getattr(self._manager.hook, HOOK_OF_KIND[kind])
            for impl in hook.get_hookimpls():
                module_name = impl.plugin_name if not inspect.ismodule(impl.plugin) else impl.plugin.__name__
                dist, dist_version = dists.get(module_name, ("(not installed)", ""))
                result = impl.function()
                for cls in result or ():
                    problem = _declaration_problem(cls, kind)
                    if problem:
                        self.skipped.append(f"{module_name}: {problem}")
                        continue
                    key = (kind, cls.name)
                    if key in self._plugins and self._plugins[key].cls is not cls:
                        other = self._plugins[key].module
                        raise PluginError(
                            f"two {kind} plugins are named {cls.name!r}: one from {other}, one from {module_name}"
                        )
                    self._plugins[key] = PluginInfo(kind, cls.name, cls, module_name, dist, dist_version)

    def names(self, kind: Kind) -> list[str]:
        """Plugin names of one kind, sorted."""
        return sorted(name for k, name in self._plugins if k == kind)

    def get(self, kind: Kind, name: str) -> PluginInfo:
        """The plugin of ``kind`` called ``name``.

        :raises PluginError: naming the closest known names when there is no such plugin.
        """
        if kind not in KIND_BASES:
            raise PluginError(f"unknown plugin kind {kind!r}; kinds are {', '.join(KINDS)}")
        try:
            return self._plugins[(kind, name)]
        except KeyError:
            known = self.names(kind)
            close = difflib.get_close_matches(name, known, n=3, cutoff=0.5)
            hint = f"did you mean {' or '.join(repr(c) for c in close)}?" if close else (
                f"known {kind} plugins: {', '.join(known) or 'none'}"
            )
            skipped = f" (skipped as invalid: {'; '.join(self.skipped)})" if self.skipped else ""
            raise PluginError(f"unknown {kind} plugin {name!r}; {hint}{skipped}") from None

    def all(self, kind: Kind | None = None) -> list[PluginInfo]:
        """Every plugin (of one kind), ordered by kind then name."""
        order = {k: i for i, k in enumerate(KINDS)}
        infos = [p for p in self._plugins.values() if kind is None or p.kind == kind]
        return sorted(infos, key=lambda p: (order[p.kind], p.name))

    def modules(self) -> Sequence[str]:
        """Names of the registered plugin modules."""
        return sorted(self._manager.get_name(p) or str(p) for p in self._manager.get_plugins())


def _declaration_problem(cls: object, kind: Kind) -> str | None:
    """Why ``cls`` cannot be a ``kind`` plugin, or None when it can."""
    base = KIND_BASES[kind]
    if not (inspect.isclass(cls) and issubclass(cls, base)):
        return f"{cls!r} returned by the {kind} hook does not derive from slamfront.{base.__name__}"
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name.isidentifier():
        return f"{cls.__qualname__} has no valid 'name' (a Python identifier)"
    if not (cls.__doc__ and cls.__doc__.strip()):
        return f"{kind} plugin {name!r} ({cls.__qualname__}) has no docstring"
    if not (inspect.isclass(cls.Config) and issubclass(cls.Config, BaseModel)):
        return f"{kind} plugin {name!r}: Config is not a pydantic model"
    return None
