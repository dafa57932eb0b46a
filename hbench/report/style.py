"""How a method looks in every figure of every report, and what kind of method it is.

:func:`method_style` gives one fixed colour, marker and line style per method name: the paper's
and hbench's methods have their own entries in :data:`METHOD_STYLES` (Okabe-Ito colours, safe
for colour-blind readers); a name not listed gets a colour and marker from its name's CRC32, so
adding a method never changes another's look. Oracle bounds are grey and dashed; reconstructions
dotted. :data:`STYLE_FILE` is the matplotlib style of the figures, reusable by users::

    import matplotlib.pyplot as plt
    from hbench.report.style import STYLE_FILE
    plt.style.use(STYLE_FILE)
"""

from __future__ import annotations

import zlib
from importlib import resources
from pathlib import Path
from typing import Any

#: The matplotlib style file of hbench's figures (journal sizes, Type 42 fonts, 200 dpi PNG).
STYLE_FILE = Path(str(resources.files("hbench").joinpath("data", "hbench.mplstyle")))
#: Figure widths in inches: one journal column, and the full page (two columns).
COLUMN_WIDTH = 3.5
PAGE_WIDTH = 7.16
#: Colour and marker of the known methods.
METHOD_STYLES: dict[str, tuple[str, str]] = {
    "wang-lsm": ("#0072B2", "o"),
    "wang-iv": ("#D55E00", "s"),
    "bai-fu": ("#009E73", "^"),
    "sun-liu-sano": ("#CC79A7", "D"),
    "wang-lsm-inv": ("#56B4E9", "v"),
    "wang-delay": ("#E69F00", "P"),
    "wang-lsm-cn": ("#332288", "X"),
    "wang-iv-opt": ("#882255", "h"),
    "joint-refine": ("#117733", "*"),
    "oracle": ("0.35", "x"),
    "oracle-inv": ("0.55", "+"),
}
#: Colours and markers drawn from (by name) for a method not in :data:`METHOD_STYLES`.
SPARE_COLOURS = ("#44AA99", "#999933", "#AA4499", "#DDCC77", "#661100", "#6699CC", "#888800")
SPARE_MARKERS = ("<", ">", "p", "d", "H", "8")


def method_info(name: str) -> dict[str, bool]:
    """``{"reconstruction": bool, "oracle": bool}`` from the registry (unknown names: False)."""
    try:
        from hbench.plugins import registry

        cls = registry().get("identifiers", name)
    except Exception:
        return {"reconstruction": False, "oracle": False}
    return {
        "reconstruction": bool(getattr(cls, "reconstruction", False)),
        "oracle": "truth" in getattr(cls, "needs", frozenset()),
    }


def method_style(name: str) -> dict[str, Any]:
    """``{"color", "marker", "linestyle"}`` of a method (or of a series ``"a = b | facet"``:
    its first method's)."""
    name = name.split(" | ")[0].split(" = ")[0]
    info = method_info(name)
    if name in METHOD_STYLES:
        color, marker = METHOD_STYLES[name]
    else:
        h = zlib.crc32(name.encode())
        color, marker = SPARE_COLOURS[h % len(SPARE_COLOURS)], SPARE_MARKERS[h % len(SPARE_MARKERS)]
    if info["oracle"] and not color.startswith("0."):
        color = "0.45"  # a bound is grey
    linestyle = "--" if info["oracle"] else (":" if info["reconstruction"] else "-")
    return {"color": color, "marker": marker, "linestyle": linestyle}
