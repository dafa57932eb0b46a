"""Deprecated name of :mod:`hbench.system.runtime`: each name read from here warns and comes from
there."""

from hbench.aliases import forward

__getattr__ = forward(__name__, "hbench.system.runtime")
