"""Lazy package attributes (PEP 562): a name is imported from its submodule on first use; and the old names of
moved modules, answered by the new ones."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings


def lazy_exports(package: str, exports: dict, namespace: dict):
    """``(__getattr__, __dir__)`` for ``package`` resolving ``exports`` (name -> submodule,
    relative to ``package``) on first access and caching them in ``namespace``."""

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", package), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__


class MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Old module names that moved (issue 57's layout): ``import silfit.dataset`` gives ``silfit.io.subjects``
    itself, with a :class:`DeprecationWarning` naming the new place, so scripts written against the old layout
    keep running for a release. No file is kept at the old place."""

    def __init__(self, moved: dict):
        self.moved = dict(moved)

    def find_spec(self, name, path=None, target=None):
        if name not in self.moved:
            return None
        return importlib.util.spec_from_loader(name, self)

    def create_module(self, spec):
        new = self.moved[spec.name]
        warnings.warn(f"{spec.name} moved to {new}; the old name goes in a later release", DeprecationWarning, 2)
        return importlib.import_module(new)

    def exec_module(self, module) -> None:
        """Nothing to run: the module is the new one, already imported."""


def alias_moved_modules(moved: dict) -> None:
    """Answer the old names in ``moved`` (old dotted name -> new one) from now on (once per process)."""
    if not any(isinstance(f, MovedModules) for f in sys.meta_path):
        sys.meta_path.append(MovedModules(moved))


def moved_function(old_module: str, name: str, new_module: str):
    """``new_module.name``, for a function that left ``old_module`` (kept for one release): a DeprecationWarning names
    its new home. Called from the old module's ``__getattr__``."""
    import importlib
    import warnings

    warnings.warn(
        f"{old_module}.{name} moved to {new_module}.{name}; the old name goes in the next release",
        DeprecationWarning,
        stacklevel=3,
    )
    return getattr(importlib.import_module(new_module), name)
