"""The public path of :mod:`hbench.ident.polyphase` for plugins: every name of that module, under
this name too (a stable name for plugins, without a warning)."""

from typing import Any

from hbench.ident import polyphase as _module


def __getattr__(name: str) -> Any:
    return getattr(_module, name)


def __dir__() -> list[str]:
    return dir(_module)
