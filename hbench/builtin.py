"""hbench's built-in models and readers, registered through the ``hbench`` entry-point group."""

from __future__ import annotations

from hbench.hookspecs import Register, hookimpl


@hookimpl
def register_nonlinearities(register: Register) -> None:
    from hbench import nonlinearities as nl

    for cls in nl.BUILTIN:
        register(cls.name, cls)
