"""The ``diagnose`` command's body (imported only when the command runs)."""

from __future__ import annotations

import argparse
import json
import sys
import warnings

import numpy as np

from hbench.errors import InputError, tell
from hbench.system import atomic

#: The longest record diagnosed, in fast samples. The diagnosis holds ~6 KB per fast sample at
#: its peak and its time grows with the length (200 000 samples: 1.3 GB, 17 s), so a longer
#: record is refused as soon as it is read (a window of it can be diagnosed).
MAX_SAMPLES = 250_000


def _summary(d) -> str:
    fired = [x.name for x in d.detections if x.fired]
    lines = [
        *d.findings(),
        f"record: {d.source} (p = {d.ctx.p}, h = {d.ctx.h:g} s, {d.ctx.K} slow samples; fit on "
        f"the first {d.ctx.k_fit}, validate on the last {d.ctx.K - d.ctx.k_fit})",
        "effects detected: " + (", ".join(fired) if fired else "none"),
    ]
    return "\n".join(lines)


def _shows_progress(setting: str) -> bool:
    """Whether ``--progress`` (``on``, ``off``, ``auto``: when stderr is a terminal) shows the
    progress lines."""
    if setting == "auto":
        try:
            return sys.stderr.isatty()
        except (AttributeError, ValueError):  # a replaced or closed stderr
            return False
    return setting == "on"


def _progress(text: str) -> None:
    """A progress line on stderr (advisory: a closed stderr never stops the diagnosis)."""
    tell(f"[hbench diagnose] {text}")


def _print_notices(notices: list[str]) -> None:
    """Print the record reader's notices on stderr, one a line.

    Parameters
    ----------
    notices : list of str
        Lines already prefixed with ``"notice: "``.
    """
    for line in notices:
        print(line, file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """``hbench diagnose``: read the record, diagnose it, print and write the results.

    The five-line summary goes to stdout, or to stderr when ``--json -`` puts the JSON on
    stdout (which then holds nothing else); a progress line per step goes to stderr as
    ``--progress`` says (by default when stderr is a terminal, so that a script's stderr holds
    an error's one line alone). Output paths are checked before the work. The
    reader's notices go to stderr once the diagnosis has accepted the record: a refused record
    gives its one error line only.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (``record, p, json, out, method, fit_fraction,
        delay_multiple, criterion, rule, controller, progress``).

    Returns
    -------
    int
        The exit status, 0.

    Raises
    ------
    InputError
        A bad record, option or output path.
    """
    from hbench.diagnose.validate import diagnose, parse_criterion
    from hbench.io.readers import read_record
    from hbench.plugins import registry
    from hbench.system.writable import check_output

    to_stdout = args.json == "-"
    info = sys.stderr if to_stdout else sys.stdout  # the human text: never mixed into the JSON
    json_path = check_output(args.json, "--json") if args.json and not to_stdout else None
    out_dir = check_output(args.out, "--out", folder=True) if args.out else None
    if args.p is not None and args.p < 1:
        raise InputError(f"--p must be a positive integer, got {args.p}")
    if args.delay_multiple < 0:
        raise InputError(f"--delay-multiple must be >= 0, got {args.delay_multiple}")
    if not 0.2 <= args.fit_fraction <= 0.9:
        raise InputError(f"--fit-fraction must lie in [0.2, 0.9], got {args.fit_fraction:g}")
    parse_criterion(getattr(args, "criterion", "auto"))  # a bad --criterion: before the work
    reg = registry()
    readers = [reg.get("readers", n) for n in reg.names("readers")] or None
    record = read_record(args.record, p=args.p, readers=readers)
    if record.n_fast > MAX_SAMPLES:
        raise InputError(
            f"{args.record}: {record.n_fast} fast samples, more than the {MAX_SAMPLES} that "
            f"diagnose takes (~6 KB of memory each at its peak): diagnose a window of the record "
            "(its rows in a file of their own)"
        )
    if args.method not in reg.names("identifiers"):
        known = ", ".join(reg.names("identifiers"))
        raise InputError(f"unknown method {args.method!r} (known: {known})")
    notices = [f"notice: {n}" for n in record.meta.get("notices", [])]
    try:
        # warnings are held until the diagnosis ends: a refused record gets its one error line
        with np.errstate(all="ignore"), warnings.catch_warnings(record=True) as held:
            d = diagnose(
                record,
                source=str(args.record),
                method=args.method,
                fit_fraction=args.fit_fraction,
                delay_multiple=args.delay_multiple,
                criterion=getattr(args, "criterion", "auto"),
                rule=getattr(args, "rule", "auto"),
                controller=getattr(args, "controller", "auto"),
                progress=_progress if _shows_progress(getattr(args, "progress", "auto")) else None,
            )
    except InputError:
        # a refused record: its one error line alone (a notice such as "'y' is constant" would
        # be a second line that the error repeats, a warning a symptom of the same cause)
        raise
    except Exception:
        _print_notices(notices)  # an internal failure: the notices may help explain it
        raise
    for w in held:  # an accepted record's warnings, shown as the command shows any
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    _print_notices(notices)  # an accepted record's notices, before its summary
    out = d.as_json()
    print(_summary(d), file=info)
    if args.json:
        text = json.dumps(out, indent=2)
        if json_path is None:
            print(text)
        else:
            json_path.parent.mkdir(parents=True, exist_ok=True)
            atomic.write_text(json_path, text + "\n")
            print(f"wrote {json_path}", file=info)
    if out_dir is not None:
        from hbench.diagnose.report import write_report

        html, md = write_report(d, out_dir)
        print(f"wrote {html} and {md}", file=info)
    return 0
