"""Composition of ``hbench/conf`` through Hydra's compose API, and the structured schema."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from hbench.plugins import registry
from hbench.sim import scenarios, seeding
from hbench.sweep import config

# pytest resets warning filters per test; hbench.sweep.config silences this Hydra note for users
pytestmark = pytest.mark.filterwarnings(f"ignore:{config.SCHEMA_NOTE}:UserWarning")

CONF = config.CONF_DIR
GROUPS = ("plant", "nonlinearity", "controller", "noise", "reference", "method", "experiment")
SIX = ["wang-lsm", "wang-iv", "bai-fu", "sun-liu-sano", "oracle", "oracle-inv"]


@pytest.fixture(scope="module")
def hydra_conf() -> Iterator[None]:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3", job_name="sweep"):
        yield


def make(*overrides: str, hydra: bool = False) -> Any:
    return compose("config", overrides=list(overrides), return_hydra_config=hydra)


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


ALL_OPTIONS = [(g, o) for g in GROUPS for o in options(g)]


def test_every_group_has_the_issues_options() -> None:
    assert {"paper", "first-order", "nmp", "third-order", "discrete"} <= set(options("plant"))
    assert {"linear", "backlash", "deadband", "saturation", "stiction"} <= set(
        options("nonlinearity")
    )
    assert {"p", "pi"} <= set(options("controller"))
    assert {"continuous", "arx", "white", "arma"} <= set(options("noise"))
    assert {"rbs", "prbs", "steps"} <= set(options("reference"))
    assert {*SIX, "all"} <= set(options("method"))
    assert {"paper_section6", "snr_p_delay"} <= set(options("experiment"))
    assert (CONF / "hydra" / "launcher" / "joblib.yaml").is_file()


@pytest.mark.parametrize(("group", "option"), ALL_OPTIONS, ids=[f"{g}={o}" for g, o in ALL_OPTIONS])
def test_every_option_composes_and_builds(hydra_conf: None, group: str, option: str) -> None:
    cfg = make(f"{group}={option}")
    data = config.plain(cfg)
    assert set(data) == set(config.TOP_LEVEL_KEYS)
    if group in config.PLUGIN_GROUPS:
        assert data[group]["name"] == option  # the file's name is the plugin's name
        registry().get(config.PLUGIN_GROUPS[group], option)
    # every parameter in the YAML is one the plugin takes (scenarios.build rejects others)
    scenarios.build(config.scenario_spec(data))
    config.identify_options(data)


def test_every_registered_identifier_is_a_method_option(hydra_conf: None) -> None:
    """The six have YAML files; other installed identifiers get a ConfigStore option."""
    config.register_methods()
    for name in [*registry().names("identifiers"), "all"]:
        methods = config.plain(make(f"method={name}"))["methods"]
        assert methods == (SIX if name == "all" else [name])
    assert set(SIX) <= set(options("method"))


def test_top_level_symlink_points_at_the_packaged_conf() -> None:
    link = Path(__file__).resolve().parents[1] / "conf"
    if not link.exists():
        pytest.skip("no conf link beside the package (installed copy)")
    assert link.resolve() == CONF


def test_defaults_are_the_papers_example(hydra_conf: None) -> None:
    data = config.plain(make())
    spec = config.scenario_spec(data)
    paper = dict(scenarios.PAPER_SECTION6)
    for key in ("T", "p", "duration"):
        assert spec[key] == paper[key]
    for part in ("nonlinearity", "controller", "reference"):
        assert {k: spec[part][k] for k in paper[part]} == paper[part]
    assert spec["plant"]["delay"] == 3 and spec["plant"]["name"] == "paper"
    assert {k: spec["noise"][k] for k in paper["noise"]} == paper["noise"]
    assert spec["noise"]["snr"] is None
    assert data["runs"] == 100 and data["seed"] == 0 and data["methods"] == SIX
    assert data["identify"]["nb_max"] is None and data["identify"]["na_range"] == [1, 5]


def test_paper_preset_composes_to_the_papers_scenario(hydra_conf: None) -> None:
    data = config.plain(make("experiment=paper_section6"))
    spec = config.scenario_spec(data)
    for part in ("plant", "nonlinearity", "controller", "noise", "reference"):
        paper = scenarios.PAPER_SECTION6[part]
        assert {k: spec[part][k] for k in paper} == paper, part
    assert config.identify_options(data, 0).nb_max == 4
    assert data["runs"] == 100 and data["methods"] == SIX


def test_sweep_preset_declares_the_issues_sweep(hydra_conf: None) -> None:
    cfg = make("experiment=snr_p_delay", hydra=True)
    params = OmegaConf.to_container(cfg.hydra.sweeper.params)
    assert params == {
        "noise.snr": "2,5,20",
        "scenario.p": "3,5,8",
        "plant.delay": "0,2,7",
        "method": "wang-lsm,bai-fu",
    }
    assert cfg.runs == 20
    # launcher options live in hydra/launcher only, never in a (swept) experiment file
    assert "n_jobs" not in (CONF / "experiment" / "snr_p_delay.yaml").read_text()
    assert "n_jobs" not in (CONF / "config.yaml").read_text()


def test_joblib_launcher_composes_with_its_options(hydra_conf: None) -> None:
    cfg = make("hydra/launcher=joblib", "hydra.launcher.n_jobs=2", hydra=True)
    assert cfg.hydra.launcher.n_jobs == 2
    assert cfg.hydra.launcher._target_.endswith("JoblibLauncher")
    assert make(hydra=True).hydra.launcher._target_.endswith("BasicLauncher")


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("runs=abc", "runs"),
        ("scenario.p=2.5", "scenario.p"),
        ("seed=[1]", "seed"),
        ("methods=wang-lsm", "methods"),
        ("identify.nb_max=x", "identify.nb_max"),
    ],
)
def test_wrong_type_fails_naming_the_key(hydra_conf: None, override: str, key: str) -> None:
    with pytest.raises(ConfigCompositionException) as info:
        make(override)
    assert info.value.__cause__.full_key == key


@pytest.mark.parametrize(
    "override", ["rnus=5", "plant.delya=7", "scenario.q=1", "identify.nbmax=3"]
)
def test_unknown_key_fails_at_composition(hydra_conf: None, override: str) -> None:
    with pytest.raises(ConfigCompositionException, match=override.split("=")[0]):
        make(override)


def test_noise_level_switches_by_the_key_overridden(hydra_conf: None) -> None:
    noise = config.plain(make())["noise"]
    assert (noise["sigma2"], noise["snr"]) == (0.001, None)
    noise = config.plain(make("noise.snr=5"))["noise"]
    assert (noise["sigma2"], noise["snr"]) == (None, 5)
    noise = config.plain(make("noise=white", "noise.snr=2"))["noise"]
    assert (noise["sigma2"], noise["snr"]) == (None, 2)
    noise = config.plain(make("noise.sigma2=0.01"))["noise"]
    assert (noise["sigma2"], noise["snr"]) == (0.01, None)
    scenario = scenarios.build(config.scenario_spec(make("noise.snr=5")))
    assert scenario.snr == 5 and scenario.sigma2 is None


def test_nb_max_null_is_p_minus_one(hydra_conf: None) -> None:
    assert config.identify_options(make("scenario.p=3")).nb_max == 2
    assert config.identify_options(make("scenario.p=8")).nb_max == 7
    assert config.identify_options(make("identify.nb_max=4")).nb_max == 4
    opts = config.identify_options(make("identify.tau_range=[0,2]"), delay_multiple=1)
    assert opts.tau_range == (0, 2) and opts.delay_multiple == 1


def test_pi_controller_takes_the_scenarios_period(hydra_conf: None) -> None:
    data = config.plain(make("controller=pi", "scenario.T=0.5"))
    assert data["controller"]["T"] == 0.5


def test_run_id_ignores_the_output_folder_and_number_spelling(hydra_conf: None) -> None:
    a = make("noise.snr=2", "out=/tmp/a")
    b = make("noise.snr=2.0", "out=/tmp/b")
    assert config.run_id(a) == config.run_id(b)
    assert config.run_id(a) != config.run_id(make("noise.snr=2", "runs=7"))
    assert config.run_id(a) != config.run_id(make("noise.snr=5"))


def test_cell_seed_depends_on_the_scenario_only(hydra_conf: None) -> None:
    def seed(*ov: str) -> list[int]:
        axes = config.scenario_axes(make(*ov))
        return list(seeding.cell_seed(0, config.canonical(axes)).entropy)

    base = seed("method=wang-lsm")
    assert seed("method=bai-fu") == base  # every method of a cell sees the same data
    assert seed("method=wang-lsm", "runs=3", "identify.nb_max=2") == base
    assert seed("method=wang-lsm", "plant.delay=2") != base
    assert seed("method=wang-lsm", "scenario.p=3") != base
    assert set(config.scenario_axes(make())) == {*config.PLUGIN_GROUPS, "scenario"}


def test_packaged_yaml_is_declared_as_package_data() -> None:
    import tomllib

    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    if not pyproject.exists():
        pytest.skip("no pyproject.toml beside the tests")
    data = tomllib.loads(pyproject.read_text())["tool"]["setuptools"]["package-data"]["hbench"]
    assert any(p.startswith("conf/**") for p in data)
