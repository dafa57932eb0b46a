"""``hbench sweep``: the Hydra app (one job = one cell), its validated configuration, the callbacks
that aggregate tables, and the adapter to Hydra.

Reading a name of the former module ``hbench.sweep`` from the package (``hbench.sweep.NAME``) is
deprecated: it warns and comes from :mod:`hbench.sweep.app`.
"""

from hbench._moved import forward

__getattr__ = forward(
    __name__, "hbench.sweep.app", submodules=("app", "config", "callbacks", "hydra_adapter")
)
