"""The validation criterion of ``hbench diagnose`` (K-step prediction beside simulation), the
valve class's margin, and the detectors' verdict rule."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from hbench.diagnose import effects, nominal
from hbench.diagnose import validate as va
from hbench.errors import InputError
from hbench.io.readers import write_record
from hbench.sim import scenarios
from hbench.sim.simulate import simulate

RunCli = Callable[[list[str]], tuple[int, str, str]]


def test_prediction_of_noise_is_its_k_step_error() -> None:
    """For ``y = y_sim + e / D``: ``y - y_hat(t | t - K) = F_K e``, F_K the first K terms of
    the impulse response of 1 / D (derived in :class:`hbench.diagnose.validate.Criterion`)."""
    rng = np.random.default_rng(0)
    d = np.array([1.0, -1.5, 0.56])  # poles 0.7 and 0.8
    e = rng.standard_normal(3000)
    ysim = np.sin(np.arange(3000) / 50.0)
    y = ysim + signal.lfilter([1.0], d, e)
    for k in (1, 3, 10):
        imp = np.zeros(k)
        imp[0] = 1.0
        fk = signal.lfilter([1.0], d, imp)
        err = y - va.predict(y, ysim, d, k)
        np.testing.assert_allclose(err, signal.lfilter(fk, [1.0], e), atol=1e-9)
    # one step: the innovations themselves
    np.testing.assert_allclose(y - va.predict(y, ysim, d, 1), e, atol=1e-9)
    # a horizon past the impulse response's life: the simulation
    np.testing.assert_allclose(va.predict(y, ysim, d, 400), ysim, atol=1e-8)
    # no noise model, or horizon 0: the simulation
    np.testing.assert_array_equal(va.predict(y, ysim, None, 5), ysim)
    np.testing.assert_array_equal(va.predict(y, ysim, d, 0), ysim)


def test_the_horizon_rule_is_the_dominant_time_constant() -> None:
    assert va.dominant_horizon(np.array([1.0, -0.99]), 10_000) == 100  # ceil(-1 / ln 0.99)
    assert va.dominant_horizon(np.array([1.0, -1.962, 0.9623]), 10_000) == int(
        np.ceil(-1 / np.log(max(abs(np.roots([1.0, -1.962, 0.9623])))))
    )
    # clipped: at least HORIZON_MIN, at most a quarter of the validation part
    assert va.dominant_horizon(np.array([1.0, -0.1]), 1000) == va.HORIZON_MIN
    assert va.dominant_horizon(np.array([1.0, -0.9999]), 400) == 100
    assert va.dominant_horizon(np.ones(1), 400) == va.HORIZON_MIN


def test_criteria_are_named_and_checked() -> None:
    assert va.parse_criterion("simulation") == va.Criterion(0)
    assert va.parse_criterion("prediction-12") == va.Criterion(12)
    assert va.Criterion(12).name == "prediction-12" and va.Criterion(0).name == "simulation"
    for record_dependent in ("prediction", "closed-loop", "auto"):
        assert va.parse_criterion(record_dependent) is None
    for bad in ("prediction-0", "prediction-x", "open-loop", "prediction--3", "closed"):
        with pytest.raises(InputError):
            va.parse_criterion(bad)


def _paper_record(sigma2: float, nl: dict, seed: int = 3):
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec["noise"]["sigma2"] = sigma2
    spec["nonlinearity"] = nl
    rec, _ = simulate(scenarios.build(spec), 1, np.random.default_rng(seed))
    return rec


@pytest.mark.parametrize("nl", [{"name": "linear"}, {"name": "backlash", "d": 0.1}])
def test_the_criterion_is_informative_on_the_paper_plant_without_noise(nl: dict) -> None:
    """The paper's loop (poles 0.97, 0.99 at the fast rate) without noise: the nominal model
    predicts the validation part to better than 99 % under the stated criterion."""
    d = va.diagnose(_paper_record(0.0, nl))
    assert d.criterion == "simulation"
    assert d.baseline_fit > 99.0
    pred = [c for c in d.fits["nominal"] if c.startswith("prediction-")]
    assert len(pred) == 1 and va.HORIZON_MIN <= int(pred[0].split("-")[1]) <= 200
    assert d.fits["nominal"][pred[0]] > 99.0
    assert d.nonlinearity["class"] == nl["name"]
    again = va.diagnose(d.ctx.record, criterion="prediction")
    assert again.criterion == pred[0] and again.baseline_fit > 99.0


def test_a_fixed_criterion_is_the_one_reported() -> None:
    rec = _paper_record(1e-3, {"name": "linear"})
    d = va.diagnose(rec, criterion="simulation")
    assert d.criterion == "simulation"
    assert d.baseline_fit == pytest.approx(va.val_fit(d.ctx, d.nominal.model))
    d5 = va.diagnose(rec, criterion="prediction-5")
    assert d5.criterion == "prediction-5" and "simulation" in d5.fits["nominal"]
    # a 5-step predictor knows more of the noise than the simulation does
    assert d5.baseline_fit > d.baseline_fit


def test_bad_criterion_exits_2_with_one_line(run_cli: RunCli, tmp_path: Path) -> None:
    path = write_record(_paper_record(1e-3, {"name": "linear"}), tmp_path / "r.csv")
    status, _, err = run_cli(["diagnose", str(path), "--criterion", "open-loop"])
    assert status == 2
    assert len(err.strip().splitlines()) == 1 and "criterion" in err


def test_json_names_the_criterion_and_the_margin(run_cli: RunCli, tmp_path: Path) -> None:
    path = write_record(_paper_record(1e-3, {"name": "backlash", "d": 0.1}), tmp_path / "r.csv")
    out = tmp_path / "d.json"
    status, stdout, err = run_cli(["diagnose", str(path), "--json", str(out)])
    assert status == 0, err
    d = json.loads(out.read_text())
    assert d["criterion"] == "simulation"
    nl = d["nonlinearity"]
    assert nl["confident"] == (nl["margin"] >= va.CONFIDENT_MARGIN)
    first = stdout.splitlines()[0]
    assert first.startswith("valve: ")  # the summary leads with the findings
    assert stdout.splitlines()[1].startswith("cause: ")


def test_class_margin() -> None:
    from hbench.diagnose.classes import ClassFit

    # a stiction fit without a slip jump is the backlash it nests, not its rival
    fits = {
        "linear": ClassFit("linear", {}, 1.0, 100, 2, score=0.0),
        "backlash": ClassFit("backlash", {"width": 0.1}, 1.0, 100, 3, score=50.0),
        "stiction": ClassFit("stiction", {"S": 0.1, "J": 0.0}, 1.0, 100, 4, score=49.0),
        "deadband": ClassFit("deadband", {}, 1.0, 100, 4, score=10.0),
    }
    m, runner = va.class_margin("backlash", fits)
    assert runner == "deadband" and m == pytest.approx(0.8)
    assert list(va.nested_rivals("backlash", fits)) == ["stiction"]  # the findings say why
    assert "a backlash" in va.nested_rivals("backlash", fits)["stiction"]
    assert va.nested_rivals("deadband", fits) == {}  # nested only beside the class it holds
    fits["stiction"].theta = {"S": 0.1, "J": 0.05}
    m, runner = va.class_margin("backlash", fits)
    assert runner == "stiction" and m == pytest.approx(0.02)
    assert va.nested_rivals("backlash", fits) == {}
    m, runner = va.class_margin("backlash", {"linear": 0.0, "backlash": 40.0, "stiction": 30.0})
    assert runner == "stiction" and m == pytest.approx(0.25)
    m, runner = va.class_margin("linear", {"linear": 0.0, "backlash": 2.0, "stiction": 1.0})
    assert runner == "backlash" and m < 0  # chosen by a rule, not by the score
    m, runner = va.class_margin("linear", {"linear": 0.0})
    assert runner == "" and m == np.inf


def test_findings_say_why_a_nested_class_is_no_rival() -> None:
    """A backlash record (the benchmark's paper-loop record of seed 13014, no effect) whose
    stiction fit scores about as much as the backlash but has next to no slip jump: the margin
    is to the next class, and the first line gives both scores and says why stiction is not
    the runner-up."""
    from hbench.diagnose import benchmark_cases as bc

    case = bc.draw_bench_case(13014, "none", "backlash", "paper")
    d = va.diagnose(bc.simulate_bench_case(case))
    fits = d._final_class()[1]
    assert d.nonlinearity["class"] == "backlash"
    assert list(va.nested_rivals("backlash", fits)) == ["stiction"]
    _, runner = va.class_margin("backlash", fits)
    assert runner not in ("", "stiction")
    first = d.findings()[0]
    share = 100 * nominal.MIN_JUMP_SHARE
    score = f"{fits['stiction'].score:.1f}, backlash's {fits['backlash'].score:.1f}"
    assert f"over {runner}; stiction's fit (score {score}) is no rival: its slip jump, " in first
    assert f"% of its band, is below {share:g} %: a backlash)" in first


def test_the_slip_jump_rule_is_one_rule_for_the_chooser_and_the_margin() -> None:
    """A stiction fit with a slip jump of 12 % of its band is a stiction (the benchmark draws
    J / S from 0.1): the graph chooser takes it over a backlash it beats, and beside a chosen
    backlash it is a rival; at 9.9 % it is the backlash it nests in both."""
    from hbench.diagnose.classes import ClassFit

    assert nominal.MIN_JUMP_SHARE == 0.1  # the lower end of benchmark_cases' J / S
    for jr, chosen, nested in ((0.12, "stiction", set()), (0.099, "backlash", {"stiction"})):
        fits = {
            "linear": ClassFit("linear", {}, 1.0, 100, 2, score=0.0),
            "backlash": ClassFit("backlash", {"width": 0.1}, 1.0, 100, 3, score=50.0),
            "stiction": ClassFit("stiction", {"S": 0.1, "J": 0.1 * jr}, 1.0, 100, 4, score=60.0),
        }
        assert nominal.choose_graph(fits) == chosen
        assert set(va.nested_rivals("backlash", fits)) == nested


def test_a_one_sided_dead_zone_is_no_rival_of_the_saturation_it_nests() -> None:
    from hbench.diagnose.classes import ClassFit

    fits = {
        "linear": ClassFit("linear", {}, 1.0, 100, 2, score=0.0),
        "saturation": ClassFit("saturation", {}, 1.0, 100, 4, score=30.0),
        "deadband": ClassFit("deadband", {}, 1.0, 100, 4, score=31.0, info={"one_sided": True}),
    }
    assert list(va.nested_rivals("saturation", fits)) == ["deadband"]
    margin, runner = va.class_margin("saturation", fits)
    assert runner == "linear" and margin == pytest.approx(1.0)
    fits["deadband"].info = {}  # two-sided: a rival
    assert va.nested_rivals("saturation", fits) == {}
    assert va.class_margin("saturation", fits)[1] == "deadband"
    # bare scores nest nothing
    assert va.nested_rivals("backlash", {"backlash": 5.0, "stiction": 4.0}) == {}


class _Probe(effects.Effect):
    name = "probe"
    threshold = 1.0


@pytest.mark.parametrize(
    ("stat", "p", "fired", "said"),
    [
        (2.0, 1e-6, True, "fires"),
        (2.0, 0.3, False, "is not below"),
        (0.5, 1e-45, False, "below the threshold"),
        (0.5, 0.5, False, "quiet"),
        (float("nan"), 1e-9, False, "below the threshold"),
    ],
)
def test_verdict_never_contradicts_the_p_value(
    stat: float, p: float, fired: bool, said: str
) -> None:
    det = _Probe()._det(stat, p, "probe")
    assert det.fired is fired
    assert said in det.evidence
    if det.fired:
        assert det.p_value < effects.ALPHA and det.statistic > det.threshold
