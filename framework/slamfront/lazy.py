"""Libraries imported on first use, so that listing plugins does not load what they compute with.

``slamfront plugins`` imports every plugin module to show its parameters; a module whose
functions use Open3D or GTSAM throughout names the library with :func:`lazy_module`
instead of ``import``, and the library loads when a function first touches it (when the
plugin runs), not when the plugin's module is imported. This is the standard library's
recipe (:class:`importlib.util.LazyLoader`); the module object is the real one once loaded.
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType


def lazy_module(name: str) -> ModuleType:
    """The module ``name``, executed on its first attribute access (imported now if already loaded).

    :raises ModuleNotFoundError: ``name`` is not installed (checked now, not at first use).
    """
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)
    loader = importlib.util.LazyLoader(spec.loader)
    spec.loader = loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    loader.exec_module(module)
    return module
