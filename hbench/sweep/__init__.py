"""``hbench sweep``: the Hydra app (one job = one cell), its validated configuration, the callbacks
that aggregate tables, and the adapter to Hydra.

Reading a name of :mod:`hbench.sweep.app` from the package itself (``hbench.sweep.NAME``) is
deprecated: it warns and comes from there.
"""

import pkgutil

from hbench.aliases import forward

__getattr__ = forward(
    __name__, "hbench.sweep.app", submodules=[m.name for m in pkgutil.iter_modules(__path__)]
)
