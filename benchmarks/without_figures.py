"""A yardstick: the ``hbench`` command with part of its figures' output left out, so that a
benchmark can weigh what the figures cost in the command's time (``bench_reproduce.py``)::

    python -m benchmarks.without_figures pdf reproduce [ARGS]      # every figure as PNG only
    python -m benchmarks.without_figures figures reproduce [ARGS]  # no figure drawn or written

``pdf``: every figure is drawn and written as PNG and its PDF is left out; ``figures``: every
figure is still built (its artists created) but neither drawn nor written, and the report's page
carries a blank one-pixel image in its place. Everything else (the levels, the tables, the
statistics, the page) runs as the command runs it. :func:`hbench.report.figures.save` is
replaced in the command's process before it starts; the workers inherit the replacement because
they are forked (:mod:`hbench.bench.parallel` on ``fork``; where a platform has no ``fork`` they
would draw the figures in full). Run from the repository's root (``-m`` finds ``benchmarks``
there). Not part of the package: its output is not a report, only the time it took.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hbench.report import figures

#: What can be left out.
PARTS = ("pdf", "figures")

_save = figures.save
_left_out = ""


def _reduced_save(
    fig: Any, stem: Path | str | None, formats: Sequence[str] = ("png", "pdf")
) -> bytes:
    """:func:`hbench.report.figures.save` without the part left out."""
    if _left_out == "pdf":
        return _save(fig, stem, tuple(f for f in formats if f != "pdf"))
    figures.pyplot().close(fig)
    return _blank_png()


def _blank_png() -> bytes:
    """A one-pixel PNG (what the report's page embeds in place of a figure)."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.new("L", (1, 1)).save(buf, format="png")
    return buf.getvalue()


def main(argv: Sequence[str]) -> None:
    """``argv``: the part left out (:data:`PARTS`), then the ``hbench`` command's arguments."""
    global _left_out
    if not argv or argv[0] not in PARTS:
        raise SystemExit(f"usage: python -m benchmarks.without_figures {{{','.join(PARTS)}}} ARGS")
    _left_out = argv[0]
    figures.save = _reduced_save
    from hbench.cli import console

    sys.argv = ["hbench", *argv[1:]]
    console()


if __name__ == "__main__":
    main(sys.argv[1:])
