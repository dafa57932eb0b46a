"""``hbench reproduce``: the paper's Section 6 example beside its published Tables 1, 2, 4 and 5.

What runs (the defaults, and why):

* The scenario is :data:`hbench.scenarios.PAPER_SECTION6` (``--set KEY=VALUE`` overrides a key) at
  the noise levels of Tables 4 and 5, sigma^2 = 0, 1e-4, 5e-4, 1e-3, 5e-3, 1e-2, ``--runs`` Monte
  Carlo runs each (100 by default, as in the paper; the noise-free level needs at most 10: every
  estimate is exact there).
* Tables 1 and 2 come from one realisation at sigma^2 = 1e-3: run 0 of that level's Monte Carlo
  batch (the same realisation as Figures 4 and 5). ``V`` is the bias-compensated LSM's table of
  eq. (19) (``wang-lsm``) and the IVM's own table (``wang-iv`` with ``structure="iv"``);
  Table 2 is the LSM's ``Var{Delta w^(l)}``. The structure they select (na, tau, nb) is printed.
* The structure is then FIXED to that selection for every Monte Carlo run, as the paper does
  (it illustrates the selection once and reports a1, a2, b2 only in Table 4); ``--structure
  selected`` selects it per run instead.
* Methods: ``wang-lsm`` and ``wang-iv`` with ``pooled=True`` (the denominator from every quiet
  phase nb+1..p: the paper's step (iii) re-estimates A "by taking nb in place of n0_b"; with
  phase p alone the parameter spread is about twice the published one), ``bai-fu``,
  ``sun-liu-sano`` (a reconstruction), ``oracle``, ``oracle-inv``, ``wang`` (the paper's steps
  (ii) and (iv): per run, A from the LSM or the IVM by the integrated AIC and each b_l by V_EIV;
  scored beside the LSM rows in ``steps.csv`` and ``summary.txt``) and ``wang-lsm-inv`` -- the
  LSM's estimates put in the direct inverse A(q)/B(q) y, defined here. Table 5's columns are
  F_LSM = ``wang-lsm``, F0_LSM = ``oracle``, F_INV = ``wang-lsm-inv``, F0_INV = ``oracle-inv``:
  the paper's text compares eq. (27) with the direct inverse for the same estimated G(q)
  ("Eq. (27) reduces the noise effect ..."), and ``bai-fu``'s ordinary least squares is biased
  under noise (its fitness is reported beside, not as F_INV; ``--investigate`` tests that mapping).
* Fitness is the paper's: the blind estimate scaled by the true gain b1 ("the gain of G(q) is
  assumed to be known").

The comparison (``reproduce.csv``, the contract's columns) gives, per published cell,
``z = (ours - paper) / SE`` with ``SE^2 = s_ours^2 / n + s_paper^2 / n_paper + u^2 / 12``: ``s``
the standard deviations over runs, ``n`` and ``n_paper`` the runs behind each mean (100 in the
paper), ``u`` the rounding unit of the printed number (its last digit). A spread that is not
known is taken equal to the other side's (the null hypothesis of one common distribution):
``s_paper = s_ours`` where the paper prints none (SNR, F0_LSM, F0_INV, Tables 1 and 2),
``s_ours = s_paper`` after a single run. Tables 1 and 2 are single realisations: ``n = n_paper =
1`` and ``s_ours`` is the standard deviation over the first realisations of the level (up to 20),
so ``SE^2 = 2 s^2 + u^2/12``. z is undefined (empty) where a value is infinite (the SNR at
sigma^2 = 0) or no spread is known. The summary gives the share of scored cells with
``|z| <= 2`` and lists every cell beyond.

``--investigate`` re-runs Tables 4 and 5 (and Tables 1 and 2) under alternative conventions and
writes ``investigation.csv``: which alternative moves which cells toward the paper, and by how
much (mean |z| per table before and after, and the ratio of our spreads to the published ones);
``investigation_cells.csv`` lists, per cell beyond ``|z| = 2`` under the defaults, the
alternatives under which it is within (a cell near 2 is moved within by many of them by chance;
a cell far beyond by one, and only one, names its likely cause).

What ``--investigate`` finds under the defaults (100 runs, seed 20070601), and the command that
produces it: ``docs/experiments/reproduce-investigation.md``.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
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
#: The paper's steps (ii) and (iv) one at a time: ``wang`` with one choice left to the LSM
#: (names the reproduction gives these variants; ``wang`` makes both choices).
WANG_VARIANTS: dict[str, dict[str, str]] = {
    "wang-step-ii": {"select_b": "lsm"},
    "wang-step-iv": {"select_a": "lsm"},
}
#: Table 5's columns -> (contract column, method); F_LSM's method follows ``Config.lsm`` (as
#: Table 4's LSM rows do), F_INV's ``Config.f_inv``.
TABLE5_COLUMNS: dict[str, tuple[str, str]] = {
    "F_LSM": ("F", "wang-lsm"),
    "F0_LSM": ("F0", "oracle"),
    "F_INV": ("F", "wang-lsm-inv"),
    "F0_INV": ("F0", "oracle-inv"),
}
CSV_COLUMNS = ["table", "row", "column", "method", "paper", "paper_std", "ours", "ours_std", "z"]
FITNESS_QUANTITY = {"gain": "fitness", "ls": "fitness_ls", "ls-affine": "fitness_ls_affine"}
Z_LIMIT = 2.0


# --------------------------------------------------------------------------- published tables


@functools.lru_cache(maxsize=1)
def paper_data() -> dict[str, Any]:
    """The published tables (``hbench/data/paper_tables.json``), values as printed strings."""
    from importlib import resources

    text = resources.files("hbench").joinpath("data", "paper_tables.json").read_text("utf-8")
    return json.loads(text)


#: The investigation table's columns as shown (summary and report).
INVESTIGATION_COLUMNS = (
    "alternative",
    "group",
    "mean_abs_z_before",
    "mean_abs_z_after",
    "T4-params_after",
    "T4-snr_after",
    "T5_after",
    "T1_after",
    "T2_after",
    "std_ratio_T4-params_after",
    "std_ratio_T5_after",
    "within2_after",
    "cells_closer",
    "cells_further",
    "moved_most",
)


def parse_printed(text: str | None) -> tuple[float, float]:
    """``(value, unit)`` of a printed number: ``"0.9623" -> (0.9623, 1e-4)``, ``"inf" -> (inf, 0)``.

    ``unit`` is the rounding unit of the last printed digit (``nan`` for a missing value).
    """
    if text is None:
        return math.nan, math.nan
    s = str(text).strip()
    if s.lower() in ("inf", "infinity", "∞"):
        return math.inf, 0.0
    value = float(s)
    mantissa = s.lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    exp = int(s.lower().split("e")[1]) if "e" in s.lower() else 0
    return value, 10.0 ** (exp - decimals)


@dataclass(frozen=True)
class PaperCell:
    """One published cell: ``table, row, column, method`` and the printed mean, std and unit."""

    table: int
    row: float
    column: str
    method: str
    value: float
    std: float
    unit: float
    n: int


def paper_cells() -> list[PaperCell]:
    """Every published cell of Tables 1, 2, 4 (with its SNR column) and 5, in plain units."""
    d = paper_data()
    n_mc = int(d["monte_carlo_runs"])
    cells: list[PaperCell] = []
    t1 = d["table1"]
    for row in t1["rows"]:
        for tau, text in zip(t1["tau"], row["values"], strict=True):
            v, u = parse_printed(text)
            cells.append(
                PaperCell(
                    1,
                    row["na"],
                    str(tau),
                    row["method"],
                    v * t1["unit"],
                    math.nan,
                    u * t1["unit"],
                    1,
                )
            )
    t2 = d["table2"]
    for l, text in zip(t2["l"], t2["values"], strict=True):
        v, u = parse_printed(text)
        cells.append(
            PaperCell(2, l, "var_dw", t2["method"], v * t2["unit"], math.nan, u * t2["unit"], 1)
        )
    for row in d["table4"]["rows"]:
        s2 = float(row["sigma2"])
        n = n_mc if s2 > 0 else 1
        v, u = parse_printed(row["snr"])
        cells.append(PaperCell(4, s2, "snr", "scenario", v, math.nan, u, n))
        for method in ("wang-lsm", "wang-iv"):
            for param, (mean, std) in row[method].items():
                v, u = parse_printed(mean)
                s = parse_printed(std)[0] if std is not None else (0.0 if s2 == 0 else math.nan)
                cells.append(PaperCell(4, s2, param, method, v, s, u, n))
    for row in d["table5"]["rows"]:
        s2 = float(row["sigma2"])
        n = n_mc if s2 > 0 else 1
        for col, (column, method) in TABLE5_COLUMNS.items():
            mean, std = row[col]
            v, u = parse_printed(mean)
            s = parse_printed(std)[0] if std is not None else (0.0 if s2 == 0 else math.nan)
            cells.append(PaperCell(5, s2, column, method, v, s, u, n))
    return cells


# --------------------------------------------------------------------------- z and summary


def standard_error(
    ours_std: float, n: int, paper_std: float, n_paper: int, unit: float = 0.0
) -> float:
    """``sqrt(s_o^2/n + s_p^2/n_p + u^2/12)``. A spread that is not known (the paper prints
    none, or a single run of ours) is taken equal to the other side's (the null hypothesis of
    one common distribution); ``nan`` when neither is known."""
    if not math.isfinite(paper_std):
        paper_std = ours_std
    if not math.isfinite(ours_std):
        ours_std = paper_std
    if n < 1 or n_paper < 1:
        return math.nan
    u = unit if math.isfinite(unit) else 0.0
    return math.sqrt(ours_std**2 / n + paper_std**2 / n_paper + u**2 / 12.0)


def z_score(
    ours: float,
    ours_std: float,
    n: int,
    paper: float,
    paper_std: float,
    n_paper: int,
    unit: float = 0.0,
) -> float:
    """``(ours - paper) / SE`` (see :func:`standard_error`); ``nan`` where undefined."""
    if not (math.isfinite(ours) and math.isfinite(paper)):
        return math.nan
    se = standard_error(ours_std, n, paper_std, n_paper, unit)
    if not math.isfinite(se) or se <= 0.0:
        return math.nan
    return (ours - paper) / se


@dataclass
class Summary:
    """Share of scored cells with ``|z| <= limit`` and the cells beyond."""

    scored: int
    within: int
    unscored: int
    beyond: list[dict[str, Any]] = field(default_factory=list)
    limit: float = Z_LIMIT

    @property
    def share(self) -> float:
        return self.within / self.scored if self.scored else math.nan

    def line(self) -> str:
        pct = f"{100 * self.share:.0f} %" if self.scored else "n/a"
        return (
            f"{self.within} of {self.scored} scored cells ({pct}) within |z| <= {self.limit:g}; "
            f"{len(self.beyond)} beyond; {self.unscored} not scored (z undefined)"
        )

    def text(self) -> str:
        lines = [self.line()]
        if self.beyond:
            lines.append(f"cells beyond |z| = {self.limit:g} (largest first):")
            lines += ["  " + describe_cell(c) for c in self.beyond]
        return "\n".join(lines) + "\n"


def _fmt_num(v: float) -> str:
    if not isinstance(v, int | float) or not math.isfinite(v):
        return str(v)
    return f"{v:.4g}" if (abs(v) >= 1e-3 or v == 0) else f"{v:.4e}"


def describe_cell(c: Mapping[str, Any]) -> str:
    """One line per cell, e.g. ``T4 wang-lsm a1 @ sigma2=0.001: ours -1.964 +- 0.0051 vs paper
    -1.965 +- 0.0054, z = +0.9`` (Table 1: ``na=2 tau=3``; Table 2: ``l=1``)."""
    ours = _fmt_num(float(c["ours"]))
    if math.isfinite(float(c.get("ours_std", math.nan))):
        ours += f" +- {_fmt_num(float(c['ours_std']))}"
    paper = _fmt_num(float(c["paper"]))
    if math.isfinite(float(c.get("paper_std", math.nan))):
        paper += f" +- {_fmt_num(float(c['paper_std']))}"
    table = int(c["table"])
    if table == 1:
        where = f"V na={int(c['row'])} tau={c['column']}"
    elif table == 2:
        where = f"var_dw l={int(c['row'])}"
    else:
        where = f"{c['column']} @ sigma2={float(c['row']):g}"
    return f"T{table} {c['method']} {where}: ours {ours} vs paper {paper}, z = {float(c['z']):+.1f}"


def summarise(frame: Any, limit: float = Z_LIMIT) -> Summary:
    """:class:`Summary` of a ``reproduce.csv`` frame (rows with a finite ``z`` are scored)."""
    import numpy as np

    z = frame["z"].to_numpy(dtype=float)
    finite = np.isfinite(z)
    beyond = frame[finite & (np.abs(z) > limit)].copy()
    beyond = beyond.iloc[np.argsort(-np.abs(beyond["z"].to_numpy(dtype=float)), kind="stable")]
    return Summary(
        scored=int(finite.sum()),
        within=int((finite & (np.abs(z) <= limit)).sum()),
        unscored=int((~finite).sum()),
        beyond=beyond.to_dict("records"),
        limit=limit,
    )


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class Config:
    """One reproduction's conventions (the default, or an alternative of ``--investigate``).

    ``overrides`` are dotted scenario keys (``("reference.band", [0, 0.25])``); ``reference``
    replaces the whole reference spec when given. ``fitness`` is the scaling of Table 5
    (``gain``, ``ls``, ``ls-affine``), ``snr`` the definition compared with the SNR column
    (``norm``: ||y0||/||v||, ``power``: its square, ``db``: 20 log10), ``warmup`` seconds simulated
    before the 500 s record and discarded. ``lsm`` is the method behind Table 4's LSM rows and
    Table 5's F_LSM (``wang`` or a :data:`WANG_VARIANTS` name for the paper's steps (ii), (iv)).
    ``eq15`` is ``wang-lsm``'s reading of eq. (15) where it has no real root (``clip``,
    ``real``, ``modulus``, ``zero``: :func:`hbench.polyphase.noise_variance`); ``table2`` how
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
    snr: str = "norm"
    warmup: float = 0.0

    @property
    def custom_loop(self) -> bool:
        """True when the runner's rows cannot express the alternative (own scoring loop)."""
        return self.fitness == "ls-affine" or self.warmup > 0

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
            "snr": self.snr,
            "warmup": self.warmup,
        }


def scenario_spec(config: Config, sigma2: float) -> dict[str, Any]:
    """The paper's spec with the config's overrides at noise level ``sigma2``."""
    import copy

    from hbench import scenarios

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
    from hbench.seeding import cell_seed

    return cell_seed(seed, {"experiment": "paper_section6", "sigma2": float(sigma2)})


def _lsm_options(config: Config) -> dict[str, Any]:
    """``wang-lsm``'s options under ``config``."""
    return {"pooled": config.pooled, "eq15": config.eq15}


def make_methods(config: Config, names: Sequence[str]) -> dict[str, Any]:
    """Instantiated methods; the Wang methods with the config's ``pooled``."""
    from hbench.runner import methods_from_names

    out: dict[str, Any] = {}
    for name in names:
        if name == "wang-lsm-inv":  # the LSM estimates in the direct inverse (F_INV)
            kw = {"pooled": config.pooled, "inverse": "auto"}
            out[name] = methods_from_names(["wang-lsm"], {"wang-lsm": kw})["wang-lsm"]
        elif name in WANG_VARIANTS:
            kw = {"pooled": config.pooled, **WANG_VARIANTS[name]}
            out[name] = methods_from_names(["wang"], {"wang": kw})["wang"]
        elif name == "wang-lsm":
            out.update(methods_from_names([name], {name: _lsm_options(config)}))
        elif name in ("wang-iv", "wang"):
            out.update(methods_from_names([name], {name: {"pooled": config.pooled}}))
        else:
            out.update(methods_from_names([name]))
    return out


# --------------------------------------------------------------------------- simulation tasks


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
    from hbench.identifiers import IdentifyOptions

    m = scenario.discrete_plant.delay_multiple(scenario.p)
    if config.structure == "selected":
        return IdentifyOptions(delay_multiple=m)
    na, tau, nb = structure
    return IdentifyOptions(na=na, tau=tau, nb=nb, delay_multiple=m)


def cell_name(sigma2: float) -> str:
    return f"paper-sigma2={sigma2:g}"


def run_level(task: LevelTask) -> tuple[Any, dict[str, Any], float]:
    """Rows (tidy), run 0's example and the wall time of one noise level."""
    from hbench import scenarios
    from hbench.runner import run_cell

    t0 = time.perf_counter()
    config = task.config
    scenario = scenarios.build(scenario_spec(config, task.sigma2))
    methods = make_methods(config, task.methods)
    options = _options(scenario, config, task.structure)
    seed = level_seed(task.seed, task.sigma2)
    if config.custom_loop:
        rows = _custom_rows(
            scenario, methods, task.runs, seed, options, config, cell_name(task.sigma2)
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
    if example:
        example.update(
            cell=cell_name(task.sigma2), nonlinearity=scenario.nonlinearity.name, sigma2=task.sigma2
        )
    return rows, example, time.perf_counter() - t0


def _custom_rows(
    scenario: Any,
    methods: Mapping[str, Any],
    runs: int,
    seed: Any,
    options: Any,
    config: Config,
    cell: str,
) -> Any:
    """Tables 4/5 quantities for alternatives the runner cannot score (ls-affine fitness, a
    discarded warm-up): simulate exactly as the runner does, trim, identify, score."""
    from dataclasses import replace as dc_replace

    import numpy as np
    import pandas as pd

    from hbench.identifiers import identify, run_status
    from hbench.metrics import SCALINGS, fitnesses
    from hbench.simulate import simulate

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

    from hbench import scenarios
    from hbench.identifiers import IdentifyOptions, identify
    from hbench.runner import methods_from_names
    from hbench.simulate import simulate

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


def run_levels(
    tasks: Sequence[LevelTask],
    jobs: int,
    progress: Callable[[LevelTask, float], None] | None = None,
    while_waiting: Callable[[], Any] | None = None,
    on_result: Callable[[LevelTask, tuple[Any, dict[str, Any], float]], Any] | None = None,
) -> list[tuple[Any, dict[str, Any], float]]:
    """Run the tasks (in ``jobs`` forked worker processes when ``jobs > 1``), in task order;
    ``while_waiting()`` runs in the parent meanwhile (e.g. an import the next step needs), then
    ``on_result(task, result)`` for each result as it comes in (e.g. a figure of one level
    drawn while the workers compute the others)."""
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
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = multiprocessing.get_context("fork")
    results: dict[int, tuple[Any, dict[str, Any], float]] = {}
    with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
        futures = {pool.submit(run_level, task): i for i, task in enumerate(tasks)}
        if while_waiting:
            while_waiting()
        for fut in as_completed(futures):
            i = futures[fut]
            results[i] = fut.result()
            if progress:
                progress(tasks[i], results[i][2])
            if on_result:
                on_result(tasks[i], results[i])
    return [results[i] for i in range(len(tasks))]


# --------------------------------------------------------------------------- comparison


def _stats(values: Any) -> tuple[float, float, int]:
    import numpy as np

    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    n = int(v.size)
    if n == 0:
        return math.nan, math.nan, 0
    with np.errstate(invalid="ignore"):
        mean = float(np.mean(v))
        std = float(np.std(v, ddof=1)) if n > 1 else math.nan
    if n > 1 and np.all(v == v[0]):
        std = 0.0
    return mean, std, n


def _snr_as(per_run: Any, definition: str) -> Any:
    """Per-run SNRs ``||y0|| / ||v||`` under ``definition`` (``norm``, ``power``, ``db``)."""
    import numpy as np

    if definition == "norm":
        return per_run
    if definition == "power":
        return per_run**2
    if definition == "db":
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(per_run)
    raise InputError(f"unknown SNR definition {definition!r} (norm, power, db)")


def snr_values(rows: Any, sigma2: float, definition: str = "norm") -> Any:
    """Per-run SNR at a level (one value per run, in the order the runs first appear), under
    ``definition``."""
    import numpy as np

    sub = rows[np.isclose(rows["sigma2"].astype(float), sigma2, rtol=1e-9, atol=0.0)]
    return _snr_as(sub.drop_duplicates("run")["snr"].to_numpy(dtype=float), definition)


@dataclass(frozen=True)
class LevelValues:
    """What Tables 4 and 5 read from the tidy rows, gathered in one pass: ``values[(sigma2,
    method, quantity)]`` the ``ok`` runs' values and ``snr[sigma2]`` the per-run SNRs (every
    run, in the order the runs first appear), at the paper's levels (matched to rtol 1e-9).
    Every comparison of one set of rows (the defaults, the steps, the post-processed
    alternatives) reads the same object instead of filtering the rows again."""

    values: dict[tuple[float, str, str], Any]
    snr: dict[float, Any]

    @classmethod
    def of(cls, rows: Any) -> LevelValues:
        import numpy as np

        sigma2 = rows["sigma2"].to_numpy(dtype=float)
        value = rows["value"].to_numpy(dtype=float)
        ok = (rows["status"] == "ok").to_numpy(dtype=bool)
        levels = sorted({c.row for c in paper_cells() if c.table in (4, 5)})
        at = {s2: np.isclose(sigma2, s2, rtol=1e-9, atol=0.0) for s2 in levels}
        values = {}
        for (method, quantity), idx in rows.groupby(
            ["method", "quantity"], sort=False
        ).indices.items():
            idx = idx[ok[idx]]  # row order, as filtering the frame keeps it
            for s2 in levels:
                sel = idx[at[s2][idx]]
                if sel.size:
                    values[(s2, str(method), str(quantity))] = value[sel]
        run = rows["run"].to_numpy()
        snr_all = rows["snr"].to_numpy(dtype=float)
        snr = {}
        for s2 in levels:
            idx = np.flatnonzero(at[s2])
            first = np.unique(run[idx], return_index=True)[1]
            snr[s2] = snr_all[idx[np.sort(first)]]
        return cls(values, snr)


def compare_tables45(rows: Any, config: Config = Config()) -> Any:
    """``reproduce.csv`` rows of Tables 4 (with its SNR column) and 5 from tidy rows (or their
    :class:`LevelValues`, gathered once for several comparisons)."""
    import numpy as np
    import pandas as pd

    lv = rows if isinstance(rows, LevelValues) else LevelValues.of(rows)
    values = lv.values
    fq = FITNESS_QUANTITY[config.fitness]
    out = []
    for cell in paper_cells():
        if cell.table not in (4, 5):
            continue
        if cell.column == "snr":
            vals = _snr_as(lv.snr.get(cell.row, np.empty(0)), config.snr)
            if vals.size and np.all(np.isinf(vals)):
                mean, std, n = math.inf, math.nan, int(vals.size)
            else:
                mean, std, n = _stats(vals)
        else:
            method = cell.method
            if cell.table == 5 and cell.column == "F" and method == "wang-lsm-inv":
                method = config.f_inv
            elif method == "wang-lsm":
                method = config.lsm
            quantity = fq if cell.table == 5 else cell.column
            mean, std, n = _stats(values.get((cell.row, method, quantity), np.empty(0)))
            cell = replace(cell, method=method)
        z = z_score(
            mean,
            std if math.isfinite(std) else math.nan,
            n,
            cell.value,
            cell.std,
            cell.n,
            cell.unit,
        )
        out.append(
            {
                "table": cell.table,
                "row": cell.row,
                "column": cell.column,
                "method": cell.method,
                "paper": cell.value,
                "paper_std": cell.std,
                "ours": mean,
                "ours_std": std,
                "z": z,
            }
        )
    return pd.DataFrame(out, columns=CSV_COLUMNS)


#: Table 2's rows read with l = 1 and l = 2 exchanged (``Config.table2 = "swapped"``).
_SWAPPED_L = {1: 2, 2: 1}


def compare_tables12(tab: Mapping[str, Any], config: Config = Config()) -> Any:
    """``reproduce.csv`` rows of Tables 1 and 2 (run 0 vs the paper; spread over the runs).

    With ``config.table2 == "swapped"`` the paper's Table 2 row l = 1 is compared with our
    l = 2 and its l = 2 with our l = 1 (the row keeps the paper's l)."""
    import numpy as np
    import pandas as pd

    na_values = list(np.asarray(tab["na_values"]).tolist())
    out = []
    for cell in paper_cells():
        if cell.table == 1:
            V = tab["V"][cell.method]
            if int(cell.row) not in na_values:
                continue
            series = V[:, na_values.index(int(cell.row)), int(cell.column)]
        elif cell.table == 2:
            l = int(cell.row)
            if config.table2 == "swapped":
                l = _SWAPPED_L.get(l, l)
            series = tab["var_dw"][:, l - 1]
        else:
            continue
        ours = float(series[0])
        std = float(np.std(series, ddof=1)) if series.size > 1 else math.nan
        z = z_score(ours, std, 1, cell.value, math.nan, 1, cell.unit)
        out.append(
            {
                "table": cell.table,
                "row": cell.row,
                "column": cell.column,
                "method": cell.method,
                "paper": cell.value,
                "paper_std": math.nan,
                "ours": ours,
                "ours_std": std,
                "z": z,
            }
        )
    return pd.DataFrame(out, columns=CSV_COLUMNS)


def steps_comparison(rows: Any, comparison: Any, config: Config = Config()) -> tuple[Any, str]:
    """The paper's steps (ii) and (iv) on Tables 4 and 5 from tidy rows (or their
    :class:`LevelValues`): the cells of Table 4's LSM rows and of
    F_LSM scored with ``wang`` (A by integrated AIC, b by V_EIV) in place of ``wang-lsm``.

    Returns the ``wang`` cells (``reproduce.csv``'s columns) and a text: the share within
    ``|z| <= 2`` for both methods, and each cell at sigma^2 >= 5e-3 side by side.
    """
    import numpy as np

    steps = compare_tables45(rows, replace(config, lsm="wang"))
    steps = steps[steps["method"] == "wang"].reset_index(drop=True)
    key = ["table", "row", "column"]
    base = comparison[comparison["method"] == config.lsm][[*key, "ours", "ours_std", "z"]]
    m = steps.merge(base, on=key, suffixes=("", "_lsm"), how="left")

    def within(z: Any) -> str:
        z = np.abs(np.asarray(z, dtype=float))
        return f"{int(np.sum(z[np.isfinite(z)] <= Z_LIMIT))} of {int(np.isfinite(z).sum())}"

    lines = [
        "The paper's steps (ii) and (iv) (method wang: A by the integrated AIC, each b_l by "
        "V_EIV, between the LSM and the IVM) in Table 4's LSM rows and F_LSM: "
        f"{within(m['z'])} cells within |z| <= {Z_LIMIT:g} (wang-lsm: {within(m['z_lsm'])}).",
    ]
    for _, c in m[m["row"].astype(float) >= 5e-3].iterrows():
        lines.append(
            f"  {c['column']} @ sigma2={float(c['row']):g}: paper {_fmt_num(c['paper'])}; "
            f"wang {_fmt_num(c['ours'])} +- {_fmt_num(c['ours_std'])} (z {c['z']:+.1f}); "
            f"wang-lsm {_fmt_num(c['ours_lsm'])} +- {_fmt_num(c['ours_std_lsm'])} "
            f"(z {c['z_lsm']:+.1f})"
        )
    return steps, "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- display tables


def _pm(mean: float, std: float, digits: int) -> str:
    if not math.isfinite(mean):
        return "inf" if mean == math.inf else "-"
    s = f"{mean:.{digits}f}"
    if math.isfinite(std):
        s += f" ± {std:.{digits}f}"
    return s


def _with_z(text: str, z: float) -> str:
    return f"{text} (z {z:+.1f})" if math.isfinite(z) else text


def display_tables(frame: Any) -> dict[str, Any]:
    """Side-by-side tables (strings) from a ``reproduce.csv`` frame: ``table1``, ``table2``,
    ``table4``, ``snr``, ``table5`` (each present when the frame has its rows)."""
    import pandas as pd

    out: dict[str, Any] = {}
    f = frame.copy()
    f["row"] = f["row"].astype(float)

    t1 = f[f["table"] == 1]
    if len(t1):
        recs = []
        for (method, na), g in t1.groupby(["method", "row"], sort=False):
            rec = {"method": method, "na": int(na)}
            for _, c in g.iterrows():
                rec[f"tau={c['column']} ours"] = _with_z(f"{c['ours'] / 1e-7:.3f}", c["z"])
                rec[f"tau={c['column']} paper"] = f"{c['paper'] / 1e-7:.3f}"
            recs.append(rec)
        out["table1"] = pd.DataFrame(recs).sort_values(["na", "method"], kind="stable")
    t2 = f[f["table"] == 2]
    if len(t2):
        out["table2"] = pd.DataFrame(
            [
                {
                    "l": int(c["row"]),
                    "ours (x1e-7)": _with_z(f"{c['ours'] / 1e-7:.4f}", c["z"]),
                    "ours std (x1e-7)": f"{c['ours_std'] / 1e-7:.4f}",
                    "paper (x1e-7)": f"{c['paper'] / 1e-7:.5g}",
                }
                for _, c in t2.iterrows()
            ]
        )
    t4 = f[(f["table"] == 4) & (f["column"] != "snr")]
    if len(t4):
        recs = []
        for (s2, method), g in t4.groupby(["row", "method"], sort=True):
            rec = {"sigma2": f"{s2:g}", "method": method}
            for _, c in g.iterrows():
                rec[f"{c['column']} ours"] = _with_z(_pm(c["ours"], c["ours_std"], 4), c["z"])
                rec[f"{c['column']} paper"] = _pm(c["paper"], c["paper_std"], 4)
            recs.append(rec)
        out["table4"] = pd.DataFrame(recs)
    snr = f[f["column"] == "snr"]
    if len(snr):
        out["snr"] = pd.DataFrame(
            [
                {
                    "sigma2": f"{c['row']:g}",
                    "SNR ours": _with_z(_pm(c["ours"], c["ours_std"], 3), c["z"]),
                    "SNR paper": _pm(c["paper"], math.nan, 4),
                    "ratio paper/ours": (
                        f"{c['paper'] / c['ours']:.3f}"
                        if math.isfinite(c["paper"]) and c["ours"]
                        else "-"
                    ),
                }
                for _, c in snr.iterrows()
            ]
        )
    t5 = f[f["table"] == 5]
    if len(t5):
        recs = []
        names = {
            ("F", "wang-lsm"): "F_LSM",
            ("F0", "oracle"): "F0_LSM",
            ("F0", "oracle-inv"): "F0_INV",
        }
        for s2, g in t5.groupby("row", sort=True):
            rec = {"sigma2": f"{s2:g}"}
            for _, c in g.iterrows():
                name = names.get((c["column"], c["method"]), f"F_INV [{c['method']}]")
                rec[f"{name} ours"] = _with_z(_pm(c["ours"], c["ours_std"], 2), c["z"])
                rec[f"{name} paper"] = _pm(c["paper"], c["paper_std"], 2)
            recs.append(rec)
        out["table5"] = pd.DataFrame(recs)
    return out


def display_notes(realisations: int | None = None) -> dict[str, str]:
    """What the ``ours`` cells of each display table hold, for the Markdown headers.

    Tables 1 and 2 show run 0 (one realisation, as the paper does) with no ``±``; Table 2 has
    the spread over the realisations in its own column, Table 1 only through ``z``. Tables 4,
    5 and the SNR column show ``mean ± std`` over the Monte Carlo runs.

    Parameters
    ----------
    realisations : int, optional
        Realisations behind the spread of Tables 1 and 2 (named when given).

    Returns
    -------
    dict of str to str
        Note per table name (``table1``, ``table2``, ``table4``, ``snr``, ``table5``).
    """
    over = f"over {realisations} realisations" if realisations else "over the realisations"
    single = "ours: run 0, one realisation as in the paper"
    mean = "ours: mean ± std over runs; z as in reproduce.csv"
    return {
        "table1": f"{single}; z uses its spread {over} (ours_std in reproduce.csv)",
        "table2": f"{single}; ours std: its spread {over}; z as in reproduce.csv",
        "table4": mean,
        "snr": mean,
        "table5": mean,
    }


def write_display_tables(frame: Any, out: Path, *, realisations: int | None = None) -> list[Path]:
    """Write each display table (:func:`display_tables`) as Markdown and LaTeX into ``out``.

    Parameters
    ----------
    frame : pandas.DataFrame
        A ``reproduce.csv`` frame.
    out : Path
        Folder to write ``table1.md``, ``table1.tex`` ... into.
    realisations : int, optional
        Realisations behind the spread of Tables 1 and 2, named in their headers.

    Returns
    -------
    list of Path
        The files written.
    """
    from hbench.results import to_latex, to_markdown

    paths = []
    notes = display_notes(realisations)
    captions = {
        "table1": "Table 1: V(na, tau) x 1e-7, one realisation at sigma^2 = 1e-3",
        "table2": "Table 2: Var of Delta w(l) x 1e-7, same realisation",
        "table4": "Table 4: a1, a2, b2 mean +- std (b2 sign corrected)",
        "snr": "The SNR column ||y0|| / ||v||",
        "table5": "Table 5: fitness (%) mean +- std",
    }
    for name, table in display_tables(frame).items():
        (out / f"{name}.md").write_text(
            f"**{captions[name]}** ({notes[name]})\n\n" + to_markdown(table)
        )
        (out / f"{name}.tex").write_text(to_latex(table, caption=captions[name]))
        paths += [out / f"{name}.md", out / f"{name}.tex"]
    return paths


# --------------------------------------------------------------------------- investigation


def alternatives() -> list[Config]:
    """The alternatives ``--investigate`` tests, one change each against the defaults."""
    import copy

    base = Config()
    rbs = copy.deepcopy(_paper_reference())

    def ref(**kw: Any) -> tuple[tuple[str, Any], ...]:
        return tuple({**rbs, **kw}.items())

    return [
        replace(
            base,
            label="noise-foh",
            group="noise discretisation",
            description="noise filter by first-order hold",
            overrides=(("noise.method", "foh"),),
        ),
        replace(
            base,
            label="noise-impulse",
            group="noise discretisation",
            description="noise filter by impulse invariance",
            overrides=(("noise.method", "impulse"),),
        ),
        replace(
            base,
            label="noise-bilinear",
            group="noise discretisation",
            description="noise filter by Tustin (bilinear)",
            overrides=(("noise.method", "bilinear"),),
        ),
        replace(
            base,
            label="rbs-ideal",
            group="reference",
            description="RBS band [0, 0.5] by an ideal (FFT) filter instead of Butterworth",
            reference=ref(filter="ideal"),
        ),
        replace(
            base,
            label="rbs-band-0.25",
            group="reference",
            description="RBS band [0, 0.25] x Nyquist (the stated band halved)",
            reference=ref(band=[0.0, 0.25]),
        ),
        replace(
            base,
            label="rbs-band-0.3",
            group="reference",
            description="RBS band [0, 0.3] x Nyquist (fitted to the SNR column)",
            reference=ref(band=[0.0, 0.3]),
        ),
        replace(
            base,
            label="rbs-fixed",
            group="reference",
            description="one reference for all runs (per_run false)",
            reference=ref(per_run=False),
        ),
        replace(
            base,
            label="prbs-hold2",
            group="reference",
            description="PRBS (10 bits) held 2 periods: idinput's PRBS reading of band [0, 0.5]",
            reference=(("name", "prbs"), ("nbits", 10), ("hold", 2)),
        ),
        replace(
            base,
            label="prbs-hold3",
            group="reference",
            description="PRBS (10 bits) held 3 periods",
            reference=(("name", "prbs"), ("nbits", 10), ("hold", 3)),
        ),
        replace(
            base,
            label="rbs-band-0.25-amplitude-0.9",
            group="reference",
            description="RBS band [0, 0.25] x Nyquist, values +-0.9 (fitted to Table 2 read "
            "swapped and the SNR column)",
            reference=ref(band=[0.0, 0.25], amplitude=0.9),
        ),
        replace(
            base,
            label="rbs-amplitude-1.6",
            group="reference",
            description="RBS [0, 0.5] with values +-1.6 (diagnostic: power, not spectrum)",
            reference=ref(amplitude=1.6),
        ),
        replace(
            base,
            label="eq15-real",
            group="eq. (15) without a real root",
            description="the complex roots' real part 1/g11 instead of s2 (the discriminant "
            "clipped in the stable form)",
            eq15="real",
        ),
        replace(
            base,
            label="eq15-modulus",
            group="eq. (15) without a real root",
            description="the complex roots' modulus sqrt(s2/g11) (compensated residual 2 s2) "
            "instead of s2",
            eq15="modulus",
        ),
        replace(
            base,
            label="eq15-zero",
            group="eq. (15) without a real root",
            description="no compensation (sigma^2 = 0) instead of s2",
            eq15="zero",
        ),
        replace(
            base,
            label="table2-swapped",
            group="Table 2",
            description="Table 2's rows l = 1 and l = 2 read exchanged",
            table2="swapped",
        ),
        replace(
            base,
            label="fitness-ls",
            group="fitness scaling",
            description="estimate scaled by least squares instead of the true gain",
            fitness="ls",
        ),
        replace(
            base,
            label="fitness-ls-affine",
            group="fitness scaling",
            description="least-squares scale and offset",
            fitness="ls-affine",
        ),
        replace(
            base,
            label="snr-power",
            group="SNR definition",
            description="SNR as a power ratio ||y0||^2/||v||^2",
            snr="power",
        ),
        replace(
            base,
            label="snr-db",
            group="SNR definition",
            description="SNR in dB, 20 log10(||y0||/||v||)",
            snr="db",
        ),
        replace(
            base,
            label="warmup-100s",
            group="initial state",
            description="100 s simulated first and discarded (no start-up transient)",
            warmup=100.0,
        ),
        replace(
            base,
            label="backlash-centred",
            group="initial state",
            description="backlash starts centred on its first input (u0 = None)",
            overrides=(("nonlinearity.u0", None),),
        ),
        replace(
            base,
            label="controller-delay1",
            group="loop",
            description="one slow sample of computational delay in the controller",
            overrides=(("controller.delay", 1),),
        ),
        replace(
            base,
            label="unpooled",
            group="method",
            description="A from phase p alone (pooled false; Section 3.2's l = p)",
            pooled=False,
        ),
        replace(
            base,
            label="selected-per-run",
            group="method",
            description="structure (na, tau, nb) selected in every run",
            structure="selected",
        ),
        replace(
            base,
            label="paper-steps-ii-iv",
            group="method",
            description="the LSM rows and F_LSM from wang: A by integrated AIC, b by V_EIV "
            "between the LSM and the IVM (the paper's steps ii and iv)",
            lsm="wang",
        ),
        replace(
            base,
            label="paper-step-ii",
            group="method",
            description="step (ii) alone: A by integrated AIC between the LSM and the IVM, b "
            "from the LSM",
            lsm="wang-step-ii",
        ),
        replace(
            base,
            label="paper-step-iv",
            group="method",
            description="step (iv) alone: A from the LSM, b_l by V_EIV between the LSM and the IVM",
            lsm="wang-step-iv",
        ),
        replace(
            base,
            label="f-inv-bai-fu",
            group="method",
            description="F_INV from bai-fu (OLS A and B, direct inverse)",
            f_inv="bai-fu",
        ),
        # the method choices again with the reference that matches the SNR column, so that
        # their own effect is not hidden behind the reference's
        replace(
            base,
            label="rbs-band-0.3+unpooled",
            group="combined",
            description="band [0, 0.3] and A from phase p alone",
            reference=ref(band=[0.0, 0.3]),
            pooled=False,
        ),
        replace(
            base,
            label="rbs-band-0.3+f-inv-bai-fu",
            group="combined",
            description="band [0, 0.3] and F_INV from bai-fu",
            reference=ref(band=[0.0, 0.3]),
            f_inv="bai-fu",
        ),
        replace(
            base,
            label="rbs-band-0.3+noise-foh",
            group="combined",
            description="band [0, 0.3] and the noise filter by first-order hold",
            reference=ref(band=[0.0, 0.3]),
            overrides=(("noise.method", "foh"),),
        ),
        replace(
            base,
            label="rbs-band-0.25-amplitude-0.9+table2-swapped",
            group="combined",
            description="band [0, 0.25], values +-0.9, and Table 2's l = 1, 2 read exchanged",
            reference=ref(band=[0.0, 0.25], amplitude=0.9),
            table2="swapped",
        ),
        replace(
            base,
            label="rbs-band-0.3+warmup-100s",
            group="combined",
            description="band [0, 0.3] and a 100 s warm-up discarded",
            reference=ref(band=[0.0, 0.3]),
            warmup=100.0,
        ),
    ]


def _paper_reference() -> dict[str, Any]:
    from hbench import scenarios

    return dict(scenarios.PAPER_SECTION6["reference"])


#: Alternatives that only post-process the default rows (no new simulation).
POST_PROCESSED = {
    "fitness-ls",
    "snr-power",
    "snr-db",
    "f-inv-bai-fu",
    "paper-steps-ii-iv",
    "table2-swapped",
}
#: What ``--investigate`` cannot test with the existing options.
UNTESTED = [
    (
        "controller sees the noise-free output",
        "no option: the simulator feeds y = y0 + v back "
        "(the paper's SNR rising faster than 1/sigma at high noise says its loop did too)",
    ),
    (
        "the RBS generated at the fast rate and sampled by the controller, or switching with "
        "a fixed probability",
        "the reference options (band, amplitude, filter; PRBS hold) do not express them",
    ),
]

_TABLE_PARTS = {
    "T1": lambda f: f["table"] == 1,
    "T2": lambda f: f["table"] == 2,
    "T4-params": lambda f: (f["table"] == 4) & (f["column"] != "snr"),
    "T4-snr": lambda f: (f["table"] == 4) & (f["column"] == "snr"),
    "T5": lambda f: f["table"] == 5,
}


def _mean_abs_z(frame: Any) -> float:
    import numpy as np

    z = np.abs(frame["z"].to_numpy(dtype=float))
    z = z[np.isfinite(z)]
    return float(np.mean(z)) if z.size else math.nan


def spread_ratio(frame: Any) -> float:
    """Geometric mean of ``ours_std / paper_std`` over cells with both spreads positive: the
    z-scores judge means, this judges the published spreads (1 = the paper's)."""
    import numpy as np

    o = frame["ours_std"].to_numpy(dtype=float)
    p = frame["paper_std"].to_numpy(dtype=float)
    ok = np.isfinite(o) & np.isfinite(p) & (o > 0) & (p > 0)
    return float(np.exp(np.mean(np.log(o[ok] / p[ok])))) if ok.any() else math.nan


#: Methods that can stand in Table 4's LSM rows and Table 5's F_LSM (``Config.lsm``).
LSM_METHODS = frozenset({"wang-lsm", "wang", *WANG_VARIANTS})


def _slots(frame: Any) -> Any:
    """Cell keys that survive a change of the LSM's or F_INV's method: ``table, row, column,
    slot``."""
    lsm = frame["method"].isin(LSM_METHODS)
    f = (frame["table"] == 5) & (frame["column"] == "F")
    slot = frame["method"].where(~((frame["table"] == 4) & lsm), "wang-lsm")
    slot = slot.where(~f, lsm.map({True: "F_LSM", False: "F_INV"}))
    return frame.assign(slot=slot)


def investigation_row(config: Config, before: Any, after: Any, top: int = 6) -> dict[str, Any]:
    """One ``investigation.csv`` row: mean |z| over Tables 4 (parameters and SNR) and 5, and per
    table, before (defaults) and after (the alternative); the cells (all tables) whose |z| fell
    or rose by more than 1; the cells moved most."""
    import numpy as np

    key = ["table", "row", "column", "slot"]
    m = _slots(before).merge(_slots(after), on=key, suffixes=("_b", "_a"), how="inner")
    zb = np.abs(m["z_b"].to_numpy(dtype=float))
    za = np.abs(m["z_a"].to_numpy(dtype=float))
    finite = np.isfinite(zb) & np.isfinite(za)
    delta = np.where(finite, za - zb, np.nan)

    def t45(f: Any) -> Any:
        return f[f["table"].isin([4, 5])]

    row: dict[str, Any] = {
        "alternative": config.label,
        "group": config.group,
        "description": config.description,
        "cells": int(finite.sum()),
        "cells_closer": int(np.sum(delta < -1.0)),
        "cells_further": int(np.sum(delta > 1.0)),
        "mean_abs_z_before": _mean_abs_z(t45(before)),
        "mean_abs_z_after": _mean_abs_z(t45(after)),
        "within2_before": int(np.sum(np.abs(t45(before)["z"].astype(float)) <= Z_LIMIT)),
        "within2_after": int(np.sum(np.abs(t45(after)["z"].astype(float)) <= Z_LIMIT)),
    }
    for part, sel in _TABLE_PARTS.items():
        row[f"{part}_before"] = _mean_abs_z(before[sel(before)])
        row[f"{part}_after"] = _mean_abs_z(after[sel(after)])
    for part in ("T4-params", "T5"):
        sel = _TABLE_PARTS[part]
        row[f"std_ratio_{part}_before"] = spread_ratio(before[sel(before)])
        row[f"std_ratio_{part}_after"] = spread_ratio(after[sel(after)])
    order = np.argsort(np.where(finite, -np.abs(delta), 0.0), kind="stable")[:top]
    moved = []
    for i in order:
        if not finite[i] or abs(delta[i]) < 1.0:
            continue
        c = m.iloc[i]
        where = (
            f"na={int(c['row'])},tau={c['column']}"
            if c["table"] == 1
            else f"l={int(c['row'])}"
            if c["table"] == 2
            else f"{c['column']}@{c['row']:g}"
        )
        moved.append(f"T{c['table']} {c['method_a']} {where}: {c['z_b']:+.1f}->{c['z_a']:+.1f}")
    row["moved_most"] = "; ".join(moved)
    return row


# --------------------------------------------------------------------------- orchestration


_T0 = time.perf_counter()


def _log(msg: str) -> None:
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


def evaluate(
    config: Config,
    runs: int,
    seed: int,
    structure: tuple[int, int, int],
    jobs: int,
    methods: Sequence[str] = TABLE_METHODS,
    with_tables12: bool = True,
    progress: Callable[[LevelTask, float], None] | None = None,
) -> dict[str, Any]:
    """Rows, comparison (Tables 1, 2, 4, 5) and examples of one configuration."""
    import pandas as pd

    methods = (*methods, *(m for m in (config.lsm, config.f_inv) if m not in methods))
    tasks = level_tasks(config, runs, seed, structure, methods)
    results = run_levels(tasks, jobs, progress)
    rows = pd.concat([r[0] for r in results], ignore_index=True)
    examples = [r[1] for r in results if r[1]]
    comp = compare_tables45(rows, config)
    tab = None
    if with_tables12:
        tab = run_tables12(config, min(runs, TABLE12_RUNS), seed)
        comp = pd.concat([compare_tables12(tab, config), comp], ignore_index=True)
    return {"rows": rows, "comparison": comp, "examples": examples, "tables12": tab}


def investigate(
    baseline: Mapping[str, Any],
    runs: int,
    seed: int,
    structure: tuple[int, int, int],
    jobs: int,
    out: Path,
) -> Any:
    """Re-run under every alternative; write ``investigation.csv`` and ``investigation.md``.

    ``baseline`` holds the defaults' ``comparison``, their rows' :class:`LevelValues`
    (``values``) and Tables 1-2 (``tables12``), which the alternatives that only re-score the
    defaults read."""
    import pandas as pd

    from hbench.results import to_markdown

    before = baseline["comparison"]
    records = []
    comps = {}
    alts = alternatives()
    for k, config in enumerate(alts, 1):
        t0 = time.perf_counter()
        if config.label in POST_PROCESSED:
            comp = pd.concat(
                [
                    compare_tables12(baseline["tables12"], config),
                    compare_tables45(baseline["values"], config),
                ],
                ignore_index=True,
            )
        else:
            res = evaluate(config, runs, seed, structure, jobs)
            comp = res["comparison"]
        comp.to_csv(
            out / "investigation" / f"{config.label}.csv", index=False, float_format="%.10g"
        )
        records.append(investigation_row(config, before, comp))
        comps[config.label] = comp
        _log(
            f"investigate [{k}/{len(alts)}] {config.label}: mean |z| (T4, T5) "
            f"{records[-1]['mean_abs_z_before']:.2f} -> {records[-1]['mean_abs_z_after']:.2f} "
            f"({time.perf_counter() - t0:.1f} s)"
        )
    table = pd.DataFrame(records)
    table.to_csv(out / "investigation.csv", index=False, float_format="%.6g")
    causes = explained_cells(before, comps)
    causes.to_csv(out / "investigation_cells.csv", index=False, float_format="%.6g")
    show = table[list(INVESTIGATION_COLUMNS)]
    base_line = table.iloc[0]
    text = [
        "# Investigation: what moves the reproduction toward the paper",
        "",
        f"Defaults: mean |z| over Tables 4 (parameters and SNR) and 5 = "
        f"{base_line['mean_abs_z_before']:.2f}; per table T4-params "
        f"{base_line['T4-params_before']:.2f}, T4-snr {base_line['T4-snr_before']:.2f}, "
        f"T5 {base_line['T5_before']:.2f}, T1 {base_line['T1_before']:.2f}, "
        f"T2 {base_line['T2_before']:.2f}; spread ratio ours/paper T4 "
        f"{base_line['std_ratio_T4-params_before']:.2f}, "
        f"T5 {base_line['std_ratio_T5_before']:.2f}.",
        "",
        "Each alternative changes one convention (the `combined` group two); "
        "`cells_closer`/`cells_further` count cells whose |z| fell/rose by more than 1. "
        "`std_ratio_*` is the geometric mean of our spread over the published one (Table 4's "
        "parameters, Table 5's F; 1 = the paper's): z judges means, this the spreads. "
        "Tables 1-2 are recomputed for every alternative that changes the simulation or the "
        "estimator.",
        "",
        to_markdown(show.sort_values("mean_abs_z_after"), floatfmt=".3g"),
        "",
        "Best alternative per group (mean |z| over Tables 4 and 5; spread ratios T4, T5):",
        "",
        *_best_per_group(table),
        "",
        _snr_scaling_note(),
        "",
        "Not tested (no existing option expresses them):",
        "",
    ]
    text += [f"- {name}: {why}" for name, why in UNTESTED]
    text += [
        "",
        f"Cells beyond |z| = {Z_LIMIT:g} under the defaults, and the alternatives that bring "
        f"each within it (`investigation_cells.csv`): {int((causes['within_by'] != '').sum())} "
        f"of {len(causes)} have one.",
        "",
        to_markdown(causes, floatfmt=".3g") if len(causes) else "(none)",
    ]
    (out / "investigation.md").write_text("\n".join(text) + "\n")
    return table


def explained_cells(before: Any, comps: Mapping[str, Any]) -> Any:
    """Per cell beyond ``|z| = 2`` under the defaults: the alternatives under which the same
    cell (its slot: the LSM's or F_INV's method may change) is within, each with its z
    (``within_by``, ``; ``-separated, empty if none)."""
    import numpy as np
    import pandas as pd

    key = ["table", "row", "column", "slot"]
    b = _slots(before)
    zb = b["z"].to_numpy(dtype=float)
    beyond = b[np.isfinite(zb) & (np.abs(zb) > Z_LIMIT)]
    found: dict[tuple[Any, ...], list[str]] = {tuple(r): [] for r in beyond[key].to_numpy()}
    for label, comp in comps.items():
        a = _slots(comp).set_index(key)["z"]
        for cell in found:
            z = float(a.get(cell, math.nan))
            if math.isfinite(z) and abs(z) <= Z_LIMIT:
                found[cell].append(f"{label} ({z:+.1f})")
    out = beyond[["table", "row", "column", "method", "z"]].reset_index(drop=True)
    out["within_by"] = ["; ".join(found[tuple(r)]) for r in beyond[key].to_numpy()]
    return pd.DataFrame(out)


def _best_per_group(table: Any) -> list[str]:
    """One line per group: its best alternative (by Tables 4-5) against the defaults, with what
    it does to Tables 1-2 and to the spreads."""
    lines = []
    for group, g in table.groupby("group", sort=False):
        best = g.sort_values("mean_abs_z_after").iloc[0]
        before, after = best["mean_abs_z_before"], best["mean_abs_z_after"]
        verdict = (
            "closer"
            if after < 0.95 * before
            else "further"
            if after > 1.05 * before
            else "no change"
        )
        lines.append(
            f"- {group}: {best['alternative']} {before:.2f} -> {after:.2f} ({verdict}; "
            f"T1 {best['T1_before']:.2f} -> {best['T1_after']:.2f}, "
            f"T2 {best['T2_before']:.2f} -> {best['T2_after']:.2f}; spreads "
            f"{best['std_ratio_T4-params_after']:.2f}, {best['std_ratio_T5_after']:.2f})"
        )
    return lines


def _snr_scaling_note() -> str:
    """The paper's own SNR column against the three definitions: a norm ratio scales as
    sigma^-1 at low noise (little noise is fed back into y0 there), a power ratio as sigma^-2,
    dB by a constant step."""
    snr = {c.row: c.value for c in paper_cells() if c.table == 4 and c.column == "snr"}
    slope = math.log(snr[1e-3] / snr[1e-4]) / math.log(1e-3 / 1e-4)
    return (
        f"The paper's own SNR column falls by {snr[1e-4] / snr[1e-3]:.3f} from sigma^2 = 1e-4 "
        f"to 1e-3 (log-log slope {slope:.3f} against sigma^2): a ratio of norms (slope -0.5) "
        "as the paper states, not of powers (-1) nor dB (a constant 10 dB step); the "
        "SNR-definition rows only re-label our numbers."
    )


def save_examples(path: Path, examples: Sequence[Mapping[str, Any]]) -> Path:
    """``examples.npz``: per example ``c{i}__x``, ``c{i}__U``, ``c{i}__gain``, ``c{i}__meta``
    (JSON: cell, nonlinearity, sigma2) and ``c{i}__est__{method}``."""
    import numpy as np

    arrays: dict[str, Any] = {}
    for i, ex in enumerate(examples):
        arrays[f"c{i}__x"] = np.asarray(ex["x"])
        arrays[f"c{i}__U"] = np.asarray(ex["U"])
        arrays[f"c{i}__gain"] = np.asarray(ex["gain"], dtype=float)
        meta = {k: ex.get(k) for k in ("cell", "nonlinearity", "sigma2", "snr_target")}
        arrays[f"c{i}__meta"] = np.asarray(json.dumps(meta, default=str))
        for name, U in ex.get("estimates", {}).items():
            arrays[f"c{i}__est__{name}"] = np.asarray(U)
    np.savez_compressed(path, **arrays)
    return path


def reproduce(
    runs: int = DEFAULT_RUNS,
    out: Path | str = "results",
    seed: int = DEFAULT_SEED,
    investigate_: bool = False,
    jobs: int | None = None,
    overrides: Iterable[tuple[str, Any]] = (),
    structure_mode: str = "fixed",
    report: bool = True,
) -> Path:
    """The whole reproduction; returns the new output folder."""
    t_start = time.perf_counter()
    if isinstance(runs, bool) or int(runs) != runs or runs < 1:
        raise InputError(f"--runs must be a positive integer, got {runs}")
    if jobs is None:
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        jobs = max(1, min(2, cpus or 1))
    if jobs < 1:
        raise InputError(f"--jobs must be >= 1, got {jobs}")
    if structure_mode not in ("fixed", "selected"):
        raise InputError(f"--structure must be 'fixed' or 'selected', got {structure_mode!r}")
    config = replace(Config(), overrides=tuple(overrides), structure=structure_mode)
    from hbench import scenarios

    scenarios.build(scenario_spec(config, TYPICAL_LEVEL))  # bad overrides fail before any work

    import pandas as pd

    from hbench import results as res

    out_dir = res.new_output_dir(Path(out), "reproduce")
    _log(f"writing to {out_dir}")

    tab = run_tables12(config, min(runs, TABLE12_RUNS), seed)
    sel = tab["selection"]["wang-lsm"]
    sel_iv = tab["selection"]["wang-iv"]
    structure = (sel["na"], sel["tau"], sel["nb"])
    _log(
        f"Tables 1-2 ({tab['runs']} realisations at sigma^2 = 1e-3, run 0 shown): LSM selects "
        f"na = {sel['na']}, tau = {sel['tau']}, nb = {sel['nb']}; the IV's own table na = "
        f"{sel_iv['na']}, tau = {sel_iv['tau']}, nb = {sel_iv['nb']} ({tab['seconds']:.1f} s)"
    )

    def progress(task: LevelTask, seconds: float) -> None:
        _log(
            f"sigma^2 = {task.sigma2:g}: {task.runs} runs x {len(task.methods)} methods "
            f"({seconds:.1f} s)"
        )

    def warm_up() -> None:  # the figures need matplotlib: import it while the workers compute
        from hbench import figures

        figures.warm_up()

    drawn: list[Any] = []

    def draw_example(task: LevelTask, result: tuple[Any, dict[str, Any], float]) -> None:
        # Figures 4 and 5 need one level's example: drawn here as soon as it is in, while the
        # workers compute the other levels, instead of with the report's figures at the end
        if result[1] and not drawn:
            from hbench import figures

            specs = figures.paper_figure_specs(result[1], out_dir, estimate="wang-lsm")
            figures.render_many(specs, 1)
            drawn.append(task.sigma2)

    tasks = level_tasks(config, runs, seed, structure, ALL_METHODS)
    results = run_levels(
        tasks,
        jobs,
        progress,
        while_waiting=warm_up if report else None,
        on_result=draw_example,
    )
    rows = pd.concat([r[0] for r in results], ignore_index=True)
    examples = [r[1] for r in results if r[1]]
    values = LevelValues.of(rows)  # read by every comparison of these rows
    comparison = pd.concat(
        [compare_tables12(tab, config), compare_tables45(values, config)], ignore_index=True
    )
    summary = summarise(comparison)
    steps, steps_text = steps_comparison(values, comparison, config)

    tables = res.aggregated_tables(rows)  # written here, shown by the report
    res.write_tables(rows, out_dir, tables=tables)
    comparison.to_csv(out_dir / "reproduce.csv", index=False, float_format="%.10g")
    write_display_tables(comparison, out_dir, realisations=int(tab["runs"]))
    selection_text = (
        f"structure from Tables 1-2 (run 0 at sigma^2 = 1e-3): wang-lsm na={sel['na']} "
        f"tau={sel['tau']} nb={sel['nb']} (the same in {100 * sel['share_of_runs']:.0f} % of "
        f"the first {tab['runs']} realisations); wang-iv's own table na={sel_iv['na']} "
        f"tau={sel_iv['tau']} nb={sel_iv['nb']}; the paper: na=2 tau=3 nb=2. Monte Carlo "
        f"structure: {structure_mode}."
    )
    steps.to_csv(out_dir / "steps.csv", index=False, float_format="%.10g")
    (out_dir / "summary.txt").write_text(summary.text() + selection_text + "\n" + steps_text)
    for name in ("table1", "table2"):
        with (out_dir / f"{name}.md").open("a") as fh:
            fh.write(f"\nSelection implied: {selection_text}\n")
    (out_dir / "tables12.json").write_text(
        json.dumps(
            {
                "selection": tab["selection"],
                "runs": tab["runs"],
                "snr_run0": tab["snr"],
                "na_values": tab["na_values"].tolist(),
                "V_run0": {k: v[0].tolist() for k, v in tab["V"].items()},
                "var_dw_run0": tab["var_dw"][0].tolist(),
            },
            indent=2,
        )
    )
    if examples:
        save_examples(out_dir / "examples.npz", examples)
    config_desc = {
        "scenario": scenario_spec(config, TYPICAL_LEVEL),
        "levels": list(LEVELS),
        "runs": runs,
        "noise_free_runs": min(runs, NOISE_FREE_RUNS),
        "methods": list(ALL_METHODS),
        "structure": list(structure),
        "reproduction": config.describe(),
        "table5_columns": {k: v[1] for k, v in TABLE5_COLUMNS.items()},
        "z": "z = (ours - paper) / sqrt(s_o^2/n + s_p^2/n_p + u^2/12); s_p = s_o where the "
        "paper prints none; Tables 1-2: n = n_p = 1",
    }
    seeds = {"base": seed, **{cell_name(s2): str(level_seed(seed, s2).entropy) for s2 in LEVELS}}
    res.write_provenance(out_dir, config=config_desc, seeds=seeds)
    if investigate_:
        (out_dir / "investigation").mkdir()
        investigate(
            {"values": values, "tables12": tab, "comparison": comparison},
            runs,
            seed,
            structure,
            jobs,
            out_dir,
        )
    _log("tables written; rendering the figures and the report")
    if report:
        from hbench import report as rep

        path = rep.build_report(out_dir, out_dir / "report", rows=rows, tables=tables, jobs=jobs)
    rows.to_parquet(out_dir / "rows.parquet", index=False)  # last: no fork after pyarrow
    print(summary.text() + selection_text + "\n" + steps_text, end="")
    if report:
        print(f"report: {path}")
    print(f"results: {out_dir}")
    _log(f"done in {time.perf_counter() - t_start:.1f} s")
    return out_dir


def _cmd(args: argparse.Namespace) -> int:
    from hbench.cli import check_output
    from hbench.scenarios import parse_value

    if args.out is not None:  # before any work: a folder one can write in
        check_output(args.out, "--out", folder=True)
    overrides = []
    for item in args.set or []:
        if "=" not in item:
            raise InputError(f"--set takes KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        overrides.append((key, parse_value(value)))
    reproduce(
        runs=args.runs,
        out=args.out,
        seed=args.seed,
        investigate_=args.investigate,
        jobs=args.jobs,
        overrides=overrides,
        structure_mode=args.structure,
    )
    return 0


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``hbench reproduce`` to the CLI."""
    p = subparsers.add_parser(
        "reproduce",
        help="the paper's Section 6 example beside Tables 1, 2, 4, 5 and Figures 4, 5",
        description="Run the paper's Section 6 example at every noise level of Tables 4 and 5 "
        "with every method, compare with the published numbers (reproduce.csv: z per cell), draw "
        "Figures 4 and 5 and write the comparison report, all into a new folder under --out.",
    )
    p.add_argument(
        "--runs",
        type=int,
        default=DEFAULT_RUNS,
        help=f"Monte Carlo runs per noise level (default {DEFAULT_RUNS}, the paper's)",
    )
    p.add_argument("--out", default="results", help="base folder (default results/)")
    p.add_argument(
        "--seed", type=int, default=DEFAULT_SEED, help=f"base seed (default {DEFAULT_SEED})"
    )
    p.add_argument(
        "--investigate",
        action="store_true",
        help="also re-run under alternative conventions (investigation.csv)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="worker processes (default: up to 2, the CPUs available)",
    )
    p.add_argument(
        "--structure",
        choices=("fixed", "selected"),
        default="fixed",
        help="fix (na, tau, nb) to Tables 1-2's selection (default) or select per run",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a scenario key (dotted), e.g. reference.band=[0,0.25]",
    )
    p.set_defaults(func=_cmd)
    return p
