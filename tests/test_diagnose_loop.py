"""The ``closed-loop`` validation criterion (:mod:`hbench.diagnose.loop`): the controller
identified from ``(r - y, x)``, the loop re-simulated from ``r`` through the model."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core, loop
from hbench.diagnose import validate as va
from hbench.errors import InputError
from hbench.model.controllers import PI, P
from hbench.sim import scenarios
from hbench.sim.simulate import simulate


@pytest.mark.parametrize(
    ("cls", "theta"),
    [
        ("backlash", {"width": 0.3, "g0": 0.2}),
        ("stiction", {"S": 0.4, "J": 0.2, "d0": -1.0, "g0": 0.3}),
        ("deadband", {"lower": -0.1, "upper": 0.2}),
        ("saturation", {"u_min": -0.5, "u_max": 0.5}),
        ("linear", {}),
    ],
)
def test_the_valve_one_input_at_a_time_is_the_valve(cls: str, theta: dict) -> None:
    x = np.cumsum(np.random.default_rng(0).standard_normal(400)) * 0.1
    step = core.nl_stepper(cls, theta, float(x[0]))
    np.testing.assert_array_equal([step(v) for v in x], core.nl_one(cls, x, theta))


@pytest.mark.parametrize("ctl", [P(0.1), PI(0.12, 0.01, 0.6)])
def test_the_controller_is_identified_exactly(ctl: P | PI) -> None:
    """The controller's equation holds without noise (``x`` is computed from the measured
    ``y``), so least squares recovers it on a noisy record, structure and all."""
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec["noise"]["sigma2"] = 1e-3
    sc = scenarios.build(spec)
    sc.controller = ctl
    rec, _ = simulate(sc, 1, np.random.default_rng(4))
    e = loop.controller_error(rec.y[0], rec.r[0], rec.p)
    got = loop.identify_controller(rec.x[0], e)
    if isinstance(ctl, PI):
        assert got.structure == "PI"
        assert -got.b1 == pytest.approx(0.12, rel=1e-8)
        assert got.b0 + got.b1 == pytest.approx(0.01 * 0.6, rel=1e-6)
    else:
        assert got.structure == "P"
        assert got.b0 == pytest.approx(0.1, rel=1e-8) and got.c == pytest.approx(0, abs=1e-9)
        assert got.describe() == "P, kp 0.1, bias 0"  # a least-squares zero shown as 0
    # a structure given by the option is fitted as given
    assert loop.identify_controller(rec.x[0], e, "PI").structure == "PI"
    with pytest.raises(InputError):
        loop.identify_controller(rec.x[0], e, "PID")


def test_the_closed_loop_fit_of_the_paper_plant_without_noise() -> None:
    """A noise-free record of the paper's loop (backlash, PI): the nominal model re-simulated
    in the loop from ``r`` with the identified controller fits the validation part to better
    than 99 %, and the criterion is reported beside the other two."""
    case = dataclasses.replace(
        bc.draw_bench_case(10000, "none", "backlash", "paper"), noise_sigma=0.0
    )
    d = va.diagnose(bc.simulate_bench_case(case), criterion="closed-loop")
    assert d.criterion == "closed-loop"
    assert d.baseline_fit > 99.0
    assert set(d.fits["nominal"]) >= {"simulation", "closed-loop"}
    assert any(c.startswith("prediction-") for c in d.fits["nominal"])
    assert d.info["controller"].structure == "PI"
    assert d.as_json()["criterion"] == "closed-loop"


def test_a_record_without_r_falls_back_to_the_simulation() -> None:
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec["noise"]["sigma2"] = 1e-3
    rec, _ = simulate(scenarios.build(spec), 1, np.random.default_rng(5))
    d = va.diagnose(dataclasses.replace(rec, r=None), criterion="closed-loop")
    assert d.criterion == "simulation" and "closed-loop" not in d.fits["nominal"]


def test_the_cli_chooses_on_the_closed_loop_fit(run_cli, tmp_path) -> None:
    import json

    from hbench.io.readers import write_record

    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec["noise"]["sigma2"] = 1e-3
    rec, _ = simulate(scenarios.build(spec), 1, np.random.default_rng(6))
    path = write_record(rec, tmp_path / "r.csv")
    out = tmp_path / "d.json"
    status, stdout, err = run_cli(
        [
            "diagnose",
            str(path),
            "--criterion",
            "closed-loop",
            "--controller",
            "P",
            "--json",
            str(out),
        ]
    )
    assert status == 0, err
    assert json.loads(out.read_text())["criterion"] == "closed-loop"
    assert "closed-loop" in stdout and "controller P, kp 0.1" in stdout


@pytest.mark.parametrize(
    ("b0", "cls", "theta"),
    [
        (-50.0, "linear", {}),
        (-1e200, "linear", {}),
        (-50.0, "saturation", {"u_min": -np.inf, "u_max": 1e6}),  # a one-sided saturation
    ],
)
def test_a_diverging_loop_gives_an_infinite_error_without_warnings(
    b0: float, cls: str, theta: dict
) -> None:
    """Positive feedback through an integrating model: the re-simulated output leaves the
    floating-point range (inside the filter at kp 50; in the controller's product at 1e200).
    From its first sample that is not finite on, ``y_hat`` is one infinity of the sign the
    output ran off to, ``x_hat`` ``nan`` after its period, the fit ``-inf``, printed as
    diverging; numpy's overflow warnings do not reach the user (any warning fails this test).
    A valve with an infinite limit is a model like any other."""
    import warnings

    p, K = 5, 400
    lin = core.Linear(a=np.array([1.0, -1.0]), b=np.array([0.0, 1.0]), delay=0)
    model = core.Model(cls=cls, theta=theta, lin=lin, p=p)
    ctl = loop.LoopController("P", b0, 0.0, 0.0, 0.0)
    r = np.ones(K)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        y_hat, x_hat = loop.simulate_loop(model, ctl, r, 0.0)
        fit = core.fit_percent(np.sin(np.arange(K * p) / 7.0), y_hat)
    gone = np.flatnonzero(~np.isfinite(y_hat))
    assert gone.size and np.all(np.isinf(y_hat[gone[0] :]))
    assert np.all(y_hat[gone[0] :] == y_hat[gone[0]])  # one infinity
    assert np.sign(y_hat[gone[0]]) == np.sign(y_hat[gone[0] - 1])  # where it ran off to
    assert np.all(np.isfinite(y_hat[: gone[0]]))
    if b0 == -50.0:  # the filter overflows inside a period: marked from that sample
        assert gone[0] % p != 0
    m = int(np.flatnonzero(~np.isfinite(x_hat))[0])  # the controller output, in turn
    assert np.all(np.isfinite(x_hat[:m])) and np.isnan(x_hat[m + 1 :]).all()
    assert m <= gone[0] // p + 1
    assert fit == float("-inf")
    assert va.format_fit(fit).endswith("(diverges)")
    # a stable loop (negative feedback, small gain) is untouched by the check
    y_ok, _ = loop.simulate_loop(model, dataclasses.replace(ctl, b0=0.01), r, 0.0)
    assert np.all(np.isfinite(y_ok))


def test_a_model_with_a_nan_parameter_is_not_taken_for_a_diverging_loop() -> None:
    """A ``nan`` gain makes the output ``nan`` from the start: not an overflow, so the output
    is left as it comes (not marked as diverging to an infinity)."""
    p, K = 5, 50
    lin = core.Linear(a=np.array([1.0, -0.9]), b=np.array([0.0, 1.0]), delay=0)
    model = core.Model(cls="linear", theta={}, lin=lin, p=p, gain=float("nan"))
    y_hat, _ = loop.simulate_loop(
        model, loop.LoopController("P", 0.1, 0.0, 0.0, 0.0), np.ones(K), 0.0
    )
    assert np.isnan(y_hat).all()


def test_a_nominal_that_diverges_in_the_loop_measures_no_gain(monkeypatch, tmp_path) -> None:
    """Chosen on the closed-loop fit, where the nominal's loop diverges and the extensions'
    do not (the nominal's closed-loop output replaced by an overflow): every extension would
    gain ``+inf``. No extension is ranked; the cause is ``unexplained``, and the findings and
    the report say the nominal's fit diverges."""
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec["noise"]["sigma2"] = 1e-3
    rec, _ = simulate(scenarios.build(spec), 1, np.random.default_rng(7))
    real = va.criterion_output

    def nominal_diverges(ctx, model, nominal, crit, ysim=None):
        out = real(ctx, model, nominal, crit, ysim)
        if crit.loop is not None and model is nominal:
            return np.full_like(out, np.inf)
        return out

    monkeypatch.setattr(va, "criterion_output", nominal_diverges)
    d = va.diagnose(rec, criterion="closed-loop", extend_all=True)
    assert d.baseline_fit == float("-inf")
    assert any(np.isfinite(e.val_fit) for e in d.extensions.values())  # they would gain +inf
    assert d.cause == "unexplained"
    assert "(diverges)" in d.why and "no extension's gain can be measured" in d.why
    assert "(diverges)" in d.findings()[2]
    from hbench.diagnose.report import write_report

    md = write_report(d, tmp_path)[1].read_text()
    assert "(diverges)" in md
    assert "inf %" not in md and "nan %" not in md and "+inf" not in md
