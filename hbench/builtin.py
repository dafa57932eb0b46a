"""hbench's built-in models and readers, registered through the ``hbench`` entry-point group."""

from __future__ import annotations

from hbench.hookspecs import Register, hookimpl


@hookimpl
def register_nonlinearities(register: Register) -> None:
    from hbench.model import nonlinearities as nl

    for cls in nl.BUILTIN:
        register(cls.name, cls)


@hookimpl
def register_plants(register: Register) -> None:
    from hbench.model import plants

    for name, factory in plants.BUILTIN.items():
        register(name, factory)


@hookimpl
def register_controllers(register: Register) -> None:
    from hbench.model import controllers

    for cls in controllers.BUILTIN:
        register(cls.name, cls)


@hookimpl
def register_noise_models(register: Register) -> None:
    from hbench.model import noise

    for cls in noise.BUILTIN:
        register(cls.name, cls)


@hookimpl
def register_references(register: Register) -> None:
    from hbench.model import signals

    for cls in signals.BUILTIN:
        register(cls.name, cls)


@hookimpl
def register_readers(register: Register) -> None:
    from hbench.io import readers

    for reader in readers.READERS:
        register(reader.name, reader)


@hookimpl
def register_effects(register: Register) -> None:
    from hbench.diagnose import effects

    for cls in effects.BUILTIN:
        register(cls.name, cls)
