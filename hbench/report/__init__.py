"""The comparison report: HTML, LaTeX and PDF, its figures and their style, and the section on
methods beyond the paper.

Reading a name of the former module ``hbench.report`` from the package (``hbench.report.NAME``) is
deprecated: it warns and comes from :mod:`hbench.report.build`.
"""

from hbench._moved import forward

__getattr__ = forward(
    __name__, "hbench.report.build", submodules=("build", "beyond", "figures", "style")
)
