"""Deprecated top-level module names (``hbench.simulate``, ...) that forward to the packages.

A deprecated name forwards each attribute read from it to the module's new path with a
:class:`DeprecationWarning` naming that path and the release that removes the
name (:data:`REMOVED_IN`); nothing is imported and no process-wide state
(import hooks, ``sys.modules``) is touched until a name is read.
"""

import importlib
import warnings
from collections.abc import Callable, Iterable, Mapping
from typing import Any

#: The release that drops the deprecated names (stated in every warning).
REMOVED_IN = "0.3"


def forward(old: str, new: str, submodules: Iterable[str] = ()) -> Callable[[str], Any]:
    """A module ``__getattr__`` that serves the deprecated module ``old`` from ``new``.

    Parameters
    ----------
    old : str
        The deprecated module's name (its ``__name__``).
    new : str
        The module that now holds its names.
    submodules : iterable of str
        Names that are the package ``old``'s own submodules (not forwarded, so that
        ``from old import submodule`` imports it without a warning).

    Returns
    -------
    callable
        ``__getattr__(name)``: warns and returns ``new``'s attribute ``name``.
    """
    own = frozenset(submodules)

    def __getattr__(name: str) -> Any:
        if name in own or (name.startswith("__") and name.endswith("__")):
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        return _deprecated(old, name, new)

    return __getattr__


def moved(module: str, names: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that serves names ``module`` no longer holds from the modules
    that now do (``names``: name -> module), each read with a :class:`DeprecationWarning`;
    any other name is an ``AttributeError``."""

    def __getattr__(name: str) -> Any:
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        return _deprecated(f"{module}.{name}", name, names[name])

    return __getattr__


def _deprecated(old: str, name: str, new: str) -> Any:
    """``new``'s attribute ``name``, with the warning that ``old`` goes in :data:`REMOVED_IN`,
    blamed on the line that read it (the frame above the module's ``__getattr__``)."""
    warnings.warn(
        f"{old} is deprecated and will be removed in hbench {REMOVED_IN}: import {name} from {new}",
        DeprecationWarning,
        stacklevel=3,
    )
    return getattr(importlib.import_module(new), name)
