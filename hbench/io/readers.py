"""Read measured records from files and check them.

Two formats are read:

* **table** (CSV, TSV or Parquet) with columns ``t, x, y`` and optional ``r``, one row per fast
  sample: ``t`` in seconds on a uniform grid of period ``h``; ``y`` the measured output; ``x`` the
  controller output as seen at the fast rate, held over each slow period ``T = p h``; ``r`` the
  reference likewise. ``p`` is inferred from ``x`` unless given.
* **plant-log**: the tab-separated historian export with a ``PROCESSDATA`` header used by
  ``../shared/data/stictiongpt`` (MV -> ``x``, PV -> ``y``, SV -> ``r``, ``p = 1``).

Conventions
-----------
* Rows in error messages are data rows counted from 0 (the header excluded); plant-log messages
  also give the line of the file.
* **Held means bit-for-bit equal.** A zero-order hold repeats the very same number, so ``x`` is
  held over a period when consecutive fast values compare equal, with no tolerance. A tolerance
  would merge a controller's genuinely small moves into holds and infer a wrong ``p``. A file whose
  ``x`` carries float jitter inside holds is refused with a message that says how large the
  in-hold changes are, so the user can round ``x`` (or pass ``--p 1``).
* ``p`` inferred: the fast rows where ``x`` changes lie on the grid ``phase + k p``; ``p`` is the
  gcd of the gaps between changes and ``phase`` the first change modulo ``p``. A grid that a few
  stray changes spoil (90 % or more of at least 10 changes on a coarser grid) is refused rather
  than read with a spuriously small ``p``.
* Slow samples: ``x[k]`` and ``r[k]`` are the fast values at the first row of slow period ``k``.
  ``r`` need not be held (a notice says so when it is not); its value at the period start is the
  one a sampled controller would have used.
* ``h`` is the median step of ``t``, or, when one exists, the float ``h`` next to it for which
  ``t - t[0] == arange(N) * h`` exactly, so that :func:`write_record` then :func:`read_record`
  round-trips ``h`` bit for bit.
"""

from __future__ import annotations

import errno
import math
import os
import re
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import replace
from datetime import datetime
from itertools import pairwise
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import pandas as pd

from hbench.errors import RecordError
from hbench.sim.records import Record
from hbench.system import atomic

__all__ = [
    "MIN_SLOW_SAMPLES",
    "READERS",
    "PlantLogReader",
    "Reader",
    "TableReader",
    "read_record",
    "record_from_fast",
    "write_record",
]

#: Fewest slow samples a record may have.
MIN_SLOW_SAMPLES = 50

#: Relative tolerance on the steps of ``t`` (relative to the median step ``h``); steps are also
#: allowed :data:`T_ULPS` float spacings of ``t``'s largest value (Unix times near 1.7e9 s are
#: stored to 2.4e-7 s).
T_RTOL = 1e-6
T_ULPS = 4

#: A coarser grid holding at least this share of ``x``'s changes makes a smaller gcd suspect ...
_NEAR_GRID_SHARE = 0.9
#: ... when there are at least this many changes.
_NEAR_GRID_MIN_CHANGES = 10

_TABLE_SUFFIXES = {".csv": "csv", ".tsv": "tsv", ".parquet": "parquet", ".pq": "parquet"}


@runtime_checkable
class Reader(Protocol):
    """What :func:`read_record` needs of a reader (built-in or registered by a plugin)."""

    name: str

    def can_read(self, path: Path) -> bool:
        """Whether this reader recognises the file at ``path``."""

    def read(self, path: Path, p: int | None = None) -> Record:
        """Read the file at ``path`` into a :class:`~hbench.sim.records.Record`."""


# --------------------------------------------------------------------------- fast arrays -> Record


def _check_p(p: Any) -> int | None:
    if p is None:
        return None
    if isinstance(p, bool) or not isinstance(p, int | np.integer) or p < 1:
        raise RecordError(f"p must be a positive integer, got {p!r}")
    return int(p)


def _to_float(values: Any, label: str, where: Callable[[int], str]) -> np.ndarray:
    """``values`` as a 1-D float array; RecordError naming ``label`` and the first bad row."""
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise RecordError(f"column '{label}' must be 1-D (one run), got shape {arr.shape}")
    if arr.dtype.kind in "iuf":
        return arr.astype(float)
    out = np.empty(arr.shape, dtype=float)
    for i, v in enumerate(arr):
        if v is None or v is pd.NA or v is pd.NaT or (isinstance(v, str) and not v.strip()):
            out[i] = np.nan
            continue
        try:
            if isinstance(v, bool | np.bool_ | complex | np.complexfloating | bytes):
                raise TypeError
            out[i] = float(v)
        except (TypeError, ValueError):
            shown = v.item() if isinstance(v, np.generic) else v
            raise RecordError(
                f"column '{label}' has a non-numeric value {shown!r} at {where(i)}"
            ) from None
    return out


def _divisors(n: int) -> list[int]:
    small = [d for d in range(1, math.isqrt(n) + 1) if n % d == 0]
    return sorted(set(small) | {n // d for d in small})


def _near_grid(changes: np.ndarray, gaps: np.ndarray, g: int) -> tuple[int, int] | None:
    """A grid ``(P, phase)`` coarser than ``g`` holding most (not all) changes of ``x``."""
    if changes.size < _NEAR_GRID_MIN_CHANGES:
        return None
    values, counts = np.unique(gaps, return_counts=True)
    modal = int(values[np.argmax(counts)])
    for P in reversed(_divisors(modal)):
        if P <= g or P % g:
            continue
        hits = np.bincount(changes % P, minlength=P)
        phase = int(np.argmax(hits))
        if hits[phase] >= _NEAR_GRID_SHARE * changes.size:
            return P, phase
    return None


def _jitter_hint(x: np.ndarray, rows: np.ndarray) -> str:
    """A hint when the off-grid changes of ``x`` are tiny next to its range."""
    jumps = np.abs(x[rows] - x[rows - 1])
    scale = max(float(np.ptp(x)), float(np.max(np.abs(x))), np.finfo(float).tiny)
    if float(jumps.max()) <= 1e-9 * scale:
        return (
            f"; the largest is {float(jumps.max()):.3g}, which looks like float jitter: "
            "round x before writing the file"
        )
    return ""


def _exact_h(t: np.ndarray, h: float) -> float:
    """The float near ``h`` whose grid ``arange(N) * h`` reproduces ``t - t[0]``, else ``h``."""
    rel = t - t[0]
    k = np.arange(t.size)
    for c in (h, (t[-1] - t[0]) / (t.size - 1)):
        for direction in (np.inf, -np.inf):
            cc = c
            for _ in range(4):
                if np.array_equal(k * cc, rel):
                    return float(cc)
                cc = np.nextafter(cc, direction)
    return h


def record_from_fast(
    t: Any,
    x: Any,
    y: Any,
    r: Any = None,
    *,
    p: int | None = None,
    source: str = "array",
    labels: Mapping[str, str] | None = None,
    first_line: int | None = None,
) -> Record:
    """Check fast-rate arrays of one run and turn them into a :class:`~hbench.sim.records.Record`.

    Parameters
    ----------
    t : array_like, shape (N,)
        Time in seconds on a uniform grid (relative tolerance ``1e-6`` of the median step).
    x : array_like, shape (N,)
        Controller output at the fast rate, held over each slow period ``p h``.
    y : array_like, shape (N,)
        Measured output at the fast rate.
    r : array_like, shape (N,), optional
        Reference at the fast rate; its value at each period start becomes the slow sample.
    p : int, optional
        Fast-sampling ratio ``T / h``. Inferred from the changes of ``x`` when omitted.
    source : str
        Where the data come from, stored in ``Record.source``.
    labels : mapping, optional
        Names to use for ``t, x, y, r`` in messages (for instance ``{"x": "MV"}``).
    first_line : int, optional
        File line of row 0; messages then give ``line first_line + row`` beside the row.

    Returns
    -------
    Record
        One run: ``y`` of shape ``(1, K p)``, ``x`` and ``r`` of shape ``(1, K)``. ``meta`` holds
        ``notices`` (list of str), ``t0`` (time of the first kept row), ``trimmed`` (leading,
        trailing fast samples dropped), ``p_inferred`` and ``phase`` (first kept row).

    Raises
    ------
    RecordError
        Non-numeric, NaN or infinite values; fewer than 2 samples; a non-uniform ``t``; ``x`` not
        held over the given ``p``; ``p`` not inferable; fewer than 50 slow samples.
    """
    p = _check_p(p)
    lab = {"t": "t", "x": "x", "y": "y", "r": "r", **(labels or {})}

    def where(i: int) -> str:
        return f"row {i}" if first_line is None else f"row {i} (line {first_line + i})"

    cols: dict[str, np.ndarray] = {}
    for name, values in (("t", t), ("x", x), ("y", y), ("r", r)):
        if values is not None:
            cols[name] = _to_float(values, lab[name], where)
    n = cols["t"].size
    for name, arr in cols.items():
        if arr.size != n:
            raise RecordError(f"column '{lab[name]}' has {arr.size} samples but 't' has {n}")
    if n < 2:
        raise RecordError(f"the record has {n} sample(s); at least 2 are needed")
    for name, arr in cols.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.argmax(bad))
            what = "NaN (missing)" if np.isnan(arr[i]) else f"infinite ({arr[i]})"
            raise RecordError(f"column '{lab[name]}' is {what} at {where(i)}")

    tt, xx, yy, rr = cols["t"], cols["x"], cols["y"], cols.get("r")
    dt = np.diff(tt)
    h = float(np.median(dt))
    if not h > 0:
        raise RecordError(f"'{lab['t']}' does not increase (median step {h:g} s)")
    resolution = T_ULPS * float(np.spacing(np.max(np.abs(tt))))
    off = np.abs(dt - h) > max(T_RTOL * h, resolution)
    if resolution > 0.1 * T_RTOL * h:  # steps rounded to t's resolution: h from the span
        h = float((tt[-1] - tt[0]) / (n - 1))
    if off.any():
        i = int(np.argmax(off))
        raise RecordError(
            f"'{lab['t']}' is not uniform: the step from {where(i)} to row {i + 1} is "
            f"{dt[i]:.9g} s, {dt[i] - h:+.3g} s off the median step h = {h:.9g} s "
            f"(relative tolerance {T_RTOL:g}, or {resolution:.2g} s, the float resolution of "
            f"'{lab['t']}'); {int(off.sum())} of {dt.size} steps are off"
        )
    h = _exact_h(tt, h)

    notices: list[str] = []
    changes = np.flatnonzero(xx[1:] != xx[:-1]) + 1
    p_inferred = p is None
    if p is None:
        if changes.size < 2:
            what = (
                "never changes" if changes.size == 0 else f"changes only once ({where(changes[0])})"
            )
            raise RecordError(
                f"'{lab['x']}' {what}, so p cannot be inferred: pass --p (the ratio T / h of "
                "the control period to the sampling period)"
            )
        gaps = np.diff(changes)
        g = int(np.gcd.reduce(gaps))
        near = _near_grid(changes, gaps, g)
        if near is not None:
            P, ph = near
            stray = changes[changes % P != ph]
            raise RecordError(
                f"p cannot be inferred: '{lab['x']}' looks held over p = {P}, but "
                f"{stray.size} of its {changes.size} changes fall inside a hold (the first at "
                f"{where(int(stray[0]))}){_jitter_hint(xx, stray)}; fix x, or pass --p "
                "(--p 1 reads it without fast sampling)"
            )
        p = g
        phase = int(changes[0] % p)
        if p == 1:
            if changes.size == n - 1:
                notices.append("x changes at every sample: treated as p = 1, no fast sampling")
            else:
                notices.append(
                    "x is not held over any p > 1 (its changes lie on no common period grid): "
                    "treated as p = 1, no fast sampling"
                )
    else:
        if changes.size:
            phase = int(np.argmax(np.bincount(changes % p, minlength=p)))
        else:
            phase = 0
            notices.append(f"'{lab['x']}' is constant over the whole record")
        stray = changes[changes % p != phase]
        if stray.size:
            i = int(stray[0])
            k = (i - phase) // p
            a = max(phase + k * p, 0)
            b = min(phase + (k + 1) * p - 1, n - 1)
            period = "the leading partial period" if k < 0 else f"slow period {k}"
            raise RecordError(
                f"'{lab['x']}' is not held over p = {p}: it changes at {where(i)}, inside "
                f"{period} (rows {a}..{b}); {stray.size} of its {changes.size} changes fall "
                f"inside a period{_jitter_hint(xx, stray)}"
            )

    K = (n - phase) // p
    start, stop = phase, phase + K * p
    if K < MIN_SLOW_SAMPLES:
        kept = f" after trimming {n - K * p} to the period grid" if K * p != n else ""
        raise RecordError(
            f"the record has only {K} slow samples (p = {p}, {n} fast samples{kept}); "
            f"at least {MIN_SLOW_SAMPLES} are needed"
        )
    lead, trail = start, n - stop
    if lead or trail:
        parts = []
        if lead:
            parts.append(
                f"{lead} leading fast sample(s) (x's first full period starts at row {start})"
            )
        if trail:
            parts.append(f"{trail} trailing fast sample(s) (an incomplete last period)")
        notices.append(f"trimmed {' and '.join(parts)} to keep whole periods of p = {p}")

    ys = yy[start:stop]
    xs = xx[start:stop:p]
    rs = None
    if rr is not None:
        rs = rr[start:stop:p]
        if p > 1 and np.any(rr[start:stop].reshape(K, p) != rs[:, None]):
            notices.append(
                f"'{lab['r']}' varies inside slow periods: its value at each period start is used"
            )
    if np.all(ys == ys[0]):
        notices.append(f"'{lab['y']}' is constant ({ys[0]:.7g}): it carries no information")

    meta: dict[str, Any] = {
        "notices": notices,
        "t0": float(tt[start]),
        "trimmed": (lead, trail),
        "p_inferred": p_inferred,
        "phase": start,
    }
    return Record(
        y=ys[None, :],
        x=xs[None, :],
        r=None if rs is None else rs[None, :],
        p=p,
        h=h,
        source=source,
        meta=meta,
    )


@contextmanager
def _about(path: Path) -> Iterator[None]:
    """Prefix RecordErrors raised inside with the file name."""
    try:
        yield
    except RecordError as exc:
        raise RecordError(f"{path}: {exc}") from None


# --------------------------------------------------------------------------------- table reader


def _pandas_csv_kwargs() -> dict[str, Any]:
    """``float_precision="round_trip"`` where pandas' default float parser is not exact."""
    m = re.match(r"(\d+)\.(\d+)", pd.__version__)
    if m and (int(m[1]), int(m[2])) < (3, 1):
        return {"float_precision": "round_trip"}
    return {}


class TableReader:
    """CSV, TSV or Parquet with columns ``t, x, y`` and optional ``r`` (one row per fast sample).

    Extra columns are ignored; column names are stripped of surrounding blanks.
    """

    name = "table"
    description = ".csv, .tsv, .parquet or .pq with columns t, x, y[, r]"

    def can_read(self, path: Path | str) -> bool:
        """Whether ``path`` has a table suffix (``.csv``, ``.tsv``, ``.parquet``, ``.pq``)."""
        return Path(path).suffix.lower() in _TABLE_SUFFIXES

    def _frame(self, path: Path) -> pd.DataFrame:
        kind = _TABLE_SUFFIXES.get(path.suffix.lower())
        if kind is None:
            raise RecordError(f"not a table file (suffix {path.suffix!r})")
        try:
            if kind == "parquet":
                return pd.read_parquet(path)
            return pd.read_csv(
                path,
                sep="\t" if kind == "tsv" else ",",
                encoding="utf-8-sig",
                **_pandas_csv_kwargs(),
            )
        except (FileNotFoundError, IsADirectoryError, PermissionError):
            raise
        except pd.errors.EmptyDataError:
            raise RecordError("the file is empty") from None
        except UnicodeDecodeError as exc:
            raise RecordError(f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
        except Exception as exc:  # parser and Arrow errors come in many classes
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise RecordError(f"cannot read it as {kind.upper()}: {first}") from None

    def read(self, path: Path | str, p: int | None = None) -> Record:
        """Read a table record.

        Parameters
        ----------
        path : path-like
            The ``.csv``, ``.tsv``, ``.parquet`` or ``.pq`` file.
        p : int, optional
            Fast-sampling ratio; inferred from ``x`` when omitted.

        Returns
        -------
        Record
            One run; see :func:`record_from_fast`.
        """
        path = Path(path)
        with _about(path):
            df = self._frame(path)
            df.columns = [str(c).strip() for c in df.columns]
            missing = [c for c in ("t", "x", "y") if c not in df.columns]
            if missing:
                found = ", ".join(map(repr, df.columns)) or "none"
                names = ", ".join(f"'{c}'" for c in missing)
                raise RecordError(
                    f"missing column{'s' if len(missing) > 1 else ''} {names} (columns found: "
                    f"{found}); a record needs t, x, y and optionally r"
                )
            t, when = _seconds(df["t"])
            rec = record_from_fast(
                t,
                df["x"].to_numpy(),
                df["y"].to_numpy(),
                df["r"].to_numpy() if "r" in df.columns else None,
                p=p,
                source=str(path),
            )
        rec.meta["format"] = self.name
        if when:
            rec.meta["notices"].insert(0, when)
        return rec


def _seconds(t: pd.Series) -> tuple[np.ndarray, str]:
    """A ``t`` column in seconds, and a notice where it was converted: date-times (Parquet's
    timestamps, with or without a time zone) and durations become seconds since the first row
    (their nanoseconds are never taken for seconds)."""
    if pd.api.types.is_datetime64_any_dtype(t.dtype) or pd.api.types.is_timedelta64_dtype(t.dtype):
        if t.isna().any():
            i = int(np.argmax(t.isna().to_numpy()))
            raise RecordError(f"column 't' is missing (NaT) at row {i}")
        start = t.iloc[0]
        seconds = (t - start).dt.total_seconds().to_numpy()
        kind = "date-time" if pd.api.types.is_datetime64_any_dtype(t.dtype) else "duration"
        return seconds, f"'t' is a {kind} column: read as seconds since its first row ({start})"
    return t.to_numpy(), ""


# ----------------------------------------------------------------------------- plant-log reader


def _decode(raw: bytes) -> tuple[str, str]:
    """Text of a plant log and the encoding that decoded it."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16"), "utf-16"
    for enc in ("utf-8-sig", "gb18030"):
        try:
            return raw.decode(enc), "utf-8" if enc == "utf-8-sig" else enc
        except UnicodeDecodeError:
            continue
    return raw.decode("latin-1"), "latin-1"  # pragma: no cover - gb18030 decodes nearly anything


_JAVA_TIME = (("yyyy", "%Y"), ("MM", "%m"), ("dd", "%d"), ("HH", "%H"), ("mm", "%M"), ("ss", "%S"))


def _strptime_format(fmt: str) -> str | None:
    """``yyyy-MM-dd HH:mm:ss`` (the header's time format) as a ``strptime`` format."""
    out = fmt.strip()
    for java, c in _JAVA_TIME:
        out = out.replace(java, c)
    return out if re.fullmatch(r"[%YmdHMS\s:/.\-T]*", out) and "%" in out else None


def _parameters(line: str) -> dict[str, str]:
    """``key=value`` pairs of the undocumented 5th line (one separator is a stray ``t``)."""
    fields = re.split(r"\t|(?<=\d)t(?=[A-Za-z]\w*=)", line)
    return dict(f.split("=", 1) for f in fields if "=" in f)


class PlantLogReader:
    """Tab-separated historian logs with a ``PROCESSDATA`` header (``../shared/data/stictiongpt``).

    Layout: line 1 ``PROCESSDATA <tag> Data <time format>``; line 2 ``8 <Ts> <start> <n>``; line 3
    column names (``tagname <tag>.MV <tag>.PV <tag>.SV <tag>.MODE`` and flag columns ``b...OFL``);
    line 4 descriptions (``desc ...``); line 5 ``key=value`` parameters; then one row per sample.
    Lines 4 and 5 are recognised by content and may be absent.

    MV (controller output) becomes ``x``, PV ``y``, SV ``r``; ``p = 1`` unless given. ``t`` is
    built from ``Ts`` and the row order: the logged timestamps are checked, not used (some logs
    repeat one stamp and skip the next). ``meta`` holds ``tag``, ``Ts``, ``start``,
    ``time_format``, ``n_declared``, ``mode`` (count of each MODE value), ``flags`` (rows with each
    flag set), ``descriptions``, ``parameters`` and ``encoding``.
    """

    name = "plant-log"
    description = "tab-separated log starting with PROCESSDATA"

    def can_read(self, path: Path | str) -> bool:
        """Whether the file at ``path`` starts with ``PROCESSDATA``."""
        path = Path(path)
        if not path.is_file():
            return False
        with path.open("rb") as fh:
            head = fh.read(64)
        if head.startswith((b"\xff\xfe", b"\xfe\xff")):
            text = head[: len(head) // 2 * 2].decode("utf-16", errors="ignore")
        else:
            text = head.decode("utf-8", errors="ignore")
        return text.lstrip("\ufeff \t\r\n").startswith("PROCESSDATA")

    def read(self, path: Path | str, p: int | None = None) -> Record:
        """Read a plant log.

        Parameters
        ----------
        path : path-like
            The log file.
        p : int, optional
            Fast-sampling ratio; 1 (MV logged at the PV rate) when omitted.

        Returns
        -------
        Record
            One run; file-level notices (irregular timestamps, set flags, mode changes, a sample
            count that differs from the header) come first in ``meta["notices"]``.
        """
        path = Path(path)
        with _about(path):
            return self._read(path, 1 if p is None else p)

    def _read(self, path: Path, p: int) -> Record:
        text, encoding = _decode(path.read_bytes())
        lines = text.splitlines()
        while lines and not lines[-1].strip():
            lines.pop()
        if len(lines) < 4:
            raise RecordError(
                f"a plant log needs a 3-line header and data; found {len(lines)} lines"
            )

        head1 = lines[0].split("\t")
        m = re.match(r"(.*?)\s+Data\s*$", head1[1]) if len(head1) > 1 else None
        tag = (m[1] if m else head1[1] if len(head1) > 1 else "").strip()
        time_format = head1[2].strip() if len(head1) > 2 else ""

        head2 = lines[1].split("\t")
        try:
            Ts = float(head2[1])
        except (IndexError, ValueError):
            Ts = math.nan
        if not (math.isfinite(Ts) and Ts > 0):
            got = repr(head2[1]) if len(head2) > 1 else "nothing"
            raise RecordError(
                f"line 2 should give the sampling period Ts > 0 in seconds, got {got}"
            )
        start = head2[2].strip() if len(head2) > 2 else ""
        try:
            n_declared: int | None = int(head2[3])
        except (IndexError, ValueError):
            n_declared = None

        names = [c.strip() for c in lines[2].split("\t")]

        def column(kind: str, required: bool) -> int | None:
            hits = [i for i, c in enumerate(names) if c == f"{tag}.{kind}"]
            hits = hits or [i for i, c in enumerate(names) if c.upper().endswith(f".{kind}")]
            if not hits and required:
                raise RecordError(
                    f"line 3 has no {kind} column (columns found: {', '.join(names)})"
                )
            return hits[0] if hits else None

        i_mv, i_pv = column("MV", True), column("PV", True)
        i_sv, i_mode = column("SV", False), column("MODE", False)
        i_flags = [i for i, c in enumerate(names) if re.fullmatch(r"b\w*OFL", c)]

        first = 3
        descriptions: dict[str, str] = {}
        parameters: dict[str, str] = {}
        if first < len(lines) and lines[first].split("\t")[0].strip().lower() == "desc":
            desc = lines[first].split("\t")
            for key, i in (("MV", i_mv), ("PV", i_pv), ("SV", i_sv), ("MODE", i_mode)):
                if i is not None and i < len(desc):
                    descriptions[key] = desc[i].strip()
            first += 1
        if first < len(lines) and "=" in lines[first].split("\t")[0]:
            parameters = _parameters(lines[first])
            first += 1

        rows = [ln.split("\t") for ln in lines[first:]]
        width = 1 + max(i for i in (i_mv, i_pv, i_sv, i_mode) if i is not None)
        for j, row in enumerate(rows):
            if len(row) < width:
                cut = "; the file ends inside it (truncated?)" if j == len(rows) - 1 else ""
                raise RecordError(
                    f"line {first + 1 + j} has {len(row)} field(s); the first {width} of the "
                    f"{len(names)} columns are needed ({', '.join(names[:width])}){cut}"
                )

        def col(i: int) -> list[str]:
            return [row[i].strip() if i < len(row) else "" for row in rows]

        notices: list[str] = []
        n = len(rows)
        if n_declared is not None and n_declared != n:
            notices.append(f"the header announces {n_declared} samples; the file has {n} rows")
        notices += self._check_stamps(col(0), time_format, start, Ts, first + 1)

        mode = dict(Counter(col(i_mode))) if i_mode is not None else {}
        if len(mode) > 1:
            notices.append(
                "MODE changes during the record ("
                + ", ".join(f"{k}: {v} rows" for k, v in mode.items())
                + "): the loop was not in one mode throughout"
            )
        flags = {names[i]: sum(v not in ("0", "") for v in col(i)) for i in i_flags}
        if any(flags.values()):
            set_ = [[v not in ("0", "") for v in col(i)] for i in i_flags]
            n_flagged = int(np.any(set_, axis=0).sum())
            notices.append(
                f"{n_flagged} rows carry a set flag ("
                + ", ".join(f"{k} {v}" for k, v in flags.items() if v)
                + "); their values are kept as logged"
            )

        rec = record_from_fast(
            np.arange(n) * Ts,
            col(i_mv),
            col(i_pv),
            col(i_sv) if i_sv is not None else None,
            p=p,
            source=str(path),
            labels={"x": "MV", "y": "PV", "r": "SV", "t": "t"},
            first_line=first + 1,
        )
        meta = {
            **rec.meta,
            "notices": notices + rec.meta["notices"],
            "format": self.name,
            "tag": tag,
            "Ts": Ts,
            "start": start,
            "time_format": time_format,
            "n_declared": n_declared,
            "mode": mode,
            "flags": flags,
            "descriptions": descriptions,
            "parameters": parameters,
            "encoding": encoding,
        }
        return replace(rec, meta=meta)

    @staticmethod
    def _check_stamps(
        stamps: list[str], time_format: str, start: str, Ts: float, line0: int
    ) -> list[str]:
        """Notices about timestamps that disagree with ``start + k Ts``."""
        fmt = _strptime_format(time_format) or "%Y-%m-%d %H:%M:%S"
        try:
            when = [datetime.strptime(s, fmt) for s in stamps]
        except ValueError:
            return [f"timestamps do not follow {time_format!r}: not checked; t is built from Ts"]
        notices = []
        try:
            if start and when and datetime.strptime(start, fmt) != when[0]:
                notices.append(f"the first row is stamped {stamps[0]}, the header says {start}")
        except ValueError:
            pass
        steps = np.array([(b - a).total_seconds() for a, b in pairwise(when)])
        off = np.flatnonzero(steps != Ts)
        if off.size:
            i = int(off[0])
            kinds = Counter(steps[off])
            notices.append(
                f"timestamps are irregular at {off.size} step(s) ("
                + ", ".join(f"{c} of {s:g} s" for s, c in sorted(kinds.items()))
                + f"; the first from line {line0 + i} to {line0 + i + 1}: {stamps[i]} -> "
                f"{stamps[i + 1]}); t is built from Ts = {Ts:g} s and the row order"
            )
        return notices


# ------------------------------------------------------------------------------ read and write


def _describe(reader: Any) -> str:
    desc = getattr(reader, "description", "")
    return f"{reader.name} ({desc})" if desc else str(reader.name)


def read_record(
    path: Path | str, p: int | None = None, readers: Sequence[Reader] | None = None
) -> Record:
    """Read a record with the first reader that recognises the file.

    Parameters
    ----------
    path : path-like
        The record file.
    p : int, optional
        Fast-sampling ratio ``T / h``; each reader has its default (the table reader infers it).
    readers : sequence of Reader, optional
        Readers to try in order; :data:`READERS` when omitted.

    Returns
    -------
    Record
        The record, with notices in ``meta["notices"]``.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    RecordError
        No reader recognises the file, or the reader refuses it.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(path))
    if path.is_dir():
        raise RecordError(f"{path}: is a directory, not a record file")
    readers = READERS if readers is None else readers
    for reader in readers:
        if reader.can_read(path):
            return reader.read(path, p=p)
    formats = "; ".join(_describe(r) for r in readers) or "none"
    raise RecordError(f"{path}: unsupported record format; supported: {formats}")


def writable_kind(path: Path | str) -> str:
    """The table kind :func:`write_record` writes at ``path`` (``csv``, ``tsv`` or ``parquet``).

    Raises
    ------
    RecordError
        For a suffix it cannot write, naming those it can (callers check before any work).
    """
    path = Path(path)
    kind = _TABLE_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise RecordError(
            f"{path}: cannot write a record as {path.suffix or 'a file without suffix'!r}; "
            f"use {', '.join(_TABLE_SUFFIXES)}"
        )
    return kind


def write_record(record: Record, path: Path | str) -> Path:
    """Write a one-run record as a table (``t, x, y`` and ``r`` if present) at the fast rate.

    ``x`` and ``r`` are held over each slow period. Floats are written at full precision (the
    shortest repr), so :func:`read_record` gives back the same ``y, x, r, p, h``, provided ``x``
    changes at least once between two slow periods whose gcd is ``p`` (it always does for a
    record with ``x`` changing every period).

    Parameters
    ----------
    record : Record
        A record with one run and ``x`` present.
    path : path-like
        ``.csv``, ``.tsv``, ``.parquet`` or ``.pq``.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    kind = writable_kind(path)
    if record.runs != 1:
        raise RecordError(
            f"write_record writes one run, the record has {record.runs}: use record.select([i])"
        )
    if record.x is None:
        raise RecordError("write_record needs x (the record's x is withheld)")
    data = {"t": record.t, "x": record.hold(record.x[0]), "y": record.y[0]}
    if record.r is not None:
        data["r"] = record.hold(record.r[0])
    df = pd.DataFrame(data)
    with atomic.replacing(path) as tmp:  # whole or not at all
        if kind == "parquet":
            df.to_parquet(tmp, index=False)
        else:
            df.to_csv(
                tmp,
                sep="\t" if kind == "tsv" else ",",
                index=False,
                float_format=lambda v: repr(float(v)),
            )
    return path


#: Built-in readers in detection order.
READERS: tuple[Reader, ...] = (PlantLogReader(), TableReader())
