"""``hbench sweep``: the Hydra app. One job = one cell (scenario) x the requested methods x R runs.

::

    hbench sweep                                   # one run of the defaults (the paper's example)
    hbench sweep -m noise.snr=2,5,20 scenario.p=3,5,8 plant.delay=0,2,7 \\
        method=wang-lsm,bai-fu runs=20             # a 54-job sweep
    hbench sweep -m experiment=snr_p_delay hydra/launcher=joblib hydra.launcher.n_jobs=2

Each job writes into its own Hydra output folder (named by its run id, a hash of its resolved
config): ``rows.parquet`` (tidy rows), ``config.yaml`` (resolved), ``provenance.json`` and, last,
``DONE``. A job whose run id already has a ``DONE`` marker in the sweep folder is skipped, so
re-running a sweep into the same folder (``out=DIR`` or ``hydra.sweep.dir=DIR``) resumes it. The
callback :class:`hbench.sweep.callbacks.AggregateTables` then writes ``fitness.csv`` / ``bias.csv``
(+ ``.md``, ``.tex``) and all rows into the sweep folder (a single run: into its own folder).

A cell's seed is :func:`hbench.sim.seeding.cell_seed` of the base seed and the resolved scenario
part of the config (plant, nonlinearity, controller, noise, reference, scenario), so every method of
a cell sees the same data and a cell's numbers do not depend on the other cells.

Before Hydra starts, the overrides are composed once per swept value (:func:`validate`), so a typo
(unknown key, bad type, unknown plugin, parameter or method) exits with status 2 and one line
naming the key instead of a Hydra traceback.

Launchers: ``basic`` (default, sequential), ``hydra/launcher=joblib`` (local processes, extra
``joblib``), ``hydra/launcher=ray`` (extra ``ray``, in its own environment), and SLURM through
``hydra/launcher=submitit_slurm`` (extra ``submitit``); see ``results/README.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import logging
import os
import time
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

from hbench.errors import AggregationError, InputError, tell
from hbench.sweep.jobs import DONE, ROWS, normalise, read_marker

EXAMPLE = (
    "hbench sweep -m noise.snr=2,5,20 scenario.p=3,5,8 plant.delay=0,2,7 "
    "method=wang-lsm,bai-fu runs=20"
)
#: Environment variable (set through hydra.job.env_set) holding the number of jobs of a sweep.
JOBS_ENV = "HBENCH_SWEEP_JOBS"
#: Environment variable (likewise) holding the process id of ``hbench sweep``: a job running in
#: another process (a launcher's worker) exits when that process dies (:func:`watch_parent`).
PARENT_ENV = "HBENCH_SWEEP_PARENT"
#: Sweeps with at most this many jobs are validated combination by combination; larger ones
#: value by value (every swept value once, the other keys at their first value).
FULL_CHECK_MAX = 8


# --------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------


def add_parser(subparsers: Any) -> None:
    """Add the ``sweep`` command (called by :mod:`hbench.cli`)."""
    p = subparsers.add_parser(
        "sweep",
        help="the Hydra app: one run or a multirun sweep -> tidy rows and aggregated tables",
        description="Run the benchmark as a Hydra app. Overrides are Hydra's (key=value, "
        "group=option, +key=value for a new key); -m sweeps comma-separated values. Config "
        "groups: plant, nonlinearity, controller, noise, reference, method, experiment, "
        "hydra/launcher. Results: rows.parquet, fitness/bias tables under results/ (or out=DIR).",
        epilog=f"example:\n  {EXAMPLE}\n  hbench sweep --cfg job noise.snr=5   # show the config",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("-m", "--multirun", action="store_true", help="sweep (Hydra multirun)")
    p.add_argument(
        "--cfg",
        choices=("job", "hydra", "all"),
        default=None,
        help="print the composed config and exit",
    )
    p.add_argument("--resolve", action="store_true", help="with --cfg: resolve interpolations")
    p.add_argument(
        "--aggregate",
        metavar="DIR",
        default=None,
        help="only (re)write the tables of the finished jobs in a sweep folder",
    )
    p.add_argument(
        "overrides",
        nargs=argparse.REMAINDER,
        metavar="OVERRIDE",
        help="Hydra overrides, e.g. noise.snr=2,5,20 scenario.p=3 method=wang-lsm",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``hbench sweep``: validate the overrides, then hand them to Hydra."""
    overrides = list(args.overrides or [])
    multirun = bool(args.multirun)
    for flag in ("-m", "--multirun"):  # allowed after the overrides too
        while flag in overrides:
            overrides.remove(flag)
            multirun = True
    if getattr(args, "aggregate", None):
        from hbench.sweep.callbacks import aggregate_dir

        root = Path(args.aggregate)
        if overrides or multirun or not root.is_dir():
            raise InputError("--aggregate takes an existing sweep folder and no overrides")
        if not any(root.rglob(DONE)):
            raise InputError(f"no finished jobs (no {DONE} marker) in {root}")
        try:
            aggregate_dir(root)
        except AggregationError as exc:
            tell(f"hbench sweep: error: {' '.join(str(exc).split())}")
            return 1
        return 0
    bad = [o for o in overrides if o.startswith("-")]
    if bad:
        raise InputError(
            f"unknown option {bad[0]!r} (options: -m, --cfg, --resolve, --aggregate; "
            "everything else is a Hydra override key=value)"
        )
    if args.cfg and multirun:
        raise InputError(
            "--cfg prints one job's config: drop -m (and give one value per key) to see it"
        )
    n_jobs = validate(overrides, multirun, launch=not args.cfg)
    argv = list(overrides)
    if multirun:
        argv.insert(0, "--multirun")
    if args.cfg:
        argv[:0] = ["--cfg", args.cfg] + (["--resolve"] if args.resolve else [])
    elif n_jobs:
        argv.append(f"++hydra.job.env_set.{JOBS_ENV}='{n_jobs}'")
        argv.append(f"++hydra.job.env_set.{PARENT_ENV}='{os.getpid()}'")
    return _launch(argv)


def _launch(argv: Sequence[str]) -> int:
    """Run the Hydra app with ``argv`` (Hydra's own command line); return the exit status."""
    from hbench.bench import parallel
    from hbench.sweep import config
    from hbench.sweep.hydra_adapter import run_app

    root = logging.getLogger()
    saved = (root.level, list(root.handlers))
    try:
        # cells with jobs > 1 that run in this process (the basic launcher) share worker
        # processes kept for the sweep instead of starting them per cell (hbench.bench.parallel)
        with parallel.kept_workers(), _unwritable_is_one_line():
            run_app(task, argv, config.CONF_DIR, "config")
    except SystemExit as exc:  # Hydra reports its own errors and exits
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    finally:  # Hydra configures logging for its jobs; leave the caller's as it was
        for handler in root.handlers:
            if handler not in saved[1]:
                handler.close()
        root.setLevel(saved[0])
        root.handlers[:] = saved[1]
    return 0


#: ``errno`` values of a file system that takes no more data.
_FULL = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})


@contextlib.contextmanager
def _unwritable_is_one_line() -> Iterator[None]:
    """While inside, a sweep that cannot write (a full disk, in a job's files or in Hydra's own)
    stops with one line on stderr and exit status 2 instead of Hydra's traceback; the job being
    written is left without its ``DONE`` marker, so resuming computes it.

    Hydra reports an exception of a run with a traceback and exit 1; inside this block such
    exceptions become ``SystemExit(2)`` first (:func:`hbench.sweep.hydra_adapter.report_errors`).
    """
    from hbench.errors import OutputError
    from hbench.sweep.hydra_adapter import report_errors

    def checked(func: Any) -> Any:
        try:
            return func()
        except OutputError as exc:
            tell(f"hbench sweep: error: {' '.join(str(exc).split())}")
            raise SystemExit(2) from None
        except OSError as exc:
            if exc.errno not in _FULL:
                raise
            where = f"cannot write {exc.filename}" if exc.filename else "cannot write the results"
            tell(f"hbench sweep: error: {where}: {exc.strerror}")
            raise SystemExit(2) from None

    with report_errors(checked):
        yield


# --------------------------------------------------------------------------------------------
# validation (before Hydra starts): typos -> InputError (exit 2, one line)
# --------------------------------------------------------------------------------------------


def validate(overrides: Sequence[str], multirun: bool = False, launch: bool = True) -> int:
    """Compose the config with ``overrides`` and check it; return the number of jobs.

    ``launch=False`` (``--cfg``: nothing runs) skips the checks of the output folder.

    With ``multirun``, sweeps (on the command line and in ``hydra.sweeper.params``) are expanded:
    every combination is checked when there are at most :data:`FULL_CHECK_MAX`, else every
    swept value once (the other swept keys at their first value). Raises :class:`InputError`
    naming the offending key.
    """
    import itertools

    from hydra import compose, initialize_config_dir
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    from hbench.sweep import config

    config.register_methods()
    # the config groups (conf/'s folders): a list value (group=[a,b]) would merge their options
    groups = {d.name for d in config.CONF_DIR.iterdir() if d.is_dir()}
    parser = OverridesParser.create()
    try:
        parsed = parser.parse_overrides(list(overrides))
    except HydraException as exc:
        raise InputError(f"cannot parse override: {_first_line(exc)}") from None
    fixed: dict[str, list[str]] = {}
    for o in parsed:
        key = o.get_key_element()
        group = o.key_or_group in groups
        listed = (
            any(v.lstrip().startswith("[") for v in o.sweep_string_iterator())
            if o.is_sweep_override()
            else isinstance(o.value(), list)
        )
        if group and listed:
            raise InputError(
                f"override {o.input_line!r} would merge the options of the config group "
                f"{o.key_or_group!r} into one (the last wins): sweep them with -m "
                f"{o.key_or_group}=a,b"
                + (
                    ", or run several methods in one job with methods=[a,b]"
                    if key == "method"
                    else ""
                )
            )
        if o.is_sweep_override():
            if not multirun:
                hint = (
                    "add -m to sweep it (or run several methods in one job: methods=[a,b])"
                    if key == "method"
                    else "add -m to sweep it"
                    if group
                    else "add -m (or write a list as key=[a,b])"
                )
                raise InputError(f"override {o.input_line!r} sweeps {o.key_or_group!r}: {hint}")
            if not o.is_discrete_sweep():
                raise InputError(
                    f"override {o.input_line!r}: the basic sweeper takes lists "
                    "and range(), not intervals"
                )
            fixed[key] = [f"{key}={v}" for v in o.sweep_string_iterator()]
        else:
            fixed[key] = [o.input_line]
    with initialize_config_dir(
        config_dir=str(config.CONF_DIR), version_base="1.3", job_name="sweep"
    ):

        def compose_checked(ovs: list[str]) -> Any:
            where = ""
            if multirun:
                swept = [o for k, o in zip(axes, ovs, strict=False) if len(axes[k]) > 1]
                where = f" (in the job {' '.join(swept)})" if swept else ""
            try:
                cfg = compose("config", overrides=ovs, return_hydra_config=True)
            except Exception as exc:  # Hydra/OmegaConf errors of many kinds
                raise InputError(_hydra_message(exc) + where) from None
            check_config(cfg, where)
            return cfg

        axes = dict(fixed)
        first = [v[0] for v in axes.values()]
        base = compose_checked(first)
        if launch:  # Hydra's resolved output folder (out=, hydra.run.dir=, hydra.sweep.dir=)
            from hbench.system.writable import check_output

            if base.get("out") is not None and not str(base.out).strip():
                raise InputError(
                    "out= is empty: give a folder, or leave out= out (results/<time stamp>)"
                )
            folder = base.hydra.sweep.dir if multirun else base.hydra.run.dir
            check_output(str(folder), "output folder ", folder=True)
        if not multirun:
            if launch:
                _check_not_overwriting(base)
            return 1
        params = base.hydra.sweeper.get("params") or {}
        if params:  # config-defined sweeps; the command line wins for the same key
            try:
                from_config = parser.parse_overrides([f"{k}={v}" for k, v in params.items()])
            except HydraException as exc:
                raise InputError(f"hydra.sweeper.params: {_first_line(exc)}") from None
            merged: dict[str, list[str]] = {}
            for o in from_config:
                key = o.get_key_element()
                vals = (
                    list(o.sweep_string_iterator())
                    if o.is_sweep_override()
                    else [o.get_value_element_as_str()]
                )
                merged[key] = [f"{key}={v}" for v in vals]
            merged.update(axes)
            axes = merged
        lists = list(axes.values())
        n_jobs = 1
        for v in lists:
            n_jobs *= len(v)
        if n_jobs <= FULL_CHECK_MAX:
            combos: Iterable[tuple[str, ...]] = itertools.product(*lists)
        else:
            firsts = [v[0] for v in lists]
            star = [tuple(firsts)]
            for i, vals in enumerate(lists):
                star += [(*firsts[:i], v, *firsts[i + 1 :]) for v in vals[1:]]
            combos = star
        for combo in combos:
            if list(combo) != first:
                compose_checked(list(combo))
        return n_jobs


def _check_not_overwriting(cfg: Any) -> None:
    """A single run into a folder (``out=DIR`` or ``hydra.run.dir=DIR``) that holds another
    config's finished run is refused (results are never overwritten); the same config's
    finished run is skipped by the task."""
    import json

    from hbench.sweep import config

    out = cfg.hydra.run.dir
    marker = Path(str(out)) / DONE
    if not marker.is_file():
        return
    try:
        held = json.loads(marker.read_text())
    except (OSError, ValueError):
        held = {}
    if held.get("run_id") != config.run_id(cfg):
        what = ", ".join(held.get("methods") or []) or "unknown methods"
        raise InputError(
            f"{out} holds the finished run of another config (run id "
            f"{held.get('run_id', '?')}, {what}); results are never overwritten: choose another "
            "out= or remove that folder"
        )


def check_config(cfg: Any, where: str = "") -> None:
    """Checks Hydra's composition cannot make: keys added with ``+``, the noise level, plugin
    names and parameters, methods and their options, the prior knowledge, the launcher."""
    import importlib

    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from hbench.bench import runner
    from hbench.errors import UnstableError
    from hbench.plugins import registry
    from hbench.sim import scenarios
    from hbench.sweep import config

    extra = [k for k in cfg if k != "hydra" and k not in config.TOP_LEVEL_KEYS]
    if extra:
        raise InputError(
            f"unknown key {extra[0]!r}{where} (top-level keys: {', '.join(config.TOP_LEVEL_KEYS)})"
        )
    try:
        data = config.plain(cfg)
    except OmegaConfBaseException as exc:
        raise InputError(f"{_key_message(exc)}{where}") from None
    for group in config.PLUGIN_GROUPS:
        if not isinstance(data[group], dict) or "name" not in data[group]:
            raise InputError(f"{group}: needs a 'name'{where}")
    noise = data["noise"]
    for key in ("sigma2", "snr"):
        value = noise.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)):
            raise InputError(f"noise.{key}: must be a number or null, got {value!r}{where}")
    if noise.get("sigma2") is not None and noise.get("snr") is not None:
        raise InputError(
            f"noise.sigma2 ({noise['sigma2']}) and noise.snr ({noise['snr']}) are both set"
            f"{where}: give one (noise.snr=X alone switches to SNR mode; where a preset such "
            "as experiment=paper_section6 fixes noise.sigma2, add noise.sigma2=null)"
        )
    for key, lo in (("runs", 1), ("chunk", 1), ("jobs", 1), ("seed", 0), ("scenario.p", 1)):
        value = OmegaConf.select(cfg, key)
        if value < lo:
            raise InputError(f"{key}: must be >= {lo}, got {value}{where}")
    timeout = data.get("method_timeout")
    if timeout is not None and not timeout > 0:
        raise InputError(f"method_timeout: must be > 0 seconds or null, got {timeout}{where}")
    for key in ("scenario.T", "scenario.duration"):
        if not OmegaConf.select(cfg, key) > 0:
            raise InputError(f"{key}: must be > 0, got {OmegaConf.select(cfg, key)}{where}")
    methods = data["methods"]
    if not methods:
        raise InputError(f"methods: empty{where}")
    try:
        scenario = scenarios.build(config.scenario_spec(data))
        _check_size(data, scenario, where)
    except UnstableError:
        pass  # a property of the cell, not a typo: the job records it as failed rows
    except InputError as exc:
        raise InputError(f"{exc}{where}") from None
    except Exception:  # a plugin's own bug: the job records it as failed rows
        pass
    try:
        unknown = [m for m in data["method_options"] if m not in registry().names("identifiers")]
        if unknown:
            raise InputError(
                f"method_options: unknown method {unknown[0]!r} (known: "
                f"{', '.join(registry().names('identifiers'))})"
            )
        runner.methods_from_names(methods, data["method_options"])
    except InputError as exc:
        raise InputError(f"{exc}{where}") from None
    try:
        config.identify_options(data)
    except InputError as exc:
        raise InputError(f"identify: {exc}{where}") from None
    target = str(cfg.hydra.launcher.get("_target_", ""))
    module = target.rsplit(".", 1)[0]
    try:
        importlib.import_module(module)
    except ImportError:
        extra_name = next((x for x in ("joblib", "ray", "submitit") if x in module), None)
        hint = f": pip install 'hbench[{extra_name}]'" if extra_name else ""
        raise InputError(f"hydra/launcher: {target} is not installed{hint}") from None


def _check_size(data: dict[str, Any], scenario: Any, where: str) -> None:
    """Refuse a job whose memory would exceed the budget (:mod:`hbench.system.limits`): its chunks
    and its tidy rows, which it holds until it writes them."""
    from hbench.bench import runner
    from hbench.system import limits

    plant = scenario.discrete_plant
    limits.check_states(plant, f"the plant{where}")
    rows_per_run = len(data["methods"]) * (len(runner.QUANTITIES) + len(plant.true_params()))
    need = limits.job_bytes(
        scenario.K * scenario.p,
        int(data["runs"]),
        int(data["chunk"]),
        int(data.get("jobs", 1)),
        rows_per_run,
    )
    limits.check(
        f"a job of {data['runs']} runs x {len(data['methods'])} methods{where}",
        need,
        "fewer runs per job, a shorter duration or a smaller chunk",
    )


def _first_line(exc: BaseException) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[0] if lines else type(exc).__name__


def _key_message(exc: BaseException) -> str:
    """``key: message`` from an OmegaConf error (its ``full_key``), with a close match."""
    import difflib

    key = getattr(exc, "full_key", None) or ""
    msg = _first_line(exc)
    if "not in struct" in msg or "not in '" in msg:
        parent = getattr(exc, "parent_node", None)
        siblings = [str(k) for k in parent if k != "hydra"] if parent is not None else []
        leaf = key.rsplit(".", 1)[-1]
        close = difflib.get_close_matches(leaf, siblings, n=1)
        prefix = key.rsplit(".", 1)[0] + "." if "." in key else ""
        hint = f"; did you mean {prefix}{close[0]}?" if close else ""
        known = f" (keys here: {', '.join(siblings)})" if siblings else ""
        add = f"; add a new key with +{key}=..." if prefix else ""
        return f"unknown key {key!r}{hint}{known}{add}"
    return f"{key}: {msg}" if key else msg


def _hydra_message(exc: BaseException) -> str:
    """One line naming the key for an exception of Hydra's composition."""
    import re

    from hydra.errors import MissingConfigException

    if isinstance(exc, MissingConfigException):
        text = str(exc)
        m = re.search(r"Could not find '([^']+)/([^'/]+)'", text)
        opts = re.search(r"Available options in '[^']+':\n((?:\t.*\n?)+)", text)
        if m:
            group, name = m.groups()
            options = ", ".join(s.strip() for s in opts.group(1).splitlines()) if opts else ""
            return f"unknown {group} option {name!r}" + (
                f" (options: {options})" if options else ""
            )
        return _first_line(exc)
    cause = exc.__cause__ or exc.__context__
    if cause is not None and getattr(cause, "full_key", None):
        return _key_message(cause)
    return _first_line(exc)


# --------------------------------------------------------------------------------------------
# the job
# --------------------------------------------------------------------------------------------


def _say(msg: str) -> None:
    """A progress line on stderr. Progress is advisory: a closed stderr (``2>&1 | head``) never
    stops or fails a job."""
    tell(f"[hbench sweep] {msg}")


def job_complete(folder: Path, held: dict[str, Any]) -> bool:
    """Whether the job in ``folder`` (its marker's content ``held``) is done: its cell ran
    (``status`` ``ok``) and its ``rows.parquet`` is readable with the marker's row count. A job
    whose cell failed as a whole (an error, MemoryError included) or whose rows are missing or
    truncated is computed again when the sweep is resumed."""
    import pyarrow.parquet as pq

    if held.get("status") != "ok":
        return False
    try:
        return pq.read_metadata(folder / ROWS).num_rows == held.get("rows")
    except Exception:  # missing, truncated, not Parquet
        return False


def find_done(root: Path, run_id: str) -> Path | None:
    """The folder under ``root`` holding the complete job (:func:`job_complete`) of ``run_id``
    (None if none)."""
    if not root.is_dir():
        return None
    own = root / run_id / DONE  # job folders are named by run id: the usual place
    for marker in [own] if own.is_file() else sorted(root.rglob(DONE)):
        held = read_marker(marker)
        if held and held.get("run_id") == run_id and job_complete(marker.parent, held):
            return marker.parent
    return None


def _label(data: dict[str, Any]) -> str:
    noise = data["noise"]
    level = (
        f"snr={noise['snr']:g}"
        if noise.get("snr") is not None
        else (f"sigma2={noise['sigma2']:g}" if noise.get("sigma2") is not None else "noise=?")
    )
    delay = data["plant"].get("delay")
    return (
        f"p={data['scenario']['p']} delay={delay} {level} {data['nonlinearity']['name']} "
        f"{','.join(data['methods'])}"
    )


def task(cfg: Any) -> None:
    """The Hydra task: one cell x the requested methods x R runs into the job's output folder.

    Warnings are shown on one line (:func:`hbench.errors.one_line_warnings`), also in a
    launcher's worker processes."""
    from hbench.errors import one_line_warnings

    parent = os.environ.get(PARENT_ENV, "")
    if parent.isdigit() and int(parent) != os.getpid():  # a launcher's worker of hbench sweep
        from hbench.system.runtime import tune_allocator

        tune_allocator()  # as in the sweep's own process (hbench.system.runtime)
    with one_line_warnings("sweep"), watch_parent(int(parent) if parent.isdigit() else None):
        _task(cfg)


@contextlib.contextmanager
def watch_parent(pid: int | None) -> Iterator[None]:
    """While inside, a thread ends this process (exit status 1) as soon as its parent, process
    ``pid``, ends: a launcher's worker (joblib's loky processes, children of ``hbench sweep``)
    whose sweep was killed stops its job at once instead of computing it for nobody (the job,
    left without its ``DONE`` marker, is computed when the sweep is resumed).

    Nothing is watched where ``pid`` is None, this process, or not its parent: the basic
    launcher (the job runs in ``hbench sweep`` itself), Ray's workers (children of Ray's own
    daemon) and SLURM jobs (on other machines) are left to their launcher. The parent is
    polled every 0.2 s (a dead parent's children are handed to another process).
    """
    import threading

    if pid is None or pid == os.getpid() or pid != os.getppid():
        yield
        return
    stop = threading.Event()

    def watch() -> None:
        while not stop.wait(0.2):
            if os.getppid() != pid:
                _say(f"hbench sweep (process {pid}) has ended: this worker stops its job")
                os._exit(1)

    thread = threading.Thread(target=watch, name="hbench-watch-parent", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def _task(cfg: Any) -> None:
    import json
    import os

    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from hbench.sweep import config
    from hbench.system import atomic
    from hbench.tables import results

    hc = HydraConfig.get()
    out = Path(hc.runtime.output_dir)
    multirun = hc.mode == RunMode.MULTIRUN
    root = Path(hc.sweep.dir) if multirun else out
    data = config.plain(cfg)
    rid = config.run_id(data)
    total = os.environ.get(JOBS_ENV)
    job = (
        f"job {hc.job.num + 1}/{total}"
        if multirun and total
        else (f"job {hc.job.num + 1}" if multirun else "run")
    )
    label = _label(data)
    done_in = find_done(root, rid)
    if done_in is not None:
        _say(f"{job} [{label}]: already done ({done_in.name}), skipped")
        return
    marker = out / DONE
    if marker.exists():  # another config's marker, or this job's incomplete run
        held = read_marker(marker) or {}
        if not multirun and held.get("run_id") != rid:  # validate refuses this; never overwrite
            raise InputError(f"{out} holds the finished run of another config")
        marker.unlink()  # a job folder is named by its run id: a stale marker, replaced
    t0 = time.perf_counter()

    def progress(done: int, runs: int) -> None:
        _say(f"{job} [{label}]: {done}/{runs} runs")

    rows, seeds, failure = compute(data, progress=progress)
    # each file whole or not at all, the marker last: a job is done only with readable rows
    with atomic.replacing(out / ROWS) as tmp:
        rows.to_parquet(tmp, index=False)
    atomic.write_text(out / "config.yaml", OmegaConf.to_yaml(OmegaConf.create(data)))
    results.write_provenance(out, config=data, seeds=seeds)
    status = "cell-failed" if failure else "ok"
    atomic.write_text(
        marker,
        json.dumps(
            {
                "run_id": rid,
                "cell": seeds["cell"],
                "status": status,
                "rows": len(rows),
                "methods": data["methods"],
                "seconds": round(time.perf_counter() - t0, 3),
            }
        )
        + "\n",
    )
    count = ""
    if multirun:
        count = f"; {len(list(root.rglob(DONE)))}{f'/{total}' if total else ''} jobs finished"
    note = f"; cell FAILED: {failure}" if failure else ""
    _say(f"{job} [{label}]: done in {time.perf_counter() - t0:.1f} s{count}{note}")
    if not failure:
        for line in without_estimates(rows):
            _say(f"{job} [{label}]: WARNING {line}")


def without_estimates(rows: Any) -> list[str]:
    """The methods of ``rows`` with no run ``ok``, which have no row in the fitness and bias
    tables (so the sweep says it when the job ends).

    Parameters
    ----------
    rows : DataFrame
        Tidy rows of one job (:data:`hbench.bench.schema.TIDY_COLUMNS`).

    Returns
    -------
    list of str
        One line per such method and cell: its runs, their statuses and messages, from the
        report's :func:`hbench.report.aggregate.failure_table`.
    """
    from hbench.report.aggregate import failure_table

    table = failure_table(rows)
    statuses = list(table.columns[table.columns.get_loc("ok") + 1 : -1])  # failed, ...
    lines = []
    for row in table[table["ok"] == 0].to_dict("records"):
        counts = ", ".join(f"{s} {row[s]}" for s in statuses if row[s])
        lines.append(
            f"{row['method']}: no estimate in {row['runs']} runs ({counts}): {row['messages']}"
        )
    return lines


def compute(data: dict[str, Any], progress: Any = None) -> tuple[Any, dict[str, Any], str]:
    """Rows of one job (one cell, its methods), the seeds, and the cell's failure ('' if none).

    A method that raises gives ``status=failed`` rows (the runner); a cell that raises as a whole
    (an unstable loop, a simulation error) gives ``status=failed`` rows for every method and run,
    so the sweep and its aggregation go on.
    """
    import traceback

    from hbench.bench import runner
    from hbench.sim import scenarios, seeding
    from hbench.sweep import config

    axes = config.scenario_axes(data)
    seq = seeding.cell_seed(int(data["seed"]), config.canonical(axes))
    cell = config.cell_id(data)
    seeds = {
        "base_seed": int(data["seed"]),
        "cell_entropy": [int(v) for v in seq.entropy],
        "run_streams": "run i draws from child i of the cell's SeedSequence",
        "cell": cell,
        "run_id": config.run_id(data),
    }
    scenario = None
    try:
        scenario = scenarios.build(config.scenario_spec(data))
        plant = scenario.discrete_plant
        options = config.identify_options(data, plant.delay_multiple(scenario.p))
        methods = runner.methods_from_names(data["methods"], data["method_options"])
        result = runner.run_cell(
            scenario,
            methods,
            int(data["runs"]),
            seq,
            options,
            cell=cell,
            chunk=int(data["chunk"]),
            progress=progress,
            jobs=int(data.get("jobs", 1)),
            method_timeout=data.get("method_timeout"),
        )
        rows, failure = result.rows, ""
    except Exception as exc:  # one bad cell must not stop the sweep
        last = traceback.extract_tb(exc.__traceback__)[-1]
        failure = " ".join(
            f"{type(exc).__name__}: {exc} "
            f"({last.filename.rsplit('/', 1)[-1]}:{last.lineno})".split()
        )
        rows = failed_rows(data, scenario, seq, cell, failure)
    rows = rows.assign(job=config.run_id(data))
    return normalise(rows), seeds, failure


def failed_rows(data: dict[str, Any], scenario: Any, seq: Any, cell: str, message: str) -> Any:
    """``status=failed`` rows for every method, run and quantity of a cell that could not run."""
    import numpy as np
    import pandas as pd

    from hbench.bench import runner

    true: dict[str, float] = {}
    delay = data["plant"].get("delay")
    plant_name = data["plant"]["name"]
    try:
        plant = scenario.discrete_plant
        true, delay, plant_name = plant.true_params(), plant.delay, plant.name
    except Exception:  # the plant itself may be what failed
        pass
    noise = data["noise"]
    ids = {
        "cell": cell,
        "nonlinearity": data["nonlinearity"]["name"],
        "plant": plant_name,
        "p": int(data["scenario"]["p"]),
        "delay": int(delay) if delay is not None else -1,
        "sigma2": noise["sigma2"] if noise.get("sigma2") is not None else np.nan,
        "snr_target": noise["snr"] if noise.get("snr") is not None else np.nan,
        "seed": str(seq.entropy),
    }
    rows = [
        {
            **ids,
            "method": m,
            "run": i,
            "quantity": q,
            "value": np.nan,
            "true": true.get(q, np.nan),
            "snr": np.nan,
            "status": "failed",
            "error": message,
        }
        for m in data["methods"]
        for i in range(int(data["runs"]))
        for q in (*runner.QUANTITIES, *true)
    ]
    return pd.DataFrame(rows, columns=list(runner.TIDY_COLUMNS))
