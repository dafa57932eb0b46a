"""The report's HTML elements: a table in a scrolling box and a figure with its PNG embedded.

Shared by the report (:mod:`hbench.report.build`) and its section on methods beyond the paper
(:mod:`hbench.report.beyond`).
"""

from __future__ import annotations

import base64
import html
import math
from typing import Any


def escape(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _empty_columns(table: Any) -> list[str]:
    """Columns whose every cell is empty (nan, None or blank text)."""
    out = []
    for c in table.columns:
        col = table[c]
        if len(col) and all(
            v is None
            or (isinstance(v, str) and not v.strip())
            or (isinstance(v, float) and math.isnan(v))
            for v in col
        ):
            out.append(c)
    return out


def html_table(table: Any, floatfmt: str = ".4g", table_id: str | None = None) -> str:
    """``table`` as HTML in a horizontally scrolling box; columns with no value are left out
    (said under the table)."""
    from hbench.tables.results import format_number

    hidden = _empty_columns(table)
    cols = [c for c in table.columns if c not in hidden]

    def fmt(v: Any) -> str:
        number = format_number(v, floatfmt)
        return str(v) if number is None else number

    ident = f' id="{escape(table_id)}"' if table_id else ""
    head = "".join(f"<th>{escape(c)}</th>" for c in cols)
    body = "".join(
        "<tr>" + "".join(f"<td>{escape(fmt(row[c]))}</td>" for c in cols) + "</tr>"
        for _, row in table.iterrows()
    )
    note = (
        '<p class="hidden-cols">Empty columns not shown: '
        f"{escape(', '.join(map(str, hidden)))}.</p>"
        if hidden
        else ""
    )
    return (
        f'<div class="scroll"><table{ident}><thead><tr>{head}</tr></thead>'
        f"<tbody>{body}</tbody></table></div>{note}"
    )


#: Screen pixels per inch of a figure on the page (its text at 8 pt shows as ~14 px).
SCREEN_PPI = 130


def png_size(png: bytes) -> tuple[int, int, float]:
    """``(width, height, dots per inch)`` from a PNG's IHDR and pHYs chunks (dpi 0 if unset)."""
    import struct

    width, height = struct.unpack(">II", png[16:24])
    at = png.find(b"pHYs")
    dpi = 0.0
    if at > 0:
        ppx, _, unit = struct.unpack(">IIB", png[at + 4 : at + 13])
        dpi = ppx * 0.0254 if unit == 1 else 0.0
    return width, height, dpi


def html_figure(fig_id: str, png: bytes, caption: str) -> str:
    """A figure with its PNG embedded, shown at :data:`SCREEN_PPI` of its print size."""
    data = base64.b64encode(png).decode("ascii")
    width, _, dpi = png_size(png)
    shown = f' width="{round(width * SCREEN_PPI / dpi)}"' if dpi else ""
    return (
        f'<figure id="{escape(fig_id)}"><img src="data:image/png;base64,{data}"{shown} '
        f'alt="{escape(caption)}"><figcaption>{escape(caption)}</figcaption></figure>'
    )
