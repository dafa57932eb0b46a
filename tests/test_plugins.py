"""Tests of the plugin registry (:mod:`hbench.plugins`) and of the external example plugin.

The example plugin in ``examples/hbench-example-plugin`` is a real installable package; here it
is imported from its folder and registered at run time, so the tests do not depend on it being
installed (and leave the process-wide registry as they found it).
"""

from __future__ import annotations

import importlib
import json
import sys
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from hbench import hookspecs
from hbench.bench import conformance
from hbench.bench.metrics import fitness
from hbench.errors import InputError, PluginNotFoundError
from hbench.hookspecs import hookimpl
from hbench.model.nonlinearities import Backlash
from hbench.plugins import (
    KINDS,
    Registry,
    get_manager,
    make_manager,
    register_module,
    registry,
    unregister_module,
)
from hbench.sim import scenarios
from hbench.sim.simulate import Scenario, simulate
from tests.helpers import run_method, sim

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_DIR = ROOT / "examples" / "hbench-example-plugin"
EXAMPLE_MODULE = "hbench_example_plugin"
EXAMPLE_ENTRY_POINT = "example"

RunCli = Callable[[list[str]], tuple[int, str, str]]
HOOKS = sorted(n for n, f in vars(hookspecs).items() if n.startswith("register_") and callable(f))


def _listing(run_cli: RunCli) -> dict[str, list[dict[str, str]]]:
    status, out, _ = run_cli(["plugins", "--json"])
    assert status == 0
    return json.loads(out)


def _names(entries: list[dict[str, str]]) -> set[str]:
    return {e["name"] for e in entries}


@pytest.fixture
def example_plugin(monkeypatch: pytest.MonkeyPatch) -> Iterator[ModuleType]:
    """The example plugin, registered for the test and always unregistered afterwards."""
    installed = get_manager().get_plugin(EXAMPLE_ENTRY_POINT)
    if installed is not None:  # pip install -e'd: its entry point registered it already
        yield installed
        return
    monkeypatch.syspath_prepend(str(EXAMPLE_DIR))
    sys.modules.pop(EXAMPLE_MODULE, None)
    module = importlib.import_module(EXAMPLE_MODULE)
    register_module(module)
    try:
        yield module
    finally:
        unregister_module(module)
        sys.modules.pop(EXAMPLE_MODULE, None)


# --------------------------------------------------------------------------- built-in listing


def test_plugins_json_lists_builtins(run_cli: RunCli) -> None:
    listing = _listing(run_cli)
    assert set(listing) == set(KINDS)
    nl = _names(listing["nonlinearities"])
    assert len(nl) >= 5
    assert {"linear", "backlash", "deadband", "saturation", "stiction"} <= nl
    assert len(listing["plants"]) >= 4
    assert {"paper", "first-order", "nmp", "third-order"} <= _names(listing["plants"])
    assert len(listing["noise_models"]) >= 3
    assert {"table", "plant-log"} <= _names(listing["readers"])
    assert {"wang-lsm", "wang-iv", "bai-fu", "sun-liu-sano", "oracle", "oracle-inv"} <= _names(
        listing["identifiers"]
    )
    for kind, entries in listing.items():
        for e in entries:
            assert set(e) == {"name", "source", "object"}, (kind, e)
            assert all(isinstance(v, str) and v for v in e.values()), (kind, e)
    # the source names the package and its entry point
    (oracle,) = (e for e in listing["identifiers"] if e["name"] == "oracle")
    assert "hbench" in oracle["source"] and "(oracle)" in oracle["source"]


def test_plugins_text_listing(run_cli: RunCli) -> None:
    status, out, err = run_cli(["plugins"])
    assert status == 0 and err == ""
    for word in ("identifiers:", "nonlinearities:", "readers:", "backlash", "wang-lsm"):
        assert word in out


# --------------------------------------------------------------------------- the example plugin


def test_example_package_declares_its_entry_point() -> None:
    meta = tomllib.loads((EXAMPLE_DIR / "pyproject.toml").read_text())
    assert meta["project"]["entry-points"]["hbench"] == {EXAMPLE_ENTRY_POINT: EXAMPLE_MODULE}
    assert (EXAMPLE_DIR / EXAMPLE_MODULE / "__init__.py").is_file()
    assert (
        "pip install -e examples/hbench-example-plugin" in (EXAMPLE_DIR / "README.md").read_text()
    )


def test_example_plugin_is_listed(run_cli: RunCli, example_plugin: ModuleType) -> None:
    listing = _listing(run_cli)
    (quantizer,) = (e for e in listing["nonlinearities"] if e["name"] == "quantizer")
    (double_lag,) = (e for e in listing["plants"] if e["name"] == "double-lag")
    (plain_ls,) = (e for e in listing["identifiers"] if e["name"] == "plain-ls")
    assert plain_ls["object"] == f"{EXAMPLE_MODULE}.plain_ls.PlainLS"
    for entry in (quantizer, double_lag, plain_ls):
        # run-time registration: "<module> (registered at run time)"; installed: the package
        assert EXAMPLE_MODULE in entry["source"] or "hbench-example-plugin" in entry["source"]
    assert quantizer["object"] == f"{EXAMPLE_MODULE}.Quantizer"
    assert double_lag["object"] == f"{EXAMPLE_MODULE}.double_lag"
    # the built-ins are still there, with their own sources
    (backlash,) = (e for e in listing["nonlinearities"] if e["name"] == "backlash")
    assert EXAMPLE_MODULE not in backlash["source"]


def test_example_plugin_in_a_simulation(
    make_scenario: Callable[..., Scenario], example_plugin: ModuleType
) -> None:
    q = 2.0**-6  # dyadic: k q and (k q) / q are exact in floating point, so checks are exact
    sc = make_scenario(
        {"nonlinearity": {"name": "quantizer", "q": q}, "plant": {"name": "double-lag"}},
        duration=60.0,
    )
    assert isinstance(sc.nonlinearity, example_plugin.Quantizer)
    record, truth = simulate(sc, 3, 0)
    assert truth.plant.name == "double-lag"
    levels = truth.U / q
    assert np.array_equal(levels, np.round(levels))  # every valve position is a multiple of q
    assert np.unique(truth.U).size >= 3  # the quantiser was exercised, not stuck at one level
    # and U is x quantised to the nearest multiple of q
    assert np.array_equal(truth.U, q * np.round(record.x / q))


def test_example_quantizer_rejects_bad_step(example_plugin: ModuleType) -> None:
    with pytest.raises(InputError, match="quantizer: q"):
        scenarios.make("nonlinearities", {"name": "quantizer", "q": 0.0})
    with pytest.raises(InputError, match="no parameter 'step'"):
        scenarios.make("nonlinearities", {"name": "quantizer", "step": 0.1})


def test_example_method_conforms(example_plugin: ModuleType) -> None:
    """The recipe the README points to passes the checks a plugin's own tests run."""
    assert conformance.check_method("plain-ls") == {}


def test_example_method_is_honest_on_noisy_data(example_plugin: ModuleType) -> None:
    """plain-ls is bai-fu's A and B (OLS, LS ratio) with eq. (27) instead of the direct inverse,
    and sees y only: the same structure and parameters up to the selection's rows, and U no
    worse (measured on 100 runs: 92.7 against 91.4 % at sigma^2 = 1e-4; here 20 runs)."""
    record, truth = sim(runs=20, seed=5, noise__sigma2=1e-4)
    ours = run_method("plain-ls", record, truth)
    bai_fu = run_method("bai-fu", record, truth)
    for name in ("na", "nb", "tau"):
        np.testing.assert_array_equal(getattr(ours, name), getattr(bai_fu, name))
    # the same OLS on the same phases, but the rows differ by a period or so (plain-ls's
    # moments reach back na lags, bai-fu's the largest candidate order): measured 9e-5, a
    # twentieth of a1's spread over the runs (2e-3)
    np.testing.assert_allclose(ours.a, bai_fu.a, atol=2e-4)
    np.testing.assert_allclose(ours.b, bai_fu.b, atol=2e-4)
    F_ours = fitness(ours.U, truth.U, gain=truth.plant.gain).mean()
    F_bf = fitness(bai_fu.U, truth.U, gain=truth.plant.gain).mean()
    assert 85.0 < F_ours and F_ours > F_bf, (F_ours, F_bf)


def test_readme_recipe_builds_a_conforming_estimate(example_plugin: ModuleType) -> None:
    """README's plugin recipe, its elided estimation filled in from plain-ls, registers and
    passes the conformance checks (but the A2 one: the recipe's placeholder calls every run
    identifiable, where a real method flags them)."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Writing a method plugin") :]
    start = section.index("```python\n") + len("```python\n")
    code = section[start : section.index("```\n", start)]
    elided = "        ...  # a (R, na), b (R, nb), na, nb, tau, U (R, K): see plain_ls.py\n"
    assert elided in code
    code = code.replace(
        elided,
        "        est = __import__('hbench_example_plugin').PlainLS().identify(record, options)\n"
        "        a, b, na, nb, tau, U = est.a, est.b, est.na, est.nb, est.tau, est.U\n",
    )
    module = ModuleType("readme_recipe")
    exec(compile(code, "README.md", "exec"), module.__dict__)
    register_module(module)
    try:
        assert "my-method" in registry().names("identifiers")
        checks = [c for c in conformance.CHECKS if c != "unidentifiable_is_flagged_not_raised"]
        assert conformance.check_method("my-method", checks) == {}
    finally:
        unregister_module(module)
    assert "my-method" not in registry().names("identifiers")


def test_example_method_in_a_sweep(
    run_cli: RunCli, example_plugin: ModuleType, tmp_path: Path
) -> None:
    import pandas as pd

    argv = ["sweep", "method=plain-ls", "runs=2", "scenario.duration=60", f"out={tmp_path}"]
    status, _, err = run_cli(argv)
    assert status == 0, err
    rows = pd.read_parquet(tmp_path / "rows.parquet")
    assert set(rows["method"]) == {"plain-ls"} and set(rows["status"]) == {"ok"}


def test_example_package_has_its_own_conformance_test() -> None:
    text = (EXAMPLE_DIR / "tests" / "test_plain_ls.py").read_text()
    assert 'check_method("plain-ls")' in text


def test_unregister_removes_the_example() -> None:
    if get_manager().get_plugin(EXAMPLE_ENTRY_POINT) is not None:
        pytest.skip("the example plugin is installed")
    sys.path.insert(0, str(EXAMPLE_DIR))
    try:
        module = importlib.import_module(EXAMPLE_MODULE)
        register_module(module)
        try:
            assert "quantizer" in registry().names("nonlinearities")
            assert "plain-ls" in registry().names("identifiers")
        finally:
            unregister_module(module)
    finally:
        sys.path.remove(str(EXAMPLE_DIR))
        sys.modules.pop(EXAMPLE_MODULE, None)
    assert "quantizer" not in registry().names("nonlinearities")
    assert "double-lag" not in registry().names("plants")
    assert "plain-ls" not in registry().names("identifiers")


# --------------------------------------------------------------------------- errors


class _DuplicateBacklash:
    """A plugin that registers a name the core plugin already provides."""

    @hookimpl
    def register_nonlinearities(self, register: hookspecs.Register) -> None:
        register("backlash", Backlash)


def test_duplicate_name_is_refused() -> None:
    pm = make_manager()  # a private manager: the process-wide registry is left alone
    pm.register(_DuplicateBacklash(), name="duplicate-backlash")
    with pytest.raises(InputError, match=r"nonlinearity 'backlash' is registered twice"):
        Registry(pm).entries  # noqa: B018 - collecting the entries is what raises


def test_unknown_name_lists_known_names() -> None:
    with pytest.raises(PluginNotFoundError) as info:
        registry().get("nonlinearities", "nope")
    message = str(info.value)
    assert "unknown nonlinearity 'nope'" in message
    for name in registry().names("nonlinearities"):
        assert name in message
    assert isinstance(info.value, InputError) and isinstance(info.value, KeyError)


def test_unknown_name_in_a_scenario(make_spec: Callable[..., dict]) -> None:
    with pytest.raises(PluginNotFoundError, match=r"unknown plant 'nope' \(known: .*paper"):
        scenarios.build(make_spec({"plant": {"name": "nope"}}))


@pytest.mark.parametrize(
    ("blocked", "kind", "gone", "kept"),
    [
        ("oracle", "identifiers", {"oracle", "oracle-inv"}, {"wang-lsm", "bai-fu"}),
        ("wang, oracle", "identifiers", {"wang-lsm", "wang-iv", "oracle"}, {"sun-liu-sano"}),
        ("core", "plants", {"paper", "nmp"}, set()),
    ],
)
def test_disable_plugins_env_blocks_entry_points(
    monkeypatch: pytest.MonkeyPatch, blocked: str, kind: str, gone: set[str], kept: set[str]
) -> None:
    before = set(Registry(make_manager()).names(kind))
    assert gone <= before
    monkeypatch.setenv("HBENCH_DISABLE_PLUGINS", blocked)
    after = set(Registry(make_manager()).names(kind))
    assert not (gone & after)
    assert kept <= after


# --------------------------------------------------------------------------- every hook is used


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hookspec_has_an_implementation(hook: str) -> None:
    kind = {v: k for k, v in KINDS.items()}[hook]  # every hookspec is a registry kind
    assert getattr(get_manager().hook, hook).get_hookimpls()
    assert registry().names(kind)


def test_hookspecs_are_the_registry_kinds() -> None:
    assert set(HOOKS) == set(KINDS.values())
    assert len(HOOKS) >= 8


# --------------------------------------------------------------------------- a broken package


@pytest.fixture
def broken_package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """An installed distribution whose ``hbench`` entry point cannot be imported."""
    info = tmp_path / "hbench_broken_demo-0.0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: hbench-broken-demo\nVersion: 0.0.1\n"
    )
    (info / "entry_points.txt").write_text("[hbench]\nbroken-demo = hbench_no_such_module_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    return "broken-demo"


def test_a_plugin_that_fails_to_import_is_skipped_with_a_warning(
    broken_package: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    pm = make_manager()
    err = capsys.readouterr().err
    assert f"plugin {broken_package!r} failed to load" in err and "ModuleNotFoundError" in err
    assert f"HBENCH_DISABLE_PLUGINS={broken_package}" in err and len(err.splitlines()) == 1
    # every other plugin is still there
    assert {"wang-lsm", "bai-fu", "oracle"} <= set(Registry(pm).names("identifiers"))
    monkeypatch.setenv("HBENCH_DISABLE_PLUGINS", broken_package)
    make_manager()
    assert capsys.readouterr().err == ""


def test_provenance_names_the_plugins_packages() -> None:
    from hbench.tables import results

    versions = results.provenance()["versions"]
    for _plugin, dist in get_manager().list_plugin_distinfo():
        assert versions[dist.project_name] == dist.version


def test_a_plugin_nonlinearity_and_plant_are_config_options(
    run_cli: RunCli, example_plugin: ModuleType, tmp_path: Path
) -> None:
    """``nonlinearity=<plugin's name>`` and ``plant=<plugin's name>`` select them in a sweep,
    with their factories' defaults as keys that overrides can set."""
    import pandas as pd

    status, _, err = run_cli(
        [
            "sweep",
            "nonlinearity=quantizer",
            "nonlinearity.q=0.1",
            "plant=double-lag",
            "plant.t1=3",
            "method=wang-lsm",
            "runs=2",
            "scenario.duration=60",
            f"out={tmp_path}",
        ]
    )
    assert status == 0, err
    cfg = (tmp_path / "config.yaml").read_text()
    assert "name: quantizer" in cfg and "q: 0.1" in cfg
    assert "name: double-lag" in cfg and "t1: 3" in cfg and "t2: 0.5" in cfg
    rows = pd.read_parquet(tmp_path / "rows.parquet")
    assert set(rows["nonlinearity"]) == {"quantizer"} and len(rows)
    # a parameter the plugin does not take is a typo, as for the YAML options
    status, _, err = run_cli(["sweep", "nonlinearity=quantizer", "nonlinearity.d=0.1"])
    assert status == 2 and "nonlinearity.d" in err
