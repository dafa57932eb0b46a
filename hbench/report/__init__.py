"""The comparison report: HTML, LaTeX and PDF, its figures and their style, and the section on
methods beyond the paper.

Reading a name of :mod:`hbench.report.build` from the package itself (``hbench.report.NAME``) is
deprecated: it warns and comes from there.
"""

import pkgutil

from hbench.aliases import forward

__getattr__ = forward(
    __name__, "hbench.report.build", submodules=[m.name for m in pkgutil.iter_modules(__path__)]
)
