"""A report's table as files: Markdown and LaTeX (booktabs), text cells escaped for each, an
empty table saying why (:func:`write_table`)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any


def _md_text(text: str) -> str:
    """``text`` on one line for a Markdown table cell (``\\`` and ``|`` escaped)."""
    return " ".join(text.split()).replace("\\", "\\\\").replace("|", r"\|")


def _text_cells(table: Any, escape: Callable[[str], str]) -> Any:
    """``table`` with ``escape`` applied to every text cell (numbers left alone)."""
    import pandas as pd

    out = table.copy()
    for col in out.columns:
        if out[col].dtype == object or pd.api.types.is_string_dtype(out[col].dtype):
            out[col] = out[col].map(lambda v: escape(v) if isinstance(v, str) else v)
    return out


def markdown_cells(table: Any) -> Any:
    """``table`` with every text cell on one line and escaped for a Markdown table."""
    return _text_cells(table, _md_text)


def write_table(
    out: Path, name: str, table: Any, note: str = "", empty: str = "", wrap_last: bool = False
) -> None:
    """Write ``table`` as ``out/name.md`` and ``out/name.tex`` (booktabs).

    Parameters
    ----------
    out : Path
        The report folder.
    name : str
        Stem of the files (and the LaTeX caption ``hbench <name>``).
    table : DataFrame
        The table; its text cells are escaped for Markdown (``|``) and LaTeX
        (:func:`hbench.tables.results.tex_escape`, in :func:`hbench.tables.results.to_latex`).
    note : str
        A line written above the Markdown table and as a LaTeX comment above the table.
    empty : str
        Why the table has no rows: said above the Markdown table and in a row spanning the LaTeX
        table, when ``table`` is empty.
    wrap_last : bool
        Let the last column's text wrap in LaTeX (a ``p`` column; long messages).
    """
    from hbench.tables.results import column_spec, tex_escape, to_latex, to_markdown

    lines = [line for line in (note, empty if table.empty else "") if line]
    md = to_markdown(markdown_cells(table))
    (out / f"{name}.md").write_text("".join(f"{_md_text(line)}\n\n" for line in lines) + md)
    # to_latex escapes the text cells
    tex = to_latex(table, caption=f"hbench {name}", label=f"tab:hbench-{name}")
    ncols = len(table.columns)
    if wrap_last and ncols:
        spec = column_spec(table)
        tex = tex.replace("{" + spec + "}", "{" + spec[:-1] + r"p{0.4\linewidth}}", 1)
    if table.empty and empty:
        span = rf"\multicolumn{{{ncols}}}{{p{{0.8\linewidth}}}}{{{tex_escape(empty)}}} \\"
        tex = tex.replace("\\bottomrule", span + "\n\\bottomrule", 1)
    if note:
        tex = f"% {' '.join(note.split())}\n" + tex
    (out / f"{name}.tex").write_text(tex)
