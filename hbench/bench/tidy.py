"""Tidy rows built as columns: blocks of a cell's rows, joined into one frame at the end.

A block is the rows of one method on one chunk of runs, run-major (every quantity of run 0,
then run 1 ..). Text columns (method, quantity, status, error, and the text identifiers) hold a
handful of distinct values over tens of thousands of rows, so a block keeps them as integer
codes into their labels; :func:`assemble` joins the blocks and turns each text column into the
dtype pandas gives its labels (``str`` on pandas 3) by one ``take``. Converting the repeated
Python strings row by row cost ~5x more and was a tenth of a cell's time. The frame is
the one ``pd.DataFrame`` would build from the same object arrays (tested), except that a text
column's dtype is inferred from all its values at once: a block whose errors are all ``None``
beside blocks with messages gives the messages' dtype, where concatenating per-block frames gave
``object``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from hbench.bench.schema import TIDY_COLUMNS

#: Identifier columns with a numeric dtype; the other identifiers are text.
ID_DTYPES = {"p": np.int64, "delay": np.int64, "sigma2": float, "snr_target": float}


@dataclass(frozen=True)
class Text:
    """A text column as ``labels[codes]``."""

    codes: np.ndarray
    labels: tuple[Any, ...]

    @classmethod
    def constant(cls, value: Any, n: int) -> Text:
        # the object ``np.full(n, value, dtype=object)`` holds (a numpy scalar becomes Python's)
        return cls(np.zeros(n, np.intp), (np.full(1, value, dtype=object)[0],))

    @classmethod
    def of(cls, values: Sequence[Any] | np.ndarray) -> Text:
        """The column ``values``: the objects ``np.asarray(values, dtype=object)`` holds, kept as
        they are (``None`` stays ``None``; ``1``, ``1.0`` and ``True`` stay apart)."""
        vals = np.asarray(values, dtype=object).ravel()
        return cls(*_factorize(vals))

    def repeat(self, k: int) -> Text:
        return Text(np.repeat(self.codes, k), self.labels)

    def tile(self, k: int) -> Text:
        return Text(np.tile(self.codes, k), self.labels)


#: One block of rows: column name -> values (an array, or :class:`Text`).
Block = dict[str, Any]


def block(
    method: str,
    ids: Mapping[str, Any],
    start: int,
    values: Mapping[str, tuple[np.ndarray, float]],
    snr: np.ndarray,
    status: Sequence[str] | np.ndarray,
    error: Sequence[str],
) -> Block:
    """The rows of one method on runs ``start ..``: ``values[quantity] = (per run, true)``."""
    names = list(values)
    R, Q = len(snr), len(names)
    V = np.empty((R, Q))
    for j, q in enumerate(names):
        V[:, j] = values[q][0]
    n = R * Q
    cols: Block = {
        c: np.full(n, ids[c], dtype=ID_DTYPES[c]) if c in ID_DTYPES else Text.constant(ids[c], n)
        for c in ids
    }
    cols.update(
        method=Text.constant(method, n),
        run=np.repeat(np.arange(start, start + R), Q),
        quantity=Text(np.arange(Q, dtype=np.intp), tuple(names)).tile(R),
        value=V.ravel(),
        true=np.tile(np.array([values[q][1] for q in names], dtype=float), R),
        snr=np.repeat(np.asarray(snr, dtype=float), Q),
        status=Text.of(status).repeat(Q),
        error=Text.of(error).repeat(Q),
    )
    return cols


def _factorize(values: Sequence[Any]) -> tuple[np.ndarray, tuple[Any, ...]]:
    """``(codes, labels)`` with ``values[i]`` the object ``labels[codes[i]]``, labels in order of
    first appearance; objects are told apart by type and value (``1``, ``1.0``, ``True`` apart)."""
    index: dict[tuple[type, Any], int] = {}
    codes = np.fromiter(
        (index.setdefault((type(v), v), len(index)) for v in values), np.intp, len(values)
    )
    return codes, tuple(v for _, v in index)


def _join_text(parts: list[Text]) -> Any:
    # every block's labels coded against the union of all, then each block's codes remapped
    remap, union = _factorize([v for part in parts for v in part.labels])
    codes, at = [], 0
    for part in parts:
        codes.append(remap[at : at + len(part.labels)][part.codes])
        at += len(part.labels)
    labels = np.empty(len(union), dtype=object)
    labels[:] = union
    # the dtype pandas infers for these labels (``str`` on pandas 3, object before), then one take
    return pd.Series(labels).array.take(np.concatenate(codes))


def assemble(blocks: Sequence[Block]) -> pd.DataFrame:
    """One frame of :data:`TIDY_COLUMNS` from the blocks, in their order."""
    if not blocks:
        return pd.DataFrame(columns=list(TIDY_COLUMNS))
    cols: dict[str, Any] = {}
    for c in TIDY_COLUMNS:
        parts = [b[c] for b in blocks]
        if isinstance(parts[0], Text):
            cols[c] = _join_text(parts)
        else:
            cols[c] = np.concatenate(parts)
    return pd.DataFrame(cols, columns=list(TIDY_COLUMNS))
