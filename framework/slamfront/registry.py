"""Discovering plugins: the ``slamfront`` entry-point group is the registry.

Built-ins and third-party packages are found the same way: pluggy loads every module
named in the ``slamfront`` entry-point group, calls their hooks, and the classes they
return are indexed by (kind, name). A recipe may also name importable modules in
``plugin_modules`` (a one-file plugin in the working directory, say).

Set ``SLAMFRONT_TRACE_HOOKS=1`` to print every hook call, its implementations and results.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect
import os
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import pluggy
from pydantic import BaseModel

from slamfront import hookspecs
from slamfront.errors import PluginError
from slamfront.plugin import KIND_BASES, KINDS, Kind, Plugin
from slamfront.suggest import did_you_mean

if TYPE_CHECKING:
    from slamfront.evaluation.base import Evaluation
    from slamfront.message_types import MessageTypes

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
    """The installed package that provides it (``slamfront`` for built-ins); empty for a
    local module (``-p my_plugins`` or ``plugin_modules``) that no installed package owns."""
    distribution_version: str
    file: str = ""
    """The plugin module's file."""

    @property
    def version(self) -> str:
        return self.cls.version

    @property
    def origin(self) -> str:
        """Where it came from, for people: ``slamfront 0.1.0``, ``local module my_plugins (./my_plugins.py)``."""
        if self.distribution:
            return f"{self.distribution} {self.distribution_version}".rstrip()
        return f"local module {self.module} ({self.file})" if self.file else f"local module {self.module}"


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
        """Plugins left out because their declaration is invalid, each as ``module: why``."""
        self.broken: list[str] = []
        """Installed plugin packages whose entry point cannot be imported, one line each (naming
        the package and why). Their plugins are unknown: a recipe that uses one fails (the
        error lists these), one that does not runs with a warning, ``slamfront plugins`` fails."""
        self._plugins: dict[tuple[Kind, str], PluginInfo] = {}
        self._distributions: dict[str, tuple[str, str]] = {}  # module name -> (distribution, version)
        self._manager = pluggy.PluginManager(hookspecs.PROJECT)
        self._manager.add_hookspecs(hookspecs)
        if os.environ.get("SLAMFRONT_TRACE_HOOKS"):
            self._manager.trace.root.setwriter(sys.stderr.write)
            self._manager.enable_tracing()
        if load_entry_points:
            self._load_entry_points()
        for module in modules:
            self._register(module)
        self._collect()

    def register_module(self, module: str | ModuleType) -> None:
        """Register one more plugin module (by import name or object)."""
        self._register(module)
        self._collect()

    def _load_entry_points(self) -> None:
        """Every module of the ``slamfront`` entry-point group, each checked like a local one
        (pluggy's own loader would stop at the first bad module with a multi-line message).
        One that cannot be imported (a missing dependency, a module removed) goes to
        :attr:`broken` instead of stopping everything."""
        for entry_point in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
            dist = entry_point.dist
            owner = f"{dist.name} {dist.version}" if dist is not None else "an unknown distribution"
            if self._manager.get_plugin(entry_point.name) is not None:
                continue
            try:
                module = entry_point.load()
            except Exception as exc:  # noqa: BLE001 - any import-time failure of a third-party module
                self.broken.append(
                    f"entry point {entry_point.name!r} of {owner} ({entry_point.value}) cannot be imported: "
                    f"{type(exc).__name__}: {exc}"
                )
                continue
            self._register(module, name=entry_point.name, owner=owner)
            if dist is not None:
                self._distributions[module.__name__] = (dist.name, dist.version)

    def _register(self, module: str | ModuleType, name: str | None = None, owner: str = "") -> None:
        """Check and register a plugin module.

        :raises PluginError: one line naming the module and the hook at fault.
        """
        if isinstance(module, str):
            # one-file plugins live in the working directory, as with `python -m`
            if os.getcwd() not in sys.path:
                sys.path.insert(0, os.getcwd())
            try:
                module = importlib.import_module(module)
            except ImportError as exc:
                raise PluginError(f"plugin module {module!r} cannot be imported: {exc}") from exc
        if self._manager.is_registered(module):
            return
        where = f"plugin module {module.__name__!r}" + (f" (from {owner})" if owner else "")
        problem = _hookimpl_problem(module)
        if problem:
            raise PluginError(f"{where}: {problem}")
        try:
            self._manager.register(module, name=name)
            self._manager.check_pending()  # a hook name unknown to pluggy is an error, not a no-op
        except (pluggy.PluginValidationError, ValueError) as exc:
            if self._manager.is_registered(module):
                self._manager.unregister(module)
            raise PluginError(f"{where}: {' '.join(str(exc).split())}") from exc

    def _distribution_of(self, module: ModuleType) -> tuple[str, str]:
        """(distribution, version) of a registered module; ("", "") for a local one."""
        if module.__name__ in self._distributions:
            return self._distributions[module.__name__]
        # a module named with -p may still belong to an installed package
        top = module.__name__.partition(".")[0]
        owners = importlib.metadata.packages_distributions().get(top, ())
        found = (owners[0], importlib.metadata.version(owners[0])) if owners else ("", "")
        self._distributions[module.__name__] = found
        return found

    def _collect(self) -> None:
        self.skipped = []
        self._plugins = {}
        for kind in KINDS:
            hook = getattr(self._manager.hook, HOOK_OF_KIND[kind])
            for impl in hook.get_hookimpls():
                module = impl.plugin
                module_name = module.__name__ if inspect.ismodule(module) else impl.plugin_name
                dist, dist_version = self._distribution_of(module) if inspect.ismodule(module) else ("", "")
                file = getattr(module, "__file__", None) or ""
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
                    self._plugins[key] = PluginInfo(kind, cls.name, cls, module_name, dist, dist_version, file)

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
            hint = did_you_mean(name, self.names(kind), f"{kind} plugins")
            skipped = f" (skipped as invalid: {'; '.join(self.skipped)})" if self.skipped else ""
            broken = f"; it may come from a plugin package that is broken: {'; '.join(self.broken)}" if self.broken else ""
            raise PluginError(f"unknown {kind} plugin {name!r}; {hint}{skipped}{broken}") from None

    def all(self, kind: Kind | None = None) -> list[PluginInfo]:
        """Every plugin (of one kind), ordered by kind then name."""
        order = {k: i for i, k in enumerate(KINDS)}
        infos = [p for p in self._plugins.values() if kind is None or p.kind == kind]
        return sorted(infos, key=lambda p: (order[p.kind], p.name))

    def modules(self) -> Sequence[str]:
        """Names of the registered plugin modules."""
        return sorted(self._manager.get_name(p) or str(p) for p in self._manager.get_plugins())

    # --- message types and evaluations (hooks called when a command needs them) ----------

    def _impl_origin(self, impl: pluggy.HookImpl) -> str:
        """Who implements a hook, for messages: ``slamfront 0.1.0``, ``local module my_plugins``."""
        module = impl.plugin
        if not inspect.ismodule(module):
            return f"plugin {impl.plugin_name}"
        dist, version = self._distribution_of(module)
        return f"{dist} {version} ({module.__name__})" if dist else f"local module {module.__name__}"

    def message_types(self) -> MessageTypes:
        """The shared message types and every type the registered modules declare
        (``slamfront_message_types``), by schema name.

        :raises PluginError: a declared class is not a message type, or two modules
            declare one schema name (naming both).
        """
        from slamfront.message_types import MessageTypes

        declared = []
        for impl in self._manager.hook.slamfront_message_types.get_hookimpls():
            origin = self._impl_origin(impl)
            declared.extend((cls, origin) for cls in impl.function() or ())
        return MessageTypes(declared)

    def evaluations(self, kinds: Iterable[str]) -> list[Evaluation]:
        """Fresh evaluations the registered modules contribute (``slamfront_evaluations``)
        for a run whose recipe has the plugin kinds ``kinds``, in registration order.

        :raises PluginError: an implementation returned something that is not an Evaluation.
        """
        from slamfront.evaluation.base import Evaluation

        arguments = {"kinds": frozenset(kinds)}
        chosen: list[Evaluation] = []
        for impl in self._manager.hook.slamfront_evaluations.get_hookimpls():
            for evaluation in impl.function(**{name: arguments[name] for name in impl.argnames}) or ():
                if not isinstance(evaluation, Evaluation):
                    raise PluginError(
                        f"{self._impl_origin(impl)}: slamfront_evaluations returned {evaluation!r}, "
                        "which does not derive from slamfront.Evaluation"
                    )
                chosen.append(evaluation)
        return chosen


def _hookimpl_problem(module: ModuleType) -> str | None:
    """What is wrong with ``module``'s hook implementations (a misspelt hook, an argument
    the hook does not pass), said in one line, or None when they are fine."""
    marker = f"{hookspecs.PROJECT}_impl"  # the attribute @slamfront.hookimpl sets
    spec_marker = f"{hookspecs.PROJECT}_spec"
    hooks = [name for name, value in vars(hookspecs).items() if hasattr(value, spec_marker)]
    for attribute, function in sorted(vars(module).items()):
        options = getattr(function, marker, None)
        if not isinstance(options, dict) or not callable(function):
            continue
        hook = options.get("specname") or attribute
        if hook not in hooks:
            return f"{attribute}: no hook is called {hook!r}; {did_you_mean(hook, hooks, 'hooks')}"
        expected = list(inspect.signature(getattr(hookspecs, hook)).parameters)
        given = list(inspect.signature(function).parameters)
        unexpected = [name for name in given if name not in expected]
        if unexpected:
            takes = f"takes only {', '.join(expected)}" if expected else "is called with no arguments"
            return (
                f"hook {hook}({', '.join(given)}): the hook {takes}; "
                f"remove {', '.join(repr(u) for u in unexpected)}"
            )
    return None


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


# --- the registry inside plugin configs -------------------------------------------------

CONTEXT_KEY = "registry"
"""Where :func:`config_context` puts the run's registry in pydantic's validation context."""


def config_context(registry: PluginRegistry, data: Path | None = None) -> dict[str, Any]:
    """The validation context every plugin ``Config`` is validated with: the data root
    (relative ``DataPath`` fields resolve under it) and the run's plugin registry (a config
    that names other plugins, like ``mixed_scenes``'s inner sources, looks them up there)."""
    from slamfront.data import data_root

    return {"data_root": data or data_root(), CONTEXT_KEY: registry}


def registry_in_context(context: Any) -> PluginRegistry:
    """The run's registry, inside a ``Config`` validator (``info.context``).

    :raises ValueError: the config is validated without one (outside a recipe); pydantic
        reports it as the field's error.
    """
    registry = (context or {}).get(CONTEXT_KEY) if isinstance(context, dict) or context is None else None
    if not isinstance(registry, PluginRegistry):
        raise ValueError("names other plugins, so it is validated with the run's plugin registry "
                         "(slamfront.registry.config_context); build it through a recipe")
    return registry
