"""Records of the benchmark's own loops for ``hbench diagnose``
(:mod:`hbench.diagnose.benchmark_cases`)."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose.generator import CLASSES, EFFECTS
from hbench.sim.simulate import ZeroOutputWarning, closed_loop_radius


def test_seed_ranges_are_disjoint() -> None:
    assert not set(bc.CALIBRATION_SEEDS) & set(bc.HELD_OUT_SEEDS)


def test_a_case_is_a_function_of_its_seed() -> None:
    a = bc.draw_bench_case(10_001, "drift", "stiction", "paper")
    b = bc.draw_bench_case(10_001, "drift", "stiction", "paper")
    assert a == b
    np.testing.assert_array_equal(bc.simulate_bench_case(a).y, bc.simulate_bench_case(b).y)
    assert bc.draw_bench_case(10_002, "drift", "stiction", "paper") != a


def test_paper_plant_cases_carry_the_papers_noise() -> None:
    c = bc.draw_bench_case(10_003, "none", "linear", "paper")
    assert c.p in (5, 8)
    assert 1e-4 <= c.sigma2 <= 1e-2
    assert c.noise_sigma == pytest.approx(np.sqrt(c.sigma2))
    assert c.effect_params["plant_den"] == [1.0, 0.32, 0.02]


def test_paper_snr_interpolates_the_papers_column() -> None:
    assert bc.paper_snr(1e-3) == pytest.approx(5.1003)
    assert bc.paper_snr(1e-2) == pytest.approx(1.8889)
    assert bc.paper_snr(3e-3) < bc.paper_snr(1e-3)


@pytest.mark.parametrize("plant", bc.BENCH_PLANTS)
def test_every_plant_gives_a_stable_loop_in_its_ranges(plant: str) -> None:
    for seed in range(10_010, 10_017):
        effect = EFFECTS[seed % len(EFFECTS)]
        cls = CLASSES[seed % len(CLASSES)]
        c = bc.draw_bench_case(seed, effect, cls, plant)
        assert c.controller["name"] in ("p", "pi")
        h = c.T / c.p
        from hbench.model.controllers import PI, P

        ctl = (
            P(c.controller["kp"])
            if c.controller["name"] == "p"
            else PI(c.controller["kp"], c.controller["ki"], c.T)
        )
        assert closed_loop_radius(bc.case_plant(c).discretize(h), ctl, c.p) < bc.MAX_RADIUS
        rec = bc.simulate_bench_case(c)
        assert rec.y.shape == (1, c.K * c.p) and rec.x.shape == (1, c.K)
        assert np.all(np.isfinite(rec.y)) and np.ptp(rec.x) > 0


def test_valve_parameters_follow_the_stated_ranges() -> None:
    for seed in range(10_020, 10_030):
        c = bc.draw_bench_case(seed, "none", "stiction", "paper")
        S, J = c.nl_params["S"], c.nl_params["J"]
        assert 0 < S and 0.1 * S - 1e-12 <= J <= S + 1e-12
        c = bc.draw_bench_case(seed, "none", "backlash", "paper")
        assert 0.0 < c.nl_params["d"] < 0.5  # 0.02-0.2 on the paper loop's x scale


def test_order_effect_has_three_poles_and_delay_effect_more_delay() -> None:
    c = bc.draw_bench_case(10_040, "order", "linear", "first-order")
    assert len(bc.case_plant(c).den) - 1 == 3
    c = bc.draw_bench_case(10_041, "delay", "linear", "paper")
    assert bc.case_plant(c).delay == 3 + c.effect_params["k"] * c.p


def test_the_grid_covers_every_cell() -> None:
    cases = bc.bench_grid(10_100, 1, plants=("paper",))
    assert len(cases) == len(CLASSES) * len(EFFECTS)
    assert {(c.cls, c.effect) for c in cases} == {(k, e) for k in CLASSES for e in EFFECTS}
    assert len({c.seed for c in cases}) == len(cases)


def test_a_written_case_has_its_truth_beside_it(tmp_path) -> None:
    c = bc.draw_bench_case(10_050, "outliers", "deadband", "nmp")
    path = bc.write_bench_case(c, tmp_path)
    assert path.exists() and (tmp_path / f"{c.name}.truth.json").exists()


def test_a_valve_at_rest_for_the_whole_record_is_redrawn(monkeypatch: pytest.MonkeyPatch) -> None:
    # calibration seeds whose first draw of the stiction leaves the valve at rest throughout
    # (P control, a sticking band wider than the excursions of x): y would be noise only
    seeds = [(13062, "delay", "paper"), (13068, "order", "paper"), (11101, "delay", "nmp")]
    with monkeypatch.context() as m:
        m.setattr(bc, "valve_moves", lambda case: True)
        first = [bc.draw_bench_case(s, e, "stiction", p) for s, e, p in seeds]
    for (seed, effect, plant), f in zip(seeds, first, strict=True):
        assert not bc.valve_moves(f)
        with pytest.warns(ZeroOutputWarning, match="never moves"):  # the simulation agrees
            bc.simulate_bench_case(f)
        c = bc.draw_bench_case(seed, effect, "stiction", plant)
        assert bc.valve_moves(c)
        assert c.nl_params != f.nl_params and replace(c, nl_params=f.nl_params) == f
        with warnings.catch_warnings():  # the simulation's own check: its valve moves
            warnings.simplefilter("error", ZeroOutputWarning)
            bc.simulate_bench_case(c)


def test_a_seed_whose_valve_never_moves_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    monkeypatch.setattr(bc, "valve_moves", lambda case: calls.append(case) or False)
    with pytest.raises(RuntimeError, match="stays at rest"):
        bc.draw_bench_case(13062, "delay", "stiction", "paper")
    assert len(calls) == bc.MAX_VALVE_DRAWS
