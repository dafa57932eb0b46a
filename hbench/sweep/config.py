"""Structured configs of ``hbench sweep`` (Hydra's ConfigStore) and the helpers around them.

The schema :class:`SweepConfig` is registered as ``hbench_schema`` and sits first in the
defaults list of ``hbench/conf/config.yaml``; the YAML files fill it in. A wrong type (``runs=abc``)
or an unknown key (``rnus=5``) fails when the config is composed, naming the key. Plugin groups
(``plant``, ``nonlinearity``, ``controller``, ``noise``, ``reference``) are free dicts: their keys
come from the group's YAML file, so Hydra's struct mode rejects a key absent from it
(``plant.delya=7``), and :func:`hbench.sim.scenarios.build` rejects a parameter the plugin does not
take (``+plant.foo=1``).

Three OmegaConf resolvers are registered on import:

``${hbench.unless:A,B}``
    ``None`` if ``A`` is set, else ``B``. The noise files write
    ``sigma2: ${hbench.unless:${.snr},0.001}``, so overriding ``noise.snr`` alone switches the
    level to SNR mode (sigma2 becomes null); overriding ``noise.sigma2`` keeps sigma2 mode.
    Setting both to numbers is an error.
``${hbench.or:A,B}``
    ``A`` unless it is null, else ``B`` (``hydra.sweep.dir: ${hbench.or:${out},results/...}``).
``${hbench.run_id:}``
    The run id of the config it sits in (see :func:`run_id`); the sweep's job folders are named
    by it (``hydra.sweep.subdir``), so a job lands in the same folder whatever its job number.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from omegaconf import MISSING, DictConfig, OmegaConf

#: The packaged config directory (``hbench/conf``; ``conf/`` at the top of the repository links
#: to it).
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
#: Plugin groups: config key -> registry kind.
PLUGIN_GROUPS = {
    "plant": "plants",
    "nonlinearity": "nonlinearities",
    "controller": "controllers",
    "noise": "noise_models",
    "reference": "references",
}
#: The keys that define a cell's data (its seed derives from them, never from the methods).
SCENARIO_KEYS = (*PLUGIN_GROUPS, "scenario")
#: Hydra notes that ``hydra/launcher/joblib.yaml`` shares its name with the plugin's schema (the
#: YAML is checked against it, which is what we want); silenced here because this module is
#: imported wherever hbench composes, worker processes included.
SCHEMA_NOTE = r"\s*'hydra/launcher/[^']*' is validated against ConfigStore schema"
warnings.filterwarnings("ignore", message=SCHEMA_NOTE, category=UserWarning)
#: Top-level keys left out of the run id: where results go does not change them.
#: Keys whose value does not change a job's numbers: where it writes, and how many runs are
#: simulated at once and by how many processes (every run draws from its own stream).
NOT_IN_RUN_ID = ("out", "chunk", "jobs")
#: Keys left out of the run id while null (their default): a job without a time limit keeps
#: the id it has without the key.
NULL_NOT_IN_RUN_ID = ("method_timeout",)


@dataclass
class ScenarioConf:
    """The sampling: controller period ``T`` (s), fast-sampling ratio ``p``, record length (s)."""

    p: int = 5
    T: float = 0.6
    duration: float = 500.0


@dataclass
class IdentifyConf:
    """Prior knowledge given to every method (:class:`hbench.ident.identifiers.IdentifyOptions`).

    ``nb_max: null`` means ``p - 1``, the largest bound assumption A2 allows (the paper's
    example, p = 5, uses 4). The delay's multiple of p is always given (assumption A3).
    """

    nb_max: int | None = None
    na_range: list[int] = field(default_factory=lambda: [1, 5])
    tau_range: list[int] | None = None
    na: int | None = None
    tau: int | None = None
    nb: int | None = None


@dataclass
class SweepConfig:
    """The top level of a ``hbench sweep`` config."""

    plant: dict[str, Any] = MISSING
    nonlinearity: dict[str, Any] = MISSING
    controller: dict[str, Any] = MISSING
    noise: dict[str, Any] = MISSING
    reference: dict[str, Any] = MISSING
    scenario: ScenarioConf = field(default_factory=ScenarioConf)
    methods: list[str] = MISSING
    method_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    identify: IdentifyConf = field(default_factory=IdentifyConf)
    runs: int = 100
    seed: int = 0
    chunk: int = 200
    jobs: int = 1
    method_timeout: float | None = None
    out: str | None = None


TOP_LEVEL_KEYS = tuple(f.name for f in fields(SweepConfig))


def _unless(value: Any, default: Any) -> Any:
    return None if value is not None else default


def _or(value: Any, default: Any) -> Any:
    return value if value is not None else default


def _run_id_resolver(*, _root_: DictConfig) -> str:
    return run_id(_root_)


def register() -> None:
    """Register the schema in Hydra's ConfigStore and the resolvers (idempotent)."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="hbench_schema", node=SweepConfig)
    if not OmegaConf.has_resolver("hbench.unless"):
        OmegaConf.register_new_resolver("hbench.unless", _unless)
    if not OmegaConf.has_resolver("hbench.or"):
        OmegaConf.register_new_resolver("hbench.or", _or)
    if not OmegaConf.has_resolver("hbench.run_id"):
        OmegaConf.register_new_resolver("hbench.run_id", _run_id_resolver)


def _plain_defaults(factory: Any) -> dict[str, Any]:
    """The keyword parameters of a plugin's factory (class or function) whose defaults are plain
    config values, so that ``group.param=value`` overrides them as for the YAML options."""
    import inspect

    try:
        params = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):
        return {}
    plain = (bool, int, float, str, type(None))
    out: dict[str, Any] = {}
    for prm in params:
        if prm.kind in (prm.VAR_POSITIONAL, prm.VAR_KEYWORD) or prm.default is prm.empty:
            continue
        value = prm.default
        if isinstance(value, tuple | list) and all(isinstance(v, plain) for v in value):
            value = list(value)
        elif not isinstance(value, plain):
            continue
        out[prm.name] = value
    return out


def register_methods() -> list[str]:
    """A config option for every registered plugin that has no YAML file in its group's folder
    (third-party plugins): ``method=<name>`` (``methods: [<name>]``), and ``nonlinearity=``,
    ``plant=``, ``controller=``, ``noise=``, ``reference=<name>`` with the plugin's defaults
    (``<group>.<param>=value`` sets a parameter; a noise model also gets the noise level keys).

    Returns
    -------
    list of str
        The options added, as ``group=name`` (stored in Hydra's ConfigStore; idempotent).
    """
    from hydra.core.config_store import ConfigStore

    from hbench.plugins import registry

    added = []
    for group, kind in {"method": "identifiers", **PLUGIN_GROUPS}.items():
        have = {p.stem for p in (CONF_DIR / group).glob("*.yaml")}
        for name in registry().names(kind):
            if name in have:
                continue
            if group == "method":
                node: dict[str, Any] = {"methods": [name]}
            else:
                node = {"name": name, **_plain_defaults(registry().get(kind, name))}
                if group == "noise":  # as conf/noise/*.yaml: sigma2 unless snr is set
                    node.update(sigma2="${hbench.unless:${.snr},0.001}", snr=None)
            store = ConfigStore.instance()
            store.store(
                group=group,
                name=name,
                node=node,
                package="_global_" if group == "method" else None,
                provider="hbench",
            )
            added.append(f"{group}={name}")
    return added


def canonical(obj: Any) -> Any:
    """Numbers as floats (``snr=2`` and ``snr=2.0`` are the same cell), dicts sorted."""
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int | float):
        return float(obj)
    if isinstance(obj, dict):
        return {str(k): canonical(v) for k, v in sorted(obj.items())}
    if isinstance(obj, list | tuple):
        return [canonical(v) for v in obj]
    return str(obj)


def digest(obj: Any, n: int = 12) -> str:
    """A short, stable hash of plain data (numbers canonicalised, keys sorted)."""
    blob = json.dumps(canonical(obj), sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:n]


def plain(cfg: DictConfig | dict[str, Any]) -> dict[str, Any]:
    """The resolved task config as plain data, without the ``hydra`` node."""
    if isinstance(cfg, dict):
        return {k: v for k, v in cfg.items() if k != "hydra"}
    keys = [k for k in cfg if k != "hydra"]
    out = {}
    for k in keys:
        node = cfg._get_node(k)
        out[str(k)] = (
            OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else cfg[k]
        )
    return out


def run_id(cfg: DictConfig | dict[str, Any]) -> str:
    """The id of a job: a hash of its resolved config without the hydra node and ``out``."""
    data = {
        k: v
        for k, v in plain(cfg).items()
        if k not in NOT_IN_RUN_ID and not (k in NULL_NOT_IN_RUN_ID and v is None)
    }
    return "r" + digest(data)


def scenario_axes(cfg: DictConfig | dict[str, Any]) -> dict[str, Any]:
    """The resolved scenario part (plant, nonlinearity, controller, noise, reference, scenario):
    what the cell's seed derives from."""
    data = plain(cfg)
    return {k: data[k] for k in SCENARIO_KEYS}


def cell_id(cfg: DictConfig | dict[str, Any]) -> str:
    """What a row's numbers depend on besides the method and the run index: the seed, the
    scenario, the prior knowledge and the method options. Rows with equal ``(cell, method, run,
    quantity)`` are the same measurement, so aggregation keeps one."""
    data = plain(cfg)
    key = {
        "seed": data["seed"],
        "axes": scenario_axes(data),
        "identify": data["identify"],
        "method_options": data.get("method_options", {}),
    }
    return "c" + digest(key)


def scenario_spec(cfg: DictConfig | dict[str, Any]) -> dict[str, Any]:
    """The :func:`hbench.sim.scenarios.build` spec of a config."""
    data = plain(cfg)
    spec: dict[str, Any] = {k: dict(data[k]) for k in PLUGIN_GROUPS}
    sc = data["scenario"]
    spec.update(p=sc["p"], T=sc["T"], duration=sc["duration"], name="sweep")
    return spec


def identify_options(cfg: DictConfig | dict[str, Any], delay_multiple: int = 0) -> Any:
    """:class:`hbench.ident.identifiers.IdentifyOptions` of a config (``nb_max: null`` -> p - 1)."""
    from hbench.ident.identifiers import IdentifyOptions

    data = plain(cfg)
    ident = dict(data["identify"])
    p = int(data["scenario"]["p"])
    nb_max = ident.pop("nb_max")
    if nb_max is None:
        nb_max = max(1, p - 1)
    for key in ("na_range", "tau_range"):
        if ident.get(key) is not None:
            ident[key] = tuple(int(v) for v in ident[key])
    return IdentifyOptions(nb_max=int(nb_max), delay_multiple=int(delay_multiple), **ident)


register()
