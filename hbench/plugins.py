"""The plugin registry: a pluggy manager over the ``hbench`` entry-point group.

Built-in plugins register through the same entry-point group a third-party package uses, so
there is one path for everyone. Set ``HBENCH_DISABLE_PLUGINS=name1,name2`` (entry-point names) to
block a broken plugin.
"""

from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass
from functools import cache
from types import ModuleType
from typing import Any

import pluggy

from hbench import hookspecs
from hbench.errors import InputError, PluginNotFoundError

#: Kind of plugin -> hook that registers it.
KINDS: dict[str, str] = {
    "identifiers": "register_identifiers",
    "nonlinearities": "register_nonlinearities",
    "plants": "register_plants",
    "controllers": "register_controllers",
    "noise_models": "register_noise_models",
    "references": "register_references",
    "effects": "register_effects",
    "readers": "register_readers",
}


#: Kind -> the singular noun used in messages.
SINGULAR: dict[str, str] = {
    "identifiers": "method",
    "nonlinearities": "nonlinearity",
    "plants": "plant",
    "controllers": "controller",
    "noise_models": "noise model",
    "references": "reference",
    "effects": "effect",
    "readers": "reader",
}


@dataclass(frozen=True)
class Entry:
    """One registered thing: its name, the object, and the plugin (package) it comes from."""

    kind: str
    name: str
    obj: Any
    source: str


def _source_of(plugin: object, pm: pluggy.PluginManager) -> str:
    name = pm.get_name(plugin) or getattr(plugin, "__name__", repr(plugin))
    for plugin_, dist in pm.list_plugin_distinfo():
        if plugin_ is plugin:
            return f"{dist.project_name} {dist.version} ({name})"
    return f"{name} (registered at run time)"


def make_manager(load_entrypoints: bool = True) -> pluggy.PluginManager:
    """A fresh plugin manager with hbench's hookspecs and, by default, every installed plugin."""
    pm = pluggy.PluginManager("hbench")
    pm.add_hookspecs(hookspecs)
    for name in filter(None, os.environ.get("HBENCH_DISABLE_PLUGINS", "").split(",")):
        pm.set_blocked(name.strip())
    if load_entrypoints:
        _load_entrypoints(pm)
    return pm


def _load_entrypoints(pm: pluggy.PluginManager) -> None:
    """Every installed plugin, one entry point at a time: one that fails to import is skipped
    with a one-line warning naming it (and the switch that silences it), so a broken
    third-party package does not stop every command."""
    from importlib import metadata

    for name in sorted({ep.name for ep in metadata.entry_points(group="hbench")}):
        try:
            pm.load_setuptools_entrypoints("hbench", name=name)
        except Exception as exc:  # an ImportError, or anything the plugin's import raises
            msg = " ".join(f"{type(exc).__name__}: {exc}".split())
            sys.stderr.write(
                f"hbench: warning: plugin {name!r} failed to load ({msg}); skipped "
                f"(HBENCH_DISABLE_PLUGINS={name} silences this)\n"
            )


@cache
def get_manager() -> pluggy.PluginManager:
    """The process-wide plugin manager (created on first use)."""
    return make_manager()


class Registry:
    """Everything the registered plugins provide, by kind and name."""

    def __init__(self, pm: pluggy.PluginManager | None = None) -> None:
        self.pm = pm if pm is not None else get_manager()
        self._entries: dict[str, dict[str, Entry]] | None = None

    def refresh(self) -> None:
        """Forget the cached listing (after registering or unregistering a plugin)."""
        self._entries = None

    @property
    def entries(self) -> dict[str, dict[str, Entry]]:
        if self._entries is None:
            self._entries = self._collect()
        return self._entries

    def _collect(self) -> dict[str, dict[str, Entry]]:
        out: dict[str, dict[str, Entry]] = {kind: {} for kind in KINDS}
        for kind, hook_name in KINDS.items():
            hook = getattr(self.pm.hook, hook_name)
            for impl in hook.get_hookimpls():
                source = _source_of(impl.plugin, self.pm)

                def register(name: str, obj: Any, _kind: str = kind, _src: str = source) -> None:
                    check_name(name, SINGULAR[_kind], _src)
                    if name in out[_kind]:
                        prev = out[_kind][name].source
                        raise InputError(
                            f"{SINGULAR[_kind]} {name!r} is registered twice ({prev} and {_src})"
                        )
                    out[_kind][name] = Entry(_kind, name, obj, _src)

                impl.function(**{a: register for a in impl.argnames})
        return out

    def names(self, kind: str) -> list[str]:
        """Sorted names registered for ``kind``."""
        return sorted(self.entries[kind])

    def get(self, kind: str, name: str) -> Any:
        """The object registered as ``name`` for ``kind``; a clear error if there is none."""
        try:
            return self.entries[kind][name].obj
        except KeyError:
            known = ", ".join(self.names(kind)) or "none"
            raise PluginNotFoundError(
                f"unknown {SINGULAR.get(kind, kind)} {name!r} (known: {known})"
            ) from None

    def as_dict(self) -> dict[str, list[dict[str, str]]]:
        """A JSON-ready listing: kind -> [{name, source, object}]."""
        return {
            kind: [
                {
                    "name": e.name,
                    "source": e.source,
                    "object": f"{getattr(e.obj, '__module__', '?')}."
                    f"{getattr(e.obj, '__qualname__', type(e.obj).__name__)}",
                }
                for e in sorted(entries.values(), key=lambda e: e.name)
            ]
            for kind, entries in self.entries.items()
        }


#: A plugin's name: it becomes a config option, a file name and report text, so a letter or
#: digit, then letters, digits, ``_``, ``-`` and single ``.`` (no ``/``, ``<``, ``..``, spaces).
NAME = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9_-]|\.(?!\.))*")


def check_name(name: Any, what: str, source: str) -> None:
    """Refuse a plugin name that is not :data:`NAME` (:class:`InputError` naming its plugin)."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or len(name) > 64:
        raise InputError(
            f"{what} name {name!r} from {source} is not a valid name (a letter or digit, then "
            "letters, digits, '_', '-' or single '.'; at most 64 characters)"
        )


@cache
def registry() -> Registry:
    """The process-wide registry."""
    return Registry()


def get(kind: str, name: str) -> Any:
    """Shorthand for ``registry().get(kind, name)``."""
    return registry().get(kind, name)


def register_module(module: ModuleType | object, name: str | None = None) -> None:
    """Register a plugin object at run time (tests, notebooks); refreshes the registry."""
    get_manager().register(module, name=name)
    registry().refresh()


def unregister_module(module: ModuleType | object) -> None:
    """Undo :func:`register_module`."""
    get_manager().unregister(module)
    registry().refresh()
