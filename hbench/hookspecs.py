"""Hook specifications: how plugins add methods, models and readers to hbench.

Every hook follows the register-callback pattern: hbench calls the hook with a ``register``
function and the plugin calls ``register(name, obj)`` once per thing it provides. A plugin
module implements any subset of the hooks, for instance::

    import hbench

    @hbench.hookimpl
    def register_identifiers(register):
        register("my-method", MyIdentifier)

and is found through the ``hbench`` entry-point group of its package::

    [project.entry-points.hbench]
    my_plugin = "my_package.hbench_plugin"

Plugins may accept fewer arguments than a spec lists, so hooks can grow without breaking anyone.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pluggy

hookspec = pluggy.HookspecMarker("hbench")
hookimpl = pluggy.HookimplMarker("hbench")

Register = Callable[[str, Any], None]


@hookspec
def register_identifiers(register: Register) -> None:
    """Register blind identification methods: ``register(name, cls)``.

    ``cls`` subclasses :class:`hbench.ident.identifiers.Identifier`.
    """


@hookspec
def register_nonlinearities(register: Register) -> None:
    """Register actuator models: ``register(name, cls)``, ``cls`` a
    :class:`hbench.model.nonlinearities.Nonlinearity` subclass."""


@hookspec
def register_plants(register: Register) -> None:
    """Register plants: ``register(name, factory)``; ``factory(**params)`` returns a
    :class:`hbench.model.plants.PlantModel`."""


@hookspec
def register_controllers(register: Register) -> None:
    """Register controllers: ``register(name, cls)``, a
    :class:`hbench.model.controllers.Controller`."""


@hookspec
def register_noise_models(register: Register) -> None:
    """Register output noise models: ``register(name, cls)``, a
    :class:`hbench.model.noise.NoiseModel`."""


@hookspec
def register_references(register: Register) -> None:
    """Register reference signals: ``register(name, cls)``, a
    :class:`hbench.model.signals.Reference`."""


@hookspec
def register_effects(register: Register) -> None:
    """Register effects used by ``hbench diagnose``: ``register(name, cls)``."""


@hookspec
def register_readers(register: Register) -> None:
    """Register record readers: ``register(name, reader)``; ``reader`` has ``can_read(path)``
    and ``read(path, p=None) -> Record``."""
