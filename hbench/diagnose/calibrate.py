"""Calibration and scoring of the detectors on synthetic records (``python -m
hbench.diagnose.calibrate``), of the stiction verdict on synthetic plant loops (``.. loops``) and
on the real plant records (``.. real FOLDER``), and of the literature's OP-PV pattern tests on the
synthetic plant loops (``.. patterns``).

``--effect none --start 5000 --n 200`` prints every detector's statistic on nominal records
(its largest values set the thresholds in :mod:`hbench.diagnose.effects`); any other effect
prints the detection rate and the cause found. Records come from
:mod:`hbench.diagnose.generator`; the seeds used to calibrate (5000-5199 nominal, 6000-6199 with
effects) are kept apart from the seeds the tests score. Seeds 8000-8199 and 8500-8709 (and the
paper-example seeds 700-705) were used once, to check the noise-model null of
:mod:`hbench.diagnose.null` (``docs/experiments/noise-model-null.md``); a new check needs fresh
ones.
"""

from __future__ import annotations

import argparse
import collections
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any, TypeVar

import numpy as np

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import generator as gen
from hbench.diagnose import noise_oracle
from hbench.errors import tell
from hbench.system import runtime

T = TypeVar("T")
R = TypeVar("R")


#: Criteria whose fits :func:`run_case` records beside the diagnosis's own (horizons in fast
#: samples), so that the cause rule can be compared across criteria on the same records.
COMPARED_HORIZONS: tuple[int, ...] = (0, 5, 10, 20, 40)


#: Options of :func:`run_case` set by ``bench``: ``extend_all`` fits every extension, so that
#: cause rules can be compared offline on the same records; ``method`` is the nominal's blind
#: method; ``rule`` and ``criterion`` as ``hbench diagnose``'s options. (Module state read by
#: the worker processes, which fork after it is set.)
OPTIONS: dict[str, Any] = {
    "extend_all": False,
    "method": "wang-lsm",
    "rule": "auto",
    "criterion": "auto",
}


def run_case(case: gen.Case | bc.BenchCase) -> dict[str, Any]:
    """Diagnose the record of ``case`` (a design case of :mod:`hbench.diagnose.generator` or a
    benchmark case of :mod:`hbench.diagnose.benchmark_cases`) in memory; a row of plain data."""
    from hbench.diagnose.validate import Criterion, diagnose, half_gains

    if isinstance(case, bc.BenchCase):
        rec, plant = bc.simulate_bench_case(case), case.plant
    else:
        rec, plant = gen.simulate_case(case), case.plant["name"]
    row: dict[str, Any] = {
        "seed": case.seed,
        "effect": case.effect,
        "cls": case.cls,
        "plant": plant,
        "p": case.p,
    }
    if isinstance(case, bc.BenchCase) and case.effect == "colored-noise":
        row["noise_shape_power"] = {
            null: noise_oracle.noise_shape_power(case, null=null) for null in noise_oracle.NULLS
        }
    try:
        d = diagnose(
            rec,
            source=case.name,
            also=tuple(Criterion(k) for k in COMPARED_HORIZONS),
            extend_all=OPTIONS["extend_all"],
            method=OPTIONS["method"],
            rule=OPTIONS["rule"],
            criterion=OPTIONS["criterion"],
        )
    except Exception as exc:
        row.update(cause="error", found_cls="error", error=f"{type(exc).__name__}: {exc}")
        return row
    nl = d.nonlinearity
    row.update(
        cause=d.cause,
        found_cls=nl["class"],
        baseline=d.baseline_fit,
        extended=d.extended_fit,
        gain=d.gain,
        criterion=d.criterion,
        margin=nl["margin"],
        confident=nl["confident"],
        seconds=d.seconds,
        stats={x.name: x.statistic for x in d.detections},
        fired=[x.name for x in d.detections if x.fired],
        ext={k: v.val_fit - d.baseline_fit for k, v in d.extensions.items()},
        ext_halves={k: half_gains(v, d.baseline_halves) for k, v in d.extensions.items()},
        fits={"nominal": d.fits["nominal"], **{k: v.fits for k, v in d.extensions.items()}},
        p_values={x.name: x.p_value for x in d.detections},
        thresholds={x.name: x.threshold for x in d.detections},
        margin_scores=nl["scores"],
    )
    return row


def parallel_map(
    fn: Callable[[T], R],
    items: Sequence[T],
    jobs: int = 1,
    *,
    on_result: Callable[[int, int, R], None] | None = None,
) -> list[R]:
    """``[fn(item) for item in items]`` (in order), on ``jobs`` processes, every call with one
    BLAS thread: in this process under :func:`hbench.system.runtime.one_blas_thread`
    (restored on return), in the workers of :func:`hbench.bench.parallel.pool` (one thread
    for their life). A multi-threaded BLAS sums in another order on another thread count, so
    without the pin a row's last digits (and a score near a level, its verdict) would depend
    on the machine's cores and on ``jobs``. ``on_result(done, total, result)`` (progress) is
    called in this process for each result in input order, once it and every earlier one are
    in; an exception it raises stops the run (the rows computed so far are not returned)."""
    out: list[R] = []

    def keep(result: R) -> None:
        out.append(result)
        if on_result is not None:
            on_result(len(out), len(items), result)

    if jobs <= 1:
        with runtime.one_blas_thread():
            for item in items:
                keep(fn(item))
        return out
    from hbench.bench import parallel

    with parallel.pool(jobs) as pool:
        for result in pool.map(fn, items, chunksize=1):
            keep(result)
    return out


def say_row(done: int, total: int, row: dict[str, Any]) -> None:
    """A progress line on stderr for a diagnosed record (:func:`run_case`'s row)."""
    what = row.get("error") or (
        f"class {row.get('found_cls')}, cause {row.get('cause')} "
        f"({row.get('seconds', float('nan')):.1f} s)"
    )
    tell(
        f"[calibrate {done}/{total}] seed {row['seed']} {row['plant']} p={row['p']} "
        f"{row['cls']} / {row['effect']}: {what}"
    )


def run(
    cases: Sequence[gen.Case | bc.BenchCase], jobs: int = 1, progress: bool = False
) -> list[dict[str, Any]]:
    """Rows for ``cases`` (in order), on ``jobs`` processes; ``progress``: a line on stderr
    per record (:func:`say_row`)."""
    return parallel_map(run_case, cases, jobs, on_result=say_row if progress else None)


def rate(k: int, n: int, level: float = 0.95) -> str:
    """``k / n (p %, 95 % interval lo-hi %)``: the share with its ``level`` Wilson score
    interval (``scipy.stats.binomtest``), the records taken as independent draws (each has
    its own seed); ``k / n`` alone when ``n`` is 0."""
    if n <= 0:
        return f"{k} / {n}"
    from scipy.stats import binomtest

    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=level, method="wilson")
    return (
        f"{k} / {n} ({100 * k / n:.0f} %, {100 * level:g} % interval "
        f"{100 * ci.low:.0f}-{100 * ci.high:.0f} %)"
    )


def confusion(
    rows: Iterable[dict[str, Any]], true_key: str, found_key: str, labels: Sequence[str]
) -> str:
    """A text confusion matrix (rows: truth, columns: found)."""
    rows = list(rows)
    found_labels = list(labels) + sorted({r[found_key] for r in rows} - set(labels))
    counts = collections.Counter((r[true_key], r[found_key]) for r in rows)
    w = max(len(s) for s in [*labels, *found_labels, "true \\ found"]) + 1
    lines = ["true \\ found".ljust(w) + "".join(f[:12].rjust(13) for f in found_labels)]
    for t in labels:
        if not any(r[true_key] == t for r in rows):
            continue
        lines.append(t.ljust(w) + "".join(str(counts[(t, f)]).rjust(13) for f in found_labels))
    ok = sum(counts[(t, t)] for t in labels)
    lines.append(f"correct: {rate(ok, len(rows))}")
    return "\n".join(lines)


def cause_label(effect: str) -> str:
    return "none" if effect == "none" else effect


def report(rows: list[dict[str, Any]]) -> str:
    """Both confusion matrices and the gains; each share with its 95 % interval (:func:`rate`)."""
    for r in rows:
        r["true_cause"] = cause_label(r["effect"])
    out = [
        "cause (true vs found):",
        confusion(rows, "true_cause", "cause", ["none", *gen.EFFECTS[1:]]),
        "",
        "nonlinearity class (true vs found):",
        confusion(rows, "cls", "found_cls", list(gen.CLASSES)),
    ]
    hidden = [r for r in rows if r["effect"] != "none" and "gain" in r]
    if hidden:
        pos = sum(r["gain"] > 0 for r in hidden)
        out.append(f"\ngain > 0 on {rate(pos, len(hidden))} of the records with a hidden effect")
    nominal = [r for r in rows if r["effect"] == "none"]
    if nominal:
        named = sum(r["cause"] != "none" for r in nominal)
        out.append(f"records without an effect given a cause: {rate(named, len(nominal))}")
    sure = [r for r in rows if r.get("confident")]
    if sure:
        right = sum(r["found_cls"] == r["cls"] for r in sure)
        out.append(
            f"valve class where the diagnosis is confident: right on {rate(right, len(sure))} "
            f"({len(rows) - len(sure)} records not confident)"
        )
    secs = [r["seconds"] for r in rows if r.get("seconds")]
    if secs:
        out.append(f"seconds per record: median {np.median(secs):.2f}, max {np.max(secs):.2f}")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m hbench.diagnose.calibrate", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--effect", default="all", help="an effect, 'none', or 'all' (balanced)")
    ap.add_argument("--start", type=int, default=6000)
    ap.add_argument("--n", type=int, default=35)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args(argv)
    if args.effect == "all":
        cases = gen.balanced_cases(args.n, args.start)
    else:
        cases = [
            gen.draw_case(args.start + i, args.effect, gen.CLASSES[i % len(gen.CLASSES)])
            for i in range(args.n)
        ]
    rows = run(cases, args.jobs, progress=True)
    for r in rows:
        if args.verbose or r["cause"] != cause_label(r["effect"]) or r["found_cls"] != r["cls"]:
            stats = " ".join(
                f"{k}={v:.3g}{'*' if k in r.get('fired', []) else ''}"
                for k, v in r.get("stats", {}).items()
            )
            ext = " ".join(f"{k}={v:+.1f}" for k, v in r.get("ext", {}).items())
            print(
                f"{r['seed']:5d} {r['effect']:13s} {r['cls']:10s} {r['plant']:12s} -> "
                f"{r['cause']:13s} {r['found_cls']:10s} base {r.get('baseline', 0):6.1f} "
                f"gain {r.get('gain', 0):6.1f} | {stats} | ext {ext} {r.get('error', '')}"
            )
    names = sorted({k for r in rows for k in r.get("stats", {})})
    print("\nstatistic quantiles (50 / 90 / 99 / max):")
    for n in names:
        v = np.array([r["stats"][n] for r in rows if "stats" in r])
        print(f"  {n:14s} " + " ".join(f"{q:10.4g}" for q in np.percentile(v, [50, 90, 99, 100])))
    print()
    print(report(rows))
    return 0


# --------------------------------------------------------------------------- real plant data


def stictiongpt_index(folder: Any) -> list[dict[str, str]]:
    """Rows of ``INDEX.csv`` of the StictionGPT records (``file, label, split, loop_tag, ..``)."""
    import csv
    from pathlib import Path

    with (Path(folder) / "INDEX.csv").open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def diagnose_cli(path: Any, *options: str) -> dict[str, Any]:
    """``hbench diagnose path --json ... *options`` through the command line, in this process
    (its output swallowed); the JSON with ``status`` 0, or the exit status and the last line of
    the message for a refused record."""
    import contextlib
    import io
    import json
    import tempfile
    from pathlib import Path

    from hbench import cli

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "d.json"
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            status = cli.main(["diagnose", str(path), "--json", str(out), *options])
        if status != 0:
            return {"status": status, "message": err.getvalue().strip().splitlines()[-1]}
        return {"status": 0, **json.loads(out.read_text())}


def run_plant_log(path: Any) -> dict[str, Any]:
    """``hbench diagnose`` on one plant log through the command line (:func:`diagnose_cli`)."""
    # only the valve class is scored, which no cause rule changes: the cheaper rule
    return diagnose_cli(path, "--rule", "detectors")


def score_stictiongpt(
    folder: Any, splits: Sequence[str] = ("development", "evaluation"), jobs: int = 1
) -> list[dict[str, Any]]:
    """The stiction verdict (class ``stiction`` or not) on every record of ``splits``, and the
    classical baselines' verdicts on the same records (:func:`score_baselines`): every row's
    ``verdicts`` maps ``hbench`` and each baseline to its verdict."""
    from pathlib import Path

    rows = [r for r in stictiongpt_index(folder) if r["split"] in splits]
    paths = [Path(folder) / r["file"] for r in rows]
    results = parallel_map(run_plant_log, paths, jobs)
    out = []
    for r, res in zip(rows, results, strict=True):
        cls = res.get("nonlinearity", {}).get("class") if res["status"] == 0 else None
        verdict = "stiction" if cls == "stiction" else "no-stiction"
        out.append(
            {
                **r,
                "status": res["status"],
                "class": cls,
                "verdict": verdict,
                "correct": res["status"] == 0 and verdict == r["label"],
                "message": res.get("message", ""),
                "scores": res.get("nonlinearity", {}).get("scores", {}),
                "cause": res.get("cause"),
                "verdicts": {"hbench": verdict if res["status"] == 0 else REFUSED},
            }
        )
    return score_baselines(folder, out)


#: The verdict of a detector on a record it cannot read (counted wrong).
REFUSED = "refused"


def run_baselines(path: Any) -> tuple[dict[str, Any], str]:
    """The classical detectors' verdicts (:func:`hbench.diagnose.baselines.verdicts`) on one
    plant log, by name, and ``""``; no verdicts and the reason for a log the reader refuses."""
    from hbench.diagnose import baselines
    from hbench.errors import InputError
    from hbench.io.readers import read_record

    try:
        rec = read_record(path)
    except (InputError, OSError) as exc:
        return {}, str(exc)
    return dict(baselines.verdicts(rec.x[0], rec.y[0])), ""


def score_baselines(folder: Any, rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` (of ``INDEX.csv``) with the classical baselines run on each record: the
    verdict of each (``stiction``, ``no-stiction``, ``undetermined``, or ``refused`` for a log
    the reader refuses) added to ``verdicts``, the full answers (statistic, reason) under
    ``baselines`` and the reader's reason for a refusal under ``baseline_message``."""
    from pathlib import Path

    from hbench.diagnose import baselines

    out = []
    answers = parallel_map(run_baselines, [Path(folder) / r["file"] for r in rows])
    for r, (found, message) in zip(rows, answers, strict=True):
        verdicts = dict(r.get("verdicts", {}))
        for name in baselines.DETECTORS:
            verdicts[name] = found[name].verdict if name in found else REFUSED
        out.append({**r, "verdicts": verdicts, "baselines": found, "baseline_message": message})
    return out


def accuracy(rows: Sequence[dict[str, Any]], split: str, refused: str = "wrong") -> tuple[int, int]:
    """``(correct, total)`` on ``split``; a refused record (exit 2) counts as wrong, or is left
    out with ``refused="skip"``."""
    sel = [r for r in rows if r["split"] == split and (refused == "wrong" or r["status"] == 0)]
    return sum(r["correct"] for r in sel), len(sel)


def accuracy_interval(
    rows: Sequence[dict[str, Any]],
    split: str,
    level: float = 0.95,
    n_boot: int = 10_000,
    seed: int = 0,
) -> tuple[float, float]:
    """A ``level`` percentile interval of the accuracy on ``split`` (refused records wrong),
    resampling whole loops (``loop_tag``) with replacement: records of one loop are not
    independent (several are windows of one valve), so loops are the sampling unit.

    ``n_boot`` resamples from ``numpy.random.default_rng(seed)``; returns percentages.
    """
    sel = [r for r in rows if r["split"] == split]
    if not sel:
        return float("nan"), float("nan")
    loops = sorted({r["loop_tag"] for r in sel})
    right = np.array([sum(r["correct"] for r in sel if r["loop_tag"] == t) for t in loops], float)
    count = np.array([sum(1 for r in sel if r["loop_tag"] == t) for t in loops], float)
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(loops), size=(n_boot, len(loops)))
    acc = 100.0 * right[pick].sum(axis=1) / count[pick].sum(axis=1)
    lo, hi = np.percentile(acc, [50 * (1 - level), 50 * (1 + level)])
    return float(lo), float(hi)


#: The measures of :func:`detector_rates`, each with the label of the records it is taken on
#: (``None``: all records).
MEASURES: dict[str, str | None] = {
    "accuracy": None,
    "sensitivity": "stiction",
    "specificity": "no-stiction",
}


def detector_rates(
    rows: Sequence[dict[str, Any]], split: str, detector: str
) -> dict[str, tuple[int, int, float, float]]:
    """Accuracy, sensitivity (records labelled stiction called stiction) and specificity
    (records labelled no-stiction called no-stiction) of ``detector``'s verdicts
    (``row["verdicts"][detector]``) on ``split``, each as ``(right, records, lo, hi)`` with
    ``lo-hi`` the 95 % interval over loops of :func:`accuracy_interval`. A refused record and
    an undetermined verdict count as wrong."""
    out = {}
    for measure, label in MEASURES.items():
        sel = [
            {
                "split": split,
                "loop_tag": r["loop_tag"],
                "status": 0,
                "correct": r["verdicts"][detector] == r["label"],
            }
            for r in rows
            if r["split"] == split and label in (None, r["label"])
        ]
        lo, hi = accuracy_interval(sel, split)
        out[measure] = (*accuracy(sel, split), lo, hi)
    return out


def detector_table(rows: Sequence[dict[str, Any]], splits: Sequence[str]) -> str:
    """The text table of :func:`detector_rates` for every detector in the rows' ``verdicts``
    (hbench first, then the baselines) on each split, with the count of undetermined verdicts."""
    detectors = list(rows[0]["verdicts"]) if rows else []
    head = f"{'split':12s}{'detector':9s}" + "".join(f"{m:>24s}" for m in MEASURES)
    lines = [head + f"{'undetermined':>14s}"]
    for split in splits:
        for d in detectors:
            cells = []
            for k, n, lo, hi in detector_rates(rows, split, d).values():
                cells.append(
                    f"{k}/{n} = {100 * k / n:3.0f} % ({lo:3.0f}-{hi:3.0f})" if n else "n/a: none"
                )
            und = sum(r["verdicts"][d] == "undetermined" for r in rows if r["split"] == split)
            lines.append(f"{split:12s}{d:9s}" + "".join(f"{c:>24s}" for c in cells) + f"{und:14d}")
    return "\n".join(lines)


def main_real(argv: Sequence[str] | None = None) -> int:
    """``python -m hbench.diagnose.calibrate real FOLDER [--split S] [--jobs J]``: hbench's
    stiction verdict on every record, its accuracy per split, and the table of
    :func:`detector_table`: hbench beside the classical baselines
    (:mod:`hbench.diagnose.baselines`) on the same records."""
    ap = argparse.ArgumentParser(prog="python -m hbench.diagnose.calibrate real")
    ap.add_argument("folder")
    ap.add_argument("--split", action="append", default=None)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    splits = tuple(args.split or ("development", "evaluation"))
    rows = score_stictiongpt(args.folder, splits, args.jobs)
    for r in rows:
        sc = " ".join(f"{k[:4]}={v:.1f}" for k, v in r["scores"].items())
        base = " ".join(f"{k}={v.verdict} ({v.why})" for k, v in r["baselines"].items())
        print(
            f"{r['split'][:4]} {'ok ' if r['correct'] else 'BAD'} {r['label']:12s} "
            f"{r['class']!s:10s} {r['loop_tag'][:24]:24s} {sc} | {base} "
            f"{r['message']} {r['baseline_message']}"
        )
    for split in splits:
        c, n = accuracy(rows, split)
        c2, n2 = accuracy(rows, split, "skip")
        lo, hi = accuracy_interval(rows, split)
        print(
            f"{split}: {c}/{n} = {100 * c / max(n, 1):.1f} % (refused records counted wrong; "
            f"95 % interval over loops {lo:.0f}-{hi:.0f} %); "
            f"{c2}/{n2} = {100 * c2 / max(n2, 1):.1f} % without them"
        )
    print(
        "\nhbench's stiction verdict beside the classical baselines (hbench.diagnose.baselines: "
        "Horch's cross-correlation test, He et al.'s curve-fitting index, published limits; a "
        "loop whose controller output does not oscillate regularly, Thornhill's r <= 1, is "
        "no-stiction for both; refused records and undetermined verdicts count as wrong; "
        "95 % intervals over loops):"
    )
    print(detector_table(rows, splits))
    return 0


# --------------------------------------------------------------------------- synthetic plant loops


def run_loop(case: gen.LoopCase) -> dict[str, Any]:
    """Diagnose the plant-log-like record of ``case`` (``p = 1``) in memory; the stiction
    verdict against the truth."""
    from hbench.diagnose.validate import diagnose

    rec = gen.simulate_loop(case)
    row: dict[str, Any] = {
        "seed": case.seed,
        "name": case.name,
        "loop": case.loop,
        "cls": case.cls,
        "disturbance": case.disturbance,
    }
    try:
        d = diagnose(rec, source=case.name, rule="detectors")  # the class alone is scored
        row["found_cls"] = d.nonlinearity["class"]
    except Exception as exc:
        row["found_cls"] = f"error: {type(exc).__name__}: {exc}"
    row["error"] = str(row["found_cls"]).startswith("error:")
    row["verdict"] = row["found_cls"] == "stiction"
    return row


def loop_verdicts(rows: Sequence[dict[str, Any]]) -> dict[str, tuple[int, int]]:
    """``(records called stiction, records)`` per true valve class."""
    out: dict[str, tuple[int, int]] = {}
    for cls in gen.LOOP_VALVES:
        sel = [r for r in rows if r["cls"] == cls]
        out[cls] = (sum(r["verdict"] for r in sel), len(sel))
    return out


def loop_type_verdicts(rows: Sequence[dict[str, Any]]) -> dict[str, tuple[int, int, int, int]]:
    """Per loop type: ``(sticking valves called stiction, sticking valves, other valves called
    stiction, other valves)``."""
    out: dict[str, tuple[int, int, int, int]] = {}
    for loop in gen.LOOP_TYPES:
        st = [r for r in rows if r["loop"] == loop and r["cls"] == "stiction"]
        ot = [r for r in rows if r["loop"] == loop and r["cls"] != "stiction"]
        out[loop] = (sum(r["verdict"] for r in st), len(st), sum(r["verdict"] for r in ot), len(ot))
    return out


def loop_arguments(command: str, jobs: bool = True) -> argparse.ArgumentParser:
    """The options of the commands on synthetic plant loops: ``--n``, ``--start`` and, when
    the command runs in parallel, ``--jobs``."""
    ap = argparse.ArgumentParser(prog=f"python -m hbench.diagnose.calibrate {command}")
    ap.add_argument("--n", type=int, default=128)
    ap.add_argument("--start", type=int, default=0)
    if jobs:
        ap.add_argument("--jobs", type=int, default=2)
    return ap


def main_loops(argv: Sequence[str] | None = None) -> int:
    """``python -m hbench.diagnose.calibrate loops [--n N] [--start S] [--jobs J]``: the stiction
    verdict on synthetic plant loops (:func:`hbench.diagnose.generator.loop_cases`)."""
    args = loop_arguments("loops").parse_args(argv)
    rows = parallel_map(run_loop, gen.loop_cases(args.n, args.start), args.jobs)
    for r in rows:
        ok = r["verdict"] == (r["cls"] == "stiction")
        print(f"{'ok ' if ok else 'BAD'} {r['name']:40s} -> {r['found_cls']}")
    for cls, (k, n) in loop_verdicts(rows).items():
        print(f"{cls:11s} called stiction {k}/{n}")
    print("per loop type (sticking valves found; other valves called stiction):")
    for loop, (k, n, f, m) in loop_type_verdicts(rows).items():
        print(f"  {loop:9s} stiction {k}/{n}, false alarms {f}/{m}")
    return 0


# --------------------------------------------------------------------------- OP-PV pattern tests


def pattern_tests(x: np.ndarray, y: np.ndarray, r: np.ndarray | None) -> dict[str, Any]:
    """The literature's OP-PV stiction tests with their limits (:mod:`hbench.diagnose.stats`):
    Yamashita's ``rho``, Kano et al.'s stuck-section share and Choudhury et al.'s NGI / NLI of
    the control error ``r - y`` (``y`` less its mean without a set point)."""
    from hbench.diagnose import stats

    e = (r - y) if r is not None else (y - np.mean(y))
    ngi, nli = stats.nonlinearity_indices(e)
    rho = stats.yamashita_index(x, y)
    kano = stats.kano_index(x, y)
    return {
        "rho": rho,
        "kano": kano,
        "ngi": ngi,
        "nli": nli,
        "yamashita": bool(rho > stats.YAMASHITA_RHO),
        "kano_stuck": bool(kano > stats.KANO_SHARE),
        "nonlinear": bool(ngi > stats.CHOUDHURY_NGI and nli > stats.CHOUDHURY_NLI),
    }


def _patterns_of(case: gen.LoopCase) -> dict[str, Any]:
    rec = gen.simulate_loop(case)
    r = None if rec.r is None else rec.r[0]
    return {"cls": case.cls, **pattern_tests(rec.x[0], rec.y[0], r)}


def main_patterns(argv: Sequence[str] | None = None) -> int:
    """``python -m hbench.diagnose.calibrate patterns [--n N] [--start S]``: how often each
    OP-PV pattern test (:func:`pattern_tests`) calls stiction on the synthetic plant loops,
    per true valve class."""
    args = loop_arguments("patterns", jobs=False).parse_args(argv)
    rows = parallel_map(_patterns_of, gen.loop_cases(args.n, args.start))
    for test in ("yamashita", "kano_stuck", "nonlinear"):
        cells = []
        for cls in gen.LOOP_VALVES:
            sel = [r for r in rows if r["cls"] == cls]
            cells.append(f"{cls} {sum(r[test] for r in sel)}/{len(sel)}")
        print(f"{test:11s} " + ", ".join(cells))
    return 0


def valve_position_gain(case: gen.LoopCase) -> dict[str, Any]:
    """How much the TRUE valve position ``u`` would improve the linear output-error model of a
    synthetic plant loop over the controller output ``x`` (whole record, points of fit): the
    most any valve class fitted through the dynamics could gain if its search were perfect."""
    from hbench.diagnose import classes, core
    from hbench.diagnose import nominal as nm

    rec, u = gen.simulate_loop_truth(case)
    with core.transient(False):
        ctx = nm.make_context(rec)
        fit = {}
        for name, v in (("x", ctx.x), ("u", u)):
            lin = classes.select_linear(
                v, ctx.y, ctx.all_idx, na_values=nm.NA_DYNAMIC, delays=nm.DELAYS_DYNAMIC
            )
            fit[name] = core.fit_percent(ctx.y, lin.fit.yhat)
    return {
        "name": case.name,
        "cls": case.cls,
        "loop": case.loop,
        "disturbance": case.disturbance,
        "fit_x": fit["x"],
        "gain_u": fit["u"] - fit["x"],
    }


def main_oracle(argv: Sequence[str] | None = None) -> int:
    """``python -m hbench.diagnose.calibrate oracle [--n N] [--start S] [--jobs J]``: the gain
    of the true valve position over the controller output (:func:`valve_position_gain`) on the
    synthetic loops with a sticking valve, per disturbance: where it is small or negative no
    valve model fitted from ``x`` can find the valve by its fit."""
    args = loop_arguments("oracle").parse_args(argv)
    cases = [c for c in gen.loop_cases(args.n, args.start) if c.cls == "stiction"]
    rows = parallel_map(valve_position_gain, cases, args.jobs)
    for r in sorted(rows, key=lambda r: r["gain_u"]):
        print(f"{r['name']:40s} fit from x {r['fit_x']:6.1f}  gain of u {r['gain_u']:+7.1f}")
    for dist in gen.LOOP_DISTURBANCES:
        g = np.array([r["gain_u"] for r in rows if r["disturbance"] == dist])
        if g.size:
            print(
                f"{dist:9s} gain of u >= 3 points: {int(np.sum(g >= 3))}/{g.size} "
                f"(median {np.median(g):+.1f})"
            )
    return 0


def bench_summary(rows: list[dict[str, Any]]) -> str:
    """The matrices of :func:`report` for all rows, then the per-plant and per-cause rates."""
    out = [report(rows), "", "per plant: class right, cause right, records"]
    for plant in bc.BENCH_PLANTS:
        sub = [r for r in rows if r["plant"] == plant]
        if sub:
            c = sum(r["found_cls"] == r["cls"] for r in sub)
            e = sum(r["cause"] == cause_label(r["effect"]) for r in sub)
            out.append(f"  {plant:12s} {c:4d} {e:4d} {len(sub):4d}")
    out.append("per true cause: cause right, gain > 0, records")
    for eff in gen.EFFECTS:
        sub = [r for r in rows if r["effect"] == eff]
        if sub:
            e = sum(r["cause"] == cause_label(eff) for r in sub)
            g = sum(r.get("gain", 0) > 0 for r in sub)
            out.append(f"  {eff:14s} {e:4d} {g:4d} {len(sub):4d}")
    coloured = [r for r in rows if r.get("noise_shape_power") is not None]
    if coloured:
        out.extend(oracle_summary(coloured, null) for null in noise_oracle.NULLS)
    return "\n".join(out)


def oracle_summary(rows: list[dict[str, Any]], null: str, at: float = 0.5) -> str:
    """What the ``colored-noise`` rows could show (:mod:`hbench.diagnose.noise_oracle`, its
    ``null``): how many a test of the noise's shape with the true plant finds with power ``at``
    or more, the cause right among those and among the rest, and the oracle's expected count."""
    power = [r["noise_shape_power"][null] for r in rows]
    shows = [r for r, q in zip(rows, power, strict=True) if q >= at]
    hidden = [r for r, q in zip(rows, power, strict=True) if q < at]
    right = [sum(r["cause"] == "colored-noise" for r in g) for g in (shows, hidden)]
    return (
        f"colored-noise records whose noise's shape the oracle test (true plant, null "
        f"{null!r}, 5 %) finds with power >= {at:g}: {len(shows)} of {len(rows)} (cause right "
        f"on {right[0]}); the other {len(hidden)}: cause right on {right[1]}; the oracle's "
        f"expected count {sum(power):.1f} of {len(rows)}"
    )


def main_bench(argv: Sequence[str] | None = None) -> int:
    """The benchmark's own loops (:mod:`hbench.diagnose.benchmark_cases`): every (plant, class,
    effect) cell ``--per-cell`` times from seed ``--start`` (calibration seeds 10000-19999,
    held-out seeds 20000-29999)."""
    ap = argparse.ArgumentParser(prog="python -m hbench.diagnose.calibrate bench")
    ap.add_argument("--start", type=int, default=bc.HELD_OUT_SEEDS.start)
    ap.add_argument("--per-cell", type=int, default=1)
    ap.add_argument("--plants", default=",".join(bc.BENCH_PLANTS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", default=None, help="write the rows to this JSON file")
    ap.add_argument("--extend-all", action="store_true", help="fit every extension")
    ap.add_argument("--rule", default="auto", choices=("auto", "validation", "detectors"))
    ap.add_argument("--method", default=None, help="blind method of the nominal model")
    ap.add_argument(
        "--criterion",
        default="auto",
        help="validation criterion the cause is chosen on, as hbench diagnose's --criterion",
    )
    args = ap.parse_args(argv)
    from hbench.diagnose.validate import parse_criterion
    from hbench.errors import InputError

    try:
        parse_criterion(args.criterion)  # a bad criterion: before the work
    except InputError as exc:
        ap.exit(2, f"{ap.prog}: error: {exc}\n")
    OPTIONS["extend_all"] = bool(args.extend_all)
    OPTIONS["rule"] = args.rule
    OPTIONS["criterion"] = args.criterion
    if args.method:
        OPTIONS["method"] = args.method
    cases = bc.bench_grid(args.start, args.per_cell, tuple(args.plants.split(",")))
    rows = run(cases, args.jobs, progress=True)
    for r in rows:
        if r["cause"] != cause_label(r["effect"]) or r["found_cls"] != r["cls"]:
            print(
                f"{r['seed']:6d} {r['plant']:12s} p={r['p']} {r['effect']:13s} {r['cls']:10s} -> "
                f"{r['cause']:13s} {r['found_cls']:10s} base {r.get('baseline', 0):6.1f} "
                f"gain {r.get('gain', 0):6.1f} fired {','.join(r.get('fired', []))} "
                f"{r.get('error', '')}"
            )
    print()
    print(bench_summary(rows))
    if args.json:
        import json

        with open(args.json, "w") as fh:
            json.dump(rows, fh, default=float)
    return 0


#: The sub-commands beside the default (synthetic records with hidden effects, :func:`main`).
COMMANDS = {
    "real": main_real,
    "bench": main_bench,
    "loops": main_loops,
    "patterns": main_patterns,
    "oracle": main_oracle,
}

if __name__ == "__main__":  # pragma: no cover
    if len(sys.argv) > 1 and sys.argv[1] in COMMANDS:
        sys.exit(COMMANDS[sys.argv[1]](sys.argv[2:]))
    sys.exit(main())
