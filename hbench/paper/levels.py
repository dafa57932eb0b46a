"""The reproduction's runs: its conventions (:class:`Config`), the scenario and methods of each
noise level, and the Monte Carlo runs of Tables 4 and 5 and the single realisation of Tables 1 and
2.

The defaults and why they are chosen: :mod:`hbench.paper.reproduce`.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hbench.errors import InputError

#: Noise levels of Tables 4 and 5 (sigma^2 of the white noise driving the noise filter).
LEVELS: tuple[float, ...] = (0.0, 1e-4, 5e-4, 1e-3, 5e-3, 1e-2)


#: The level of Tables 1, 2 and Figures 4, 5.
TYPICAL_LEVEL = 1e-3


DEFAULT_SEED = 20070601


DEFAULT_RUNS = 100


#: Runs of the noise-free level (every estimate is exact there).
NOISE_FREE_RUNS = 10


#: Realisations behind the spread of the Table 1 and 2 values.
TABLE12_RUNS = 20


#: Every method the reproduction runs (``wang-lsm-inv``: ``wang-lsm`` with ``inverse='auto'``).
ALL_METHODS: tuple[str, ...] = (
    "wang-lsm",
    "wang-iv",
    "wang",
    "wang-lsm-inv",
    "bai-fu",
    "sun-liu-sano",
    "oracle",
    "oracle-inv",
)


#: The methods Tables 4 and 5 need.
TABLE_METHODS: tuple[str, ...] = ("wang-lsm", "wang-iv", "wang-lsm-inv", "oracle", "oracle-inv")


#: Names the reproduction gives a method's estimates put in the direct inverse (``inverse='auto'``)
#: instead of eq. (27): Table 5's F_INV from ``wang-lsm``'s (the default) or from ``wang``'s, the
#: paper's steps (ii) and (iv) (``Config.f_inv``).
INVERSE_VARIANTS: dict[str, str] = {"wang-lsm-inv": "wang-lsm", "wang-inv": "wang"}


#: The paper's steps (ii) and (iv) one at a time: ``wang`` with one choice left to the LSM
#: (names the reproduction gives these variants; ``wang`` makes both choices).
WANG_VARIANTS: dict[str, dict[str, str]] = {
    "wang-step-ii": {"select_b": "lsm"},
    "wang-step-iv": {"select_a": "lsm"},
}


#: Which per-run fitnesses Table 5 averages (``Config.fitness_runs``): every run; every run
#: with its fitness floored at 0; the runs with a fitness >= 0 only.
FITNESS_RUNS: tuple[str, ...] = ("all", "clip0", "nonnegative")


#: The scalings Table 5 can be scored with (``Config.fitness``, ``Config.fitness_bound``: those
#: of :data:`hbench.bench.metrics.SCALINGS`, named here so that a ``Config`` is checked without
#: importing the metrics, numpy, at start-up) and the quantity of the rows each one reads.
FITNESS_QUANTITY: dict[str, str] = {
    "gain": "fitness",
    "ls": "fitness_ls",
    "ls-affine": "fitness_ls_affine",
    "gain-centred": "fitness_gain_centred",
}


#: The scalings whose quantities the runner's rows carry; the others need their own scoring loop.
RUNNER_SCALINGS = frozenset({"gain", "ls"})


@dataclass(frozen=True)
class Config:
    """One reproduction's conventions (the default, or an alternative of ``--investigate``).

    ``overrides`` are dotted scenario keys (``("reference.band", [0, 0.25])``); ``reference``
    replaces the whole reference spec when given. ``fitness`` is the scaling of Table 5
    (``gain``, ``ls``, ``ls-affine``, ``gain-centred``: :mod:`hbench.bench.metrics`),
    ``fitness_bound``, when given, the scaling of its F0 columns alone (the true parameters'
    bounds; F_LSM and F_INV keep ``fitness``),
    ``fitness_runs`` which per-run fitnesses Table 5 averages (:data:`FITNESS_RUNS`: ``all``;
    ``clip0``, each floored at 0; ``nonnegative``, the runs with a fitness >= 0 only), ``snr``
    the definition compared with the SNR column (``norm``: ||y0||/||v||, ``power``: its square,
    ``db``: 20 log10), ``warmup`` seconds simulated before the 500 s record and discarded.
    ``lsm`` is the method behind Table 4's LSM rows and Table 5's F_LSM (``wang`` or a
    :data:`WANG_VARIANTS` name for the paper's steps (ii), (iv)); ``f_lsm``, when given, the
    method behind F_LSM alone (Table 4's LSM rows keep ``lsm``); ``f_inv`` the method behind
    F_INV (``wang-lsm-inv``, or another of :data:`INVERSE_VARIANTS`, or ``bai-fu``).
    ``eq15`` is ``wang-lsm``'s reading of eq. (15) where it has no real root (``clip``,
    ``real``, ``modulus``, ``zero``: :func:`hbench.ident.polyphase.noise_variance`); ``table2`` how
    Table 2's rows are read (``as-printed``, or ``swapped``: its l = 1 and l = 2 exchanged).
    """

    label: str = "default"
    group: str = "default"
    description: str = "the defaults (see the module docstring)"
    overrides: tuple[tuple[str, Any], ...] = ()
    reference: tuple[tuple[str, Any], ...] | None = None
    pooled: bool = True
    structure: str = "fixed"
    lsm: str = "wang-lsm"
    f_inv: str = "wang-lsm-inv"
    eq15: str = "clip"
    table2: str = "as-printed"
    fitness: str = "gain"
    fitness_bound: str | None = None
    fitness_runs: str = "all"
    f_lsm: str | None = None
    snr: str = "norm"
    warmup: float = 0.0

    def __post_init__(self) -> None:
        for key, value in (("fitness", self.fitness), ("fitness_bound", self.bound_fitness)):
            if value not in FITNESS_QUANTITY:
                raise InputError(
                    f"{key} must be one of {', '.join(FITNESS_QUANTITY)}, got {value!r}"
                )
        if self.fitness_runs not in FITNESS_RUNS:
            raise InputError(
                f"fitness_runs must be one of {', '.join(FITNESS_RUNS)}, got {self.fitness_runs!r}"
            )

    @property
    def custom_loop(self) -> bool:
        """True when the runner's rows cannot express the alternative (own scoring loop)."""
        scalings = {self.fitness, self.bound_fitness}
        return not scalings <= RUNNER_SCALINGS or self.warmup > 0

    @property
    def bound_fitness(self) -> str:
        """The scaling of Table 5's F0 columns: ``fitness_bound``, or ``fitness``."""
        return self.fitness_bound if self.fitness_bound is not None else self.fitness

    @property
    def f_lsm_method(self) -> str:
        """The method behind Table 5's F_LSM: ``f_lsm``, or ``lsm`` when it is not given."""
        return self.f_lsm if self.f_lsm is not None else self.lsm

    def describe(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "overrides": {k: v for k, v in self.overrides},
            "reference": dict(self.reference) if self.reference else None,
            "pooled": self.pooled,
            "structure": self.structure,
            "lsm": self.lsm,
            "f_inv": self.f_inv,
            "eq15": self.eq15,
            "table2": self.table2,
            "fitness": self.fitness,
            "fitness_bound": self.fitness_bound,
            "fitness_runs": self.fitness_runs,
            "f_lsm": self.f_lsm,
            "snr": self.snr,
            "warmup": self.warmup,
        }


def scenario_spec(config: Config, sigma2: float) -> dict[str, Any]:
    """The paper's spec with the config's overrides at noise level ``sigma2``."""
    import copy

    from hbench.sim import scenarios

    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    if config.reference is not None:
        spec["reference"] = dict(config.reference)
    for key, value in config.overrides:
        if key.split(".")[0] == "noise" and key.split(".")[-1] in ("sigma2", "snr"):
            raise InputError(
                f"--set {key}: the noise level is the reproduction's axis; it cannot be overridden"
            )
        if key.endswith(".name"):
            group = key.split(".")[0]
            spec[group] = {
                k: v
                for k, v in spec.get(group, {}).items()
                if group == "noise" and k in ("sigma2", "snr")
            }
        scenarios.set_dotted(spec, key, copy.deepcopy(value))
    spec["noise"].pop("snr", None)
    spec["noise"]["sigma2"] = float(sigma2)
    if config.warmup > 0:
        spec["duration"] = float(spec.get("duration", 500.0)) + float(config.warmup)
    return spec


def level_seed(seed: int, sigma2: float) -> Any:
    """The level's seed: from the base seed and sigma^2 only (common random numbers across
    alternatives and independent of which other levels run)."""
    from hbench.sim.seeding import cell_seed

    return cell_seed(seed, {"experiment": "paper_section6", "sigma2": float(sigma2)})


def _lsm_options(config: Config) -> dict[str, Any]:
    """``wang-lsm``'s options under ``config``."""
    return {"pooled": config.pooled, "eq15": config.eq15}


def _wang_options(config: Config, name: str) -> dict[str, Any]:
    """A Wang method's options under ``config`` (``wang-lsm``'s with its ``eq15``)."""
    return _lsm_options(config) if name == "wang-lsm" else {"pooled": config.pooled}


def make_methods(config: Config, names: Sequence[str]) -> dict[str, Any]:
    """Instantiated methods; the Wang methods with the config's ``pooled`` (and ``eq15``), an
    inverse variant with its method's options and ``inverse='auto'``."""
    from hbench.bench.runner import methods_from_names

    out: dict[str, Any] = {}
    for name in names:
        if name in INVERSE_VARIANTS:  # the estimates in the direct inverse (F_INV)
            base = INVERSE_VARIANTS[name]
            kw = {**_wang_options(config, base), "inverse": "auto"}
            out[name] = methods_from_names([base], {base: kw})[base]
        elif name in WANG_VARIANTS:
            kw = {**_wang_options(config, "wang"), **WANG_VARIANTS[name]}
            out[name] = methods_from_names(["wang"], {"wang": kw})["wang"]
        elif name in ("wang-lsm", "wang-iv", "wang"):
            out.update(methods_from_names([name], {name: _wang_options(config, name)}))
        else:
            out.update(methods_from_names([name]))
    return out


@dataclass(frozen=True)
class LevelTask:
    config: Config
    sigma2: float
    runs: int
    seed: int
    structure: tuple[int, int, int]
    methods: tuple[str, ...]
    keep_example: bool = False


def _options(scenario: Any, config: Config, structure: tuple[int, int, int]) -> Any:
    from hbench.ident.identifiers import IdentifyOptions

    m = scenario.discrete_plant.delay_multiple(scenario.p)
    if config.structure == "selected":
        return IdentifyOptions(delay_multiple=m)
    na, tau, nb = structure
    return IdentifyOptions(na=na, tau=tau, nb=nb, delay_multiple=m)


def cell_name(sigma2: float) -> str:
    return f"paper-sigma2={sigma2:g}"


def run_level(task: LevelTask) -> tuple[Any, dict[str, Any], float]:
    """Rows (tidy), run 0's example and the wall time of one noise level."""
    from hbench.bench.runner import run_cell

    t0 = time.perf_counter()
    scenario, methods, seed, options = _level_inputs(task)
    if task.config.custom_loop:
        rows = _custom_rows(
            scenario, methods, task.runs, seed, options, task.config, cell_name(task.sigma2)
        )
        example: dict[str, Any] = {}
    else:
        res = run_cell(
            scenario,
            methods,
            task.runs,
            seed,
            options,
            cell=cell_name(task.sigma2),
            keep_example=task.keep_example,
        )
        rows, example = res.rows, res.example
    return rows, _labelled(example, task, scenario), time.perf_counter() - t0


def _level_inputs(task: LevelTask) -> tuple[Any, dict[str, Any], Any, Any]:
    """A level's scenario, methods, seed and identification options (:func:`run_level` and
    :func:`run_level_part` compute from the same)."""
    from hbench.sim import scenarios

    config = task.config
    scenario = scenarios.build(scenario_spec(config, task.sigma2))
    methods = make_methods(config, task.methods)
    return (
        scenario,
        methods,
        level_seed(task.seed, task.sigma2),
        _options(scenario, config, task.structure),
    )


def _labelled(example: dict[str, Any], task: LevelTask, scenario: Any) -> dict[str, Any]:
    """A level's example (empty: none kept) with its cell, valve class and noise level."""
    if example:
        example.update(
            cell=cell_name(task.sigma2), nonlinearity=scenario.nonlinearity.name, sigma2=task.sigma2
        )
    return example


def _custom_rows(
    scenario: Any,
    methods: Mapping[str, Any],
    runs: int,
    seed: Any,
    options: Any,
    config: Config,
    cell: str,
) -> Any:
    """Tables 4/5 quantities for alternatives the runner cannot score (ls-affine or gain-centred
    fitness, a discarded warm-up): simulate exactly as the runner does, trim, identify, score."""
    from dataclasses import replace as dc_replace

    import numpy as np
    import pandas as pd

    from hbench.bench.metrics import SCALINGS, fitnesses
    from hbench.ident.identifiers import identify, run_status
    from hbench.sim.simulate import simulate

    record, truth = simulate(scenario, runs, np.random.default_rng(seed))
    if config.warmup > 0:
        kw = round(config.warmup / scenario.T)
        p = record.p
        record = dc_replace(
            record,
            y=record.y[:, kw * p :],
            x=record.x[:, kw:],
            r=None if record.r is None else record.r[:, kw:],
        )
        y0, v = truth.y0[:, kw * p :], truth.v[:, kw * p :]
        nv = np.linalg.norm(v, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            snr = np.where(nv > 0, np.linalg.norm(y0, axis=1) / nv, np.inf)
        truth = dc_replace(truth, U=truth.U[:, kw:], y0=y0, v=v, snr=snr)
    frames = []
    gain = truth.plant.gain
    true = truth.plant.true_params()
    for name, method in methods.items():
        est = identify(method, record, options, truth)
        q: dict[str, np.ndarray] = dict(est.params())
        F = fitnesses(est.U, truth.U, SCALINGS, gain)
        q["fitness"], q["fitness_ls"], q["fitness_ls_affine"] = F["gain"], F["ls"], F["ls-affine"]
        q["fitness_gain_centred"] = F["gain-centred"]
        status, _ = run_status(est)  # as the benchmark cells count runs
        for quantity, values in q.items():
            frames.append(
                pd.DataFrame(
                    {
                        "cell": cell,
                        "method": name,
                        "sigma2": scenario.sigma2,
                        "run": np.arange(runs),
                        "quantity": quantity,
                        "value": np.asarray(values, float),
                        "true": true.get(quantity, np.nan),
                        "snr": truth.snr,
                        "status": status,
                    }
                )
            )
    return pd.concat(frames, ignore_index=True)


def run_tables12(config: Config, runs: int, seed: int) -> dict[str, Any]:
    """Tables 1 and 2 from the first ``runs`` realisations at sigma^2 = 1e-3 (run 0 is shown)."""
    import numpy as np

    from hbench.bench.runner import methods_from_names
    from hbench.ident.identifiers import IdentifyOptions, identify
    from hbench.sim import scenarios
    from hbench.sim.simulate import simulate

    t0 = time.perf_counter()
    scenario = scenarios.build(scenario_spec(config, TYPICAL_LEVEL))
    record, truth = simulate(scenario, runs, np.random.default_rng(level_seed(seed, TYPICAL_LEVEL)))
    if config.warmup > 0:
        from dataclasses import replace as dc_replace

        kw = round(config.warmup / scenario.T)
        record = dc_replace(
            record, y=record.y[:, kw * record.p :], x=record.x[:, kw:], r=record.r[:, kw:]
        )
    options = IdentifyOptions(delay_multiple=scenario.discrete_plant.delay_multiple(scenario.p))
    methods = methods_from_names(
        ["wang-lsm", "wang-iv"],
        {
            "wang-lsm": _lsm_options(config),
            "wang-iv": {"pooled": config.pooled, "structure": "iv"},
        },
    )
    lsm = identify(methods["wang-lsm"], record, options, truth)
    iv = identify(methods["wang-iv"], record, options, truth)
    sel = {}
    for name, est in (("wang-lsm", lsm), ("wang-iv", iv)):
        pick = (int(est.na[0]), int(est.tau[0]), int(est.nb[0]))
        agree = (est.na == pick[0]) & (est.tau == pick[1]) & (est.nb == pick[2])
        sel[name] = {
            "na": pick[0],
            "tau": pick[1],
            "nb": pick[2],
            "share_of_runs": float(np.mean(agree)),
        }
    return {
        "V": {"wang-lsm": lsm.criteria["V"], "wang-iv": iv.criteria["V"]},
        "na_values": np.asarray(lsm.criteria["na_values"]),
        "var_dw": lsm.criteria["var_dw"],
        "selection": sel,
        "runs": runs,
        "snr": float(truth.snr[0]),
        "seconds": time.perf_counter() - t0,
    }


#: Runs of one part of a level computed by a worker process (two chunks of the runner's 200):
#: the parts of every level shared by the workers keep them busy together to the end.
PART_RUNS = 400


def _level_parts(task: LevelTask) -> list[list[tuple[int, int]]]:
    """The level's runs as parts of consecutive runner chunks (``(start, n)`` each), at most
    :data:`PART_RUNS` runs per part; one part for a level whose rows the runner cannot give."""
    if task.config.custom_loop:
        return [[(0, task.runs)]]
    from hbench.bench.runner import chunks_of

    parts: list[list[tuple[int, int]]] = [[]]
    for piece in chunks_of(task.runs):
        if parts[-1] and sum(n for _, n in parts[-1]) + piece[1] > PART_RUNS:
            parts.append([])
        parts[-1].append(piece)
    return parts


def run_level_part(
    task: LevelTask, pieces: Sequence[tuple[int, int]]
) -> tuple[Any, dict[str, Any], float]:
    """Part of a level: the tidy blocks of the runs of ``pieces`` (:func:`hbench.bench.runner.
    cell_blocks`), the example if run 0 is among them, and the part's wall time. A level the
    runner cannot score (:attr:`Config.custom_loop`) is one part: its rows whole
    (:func:`run_level`)."""
    if task.config.custom_loop:
        return run_level(task)
    from hbench.bench.runner import cell_blocks, cell_work

    t0 = time.perf_counter()
    scenario, methods, seed, options = _level_inputs(task)
    work = cell_work(
        scenario,
        methods,
        seed,
        options,
        cell=cell_name(task.sigma2),
        keep_example=task.keep_example,
    )
    blocks, example = cell_blocks(work, pieces)
    return blocks, _labelled(example, task, scenario), time.perf_counter() - t0


def _joined(
    task: LevelTask, parts: list[tuple[Any, dict[str, Any], float]]
) -> tuple[Any, dict[str, Any], float]:
    """A level's result from its parts' (in run order): :func:`run_level`'s rows, example and
    the sum of the parts' times."""
    if task.config.custom_loop:
        return parts[0]
    from hbench.bench import tidy

    blocks = [b for part in parts for b in part[0]]
    example = next((part[1] for part in parts if part[1]), {})
    return tidy.assemble(blocks), example, sum(part[2] for part in parts)


def run_levels(
    tasks: Sequence[LevelTask],
    jobs: int,
    progress: Callable[[LevelTask, float], None] | None = None,
    while_waiting: Callable[[], Any] | None = None,
    on_result: Callable[[LevelTask, tuple[Any, dict[str, Any], float]], Any] | None = None,
) -> list[tuple[Any, dict[str, Any], float]]:
    """Run the tasks (in ``jobs`` worker processes of :func:`hbench.bench.parallel.pool` when
    ``jobs > 1``, each level cut into parts of at most :data:`PART_RUNS` runs, which the
    workers take in task order: the rows are those of one process), in task order;
    ``while_waiting()`` runs in the parent meanwhile (e.g. an import the next step needs), then
    ``on_result(task, result)`` for each level as soon as all its parts are in (e.g. a figure
    of one level drawn while the workers compute the others)."""
    if jobs <= 1 or len(tasks) <= 1:
        if while_waiting:
            while_waiting()
        out = []
        for task in tasks:
            res = run_level(task)
            if progress:
                progress(task, res[2])
            if on_result:
                on_result(task, res)
            out.append(res)
        return out
    from concurrent.futures import as_completed

    from hbench.bench import parallel

    parts = [_level_parts(task) for task in tasks]
    done: list[dict[int, tuple[Any, dict[str, Any], float]]] = [{} for _ in tasks]
    results: dict[int, tuple[Any, dict[str, Any], float]] = {}
    with parallel.pool(jobs) as pool:
        futures = {
            pool.submit(run_level_part, task, pieces): (i, k)
            for i, task in enumerate(tasks)
            for k, pieces in enumerate(parts[i])
        }
        if while_waiting:
            while_waiting()
        for fut in as_completed(futures):
            i, k = futures[fut]
            done[i][k] = fut.result()
            if len(done[i]) < len(parts[i]):
                continue
            results[i] = _joined(tasks[i], [done[i][k] for k in range(len(parts[i]))])
            if progress:
                progress(tasks[i], results[i][2])
            if on_result:
                on_result(tasks[i], results[i])
    return [results[i] for i in range(len(tasks))]


_T0 = time.perf_counter()


def log(msg: str) -> None:
    """Progress on stderr, stamped with the seconds since the module was imported."""
    print(f"reproduce [{time.perf_counter() - _T0:5.1f} s]: {msg}", file=sys.stderr, flush=True)


def level_tasks(
    config: Config,
    runs: int,
    seed: int,
    structure: tuple[int, int, int],
    methods: Sequence[str],
    keep_example: bool = True,
) -> list[LevelTask]:
    """One task per noise level, the typical level first (it carries the figures' example)."""
    levels = sorted(LEVELS, key=lambda s: (s != TYPICAL_LEVEL, s == 0.0, s))
    return [
        LevelTask(
            config,
            s2,
            min(runs, NOISE_FREE_RUNS) if s2 == 0 else runs,
            seed,
            structure,
            tuple(methods),
            keep_example and s2 == TYPICAL_LEVEL,
        )
        for s2 in levels
    ]
