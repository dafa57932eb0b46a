"""Deprecated name of :mod:`hbench.model.signals`: each name read from here warns and comes from
there."""

from hbench.aliases import forward

__getattr__ = forward(__name__, "hbench.model.signals")
