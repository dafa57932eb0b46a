"""Table 5's scoring conventions of ``hbench reproduce --investigate``: which runs the fitness
averages (``Config.fitness_runs``), the gain-centred scaling, the bounds' own scaling
(``Config.fitness_bound``), F_LSM and F_INV from the paper's steps (``Config.f_lsm``,
``Config.f_inv``), and the paper's own Table 4 rows scored on our loop (``published_row``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from hbench.bench.metrics import fitness, fitnesses
from hbench.errors import InputError
from hbench.paper import compare as pc
from hbench.paper import investigate as pi
from hbench.paper import levels as pl
from hbench.paper import published_row as pr
from hbench.tables.published import z_score


def _tidy(level, method, quantity, values):
    values = np.asarray(values, dtype=float)
    return pd.DataFrame(
        {
            "cell": "c",
            "method": method,
            "sigma2": level,
            "run": np.arange(values.size),
            "quantity": quantity,
            "value": values,
            "snr": 2.0,
            "status": "ok",
        }
    )


F_LSM = [80.0, -20.0, 50.0, -10.0]
F_INV = [30.0, -60.0, 10.0, 20.0]
F0 = [90.0, -5.0, 70.0, 75.0]


def _rows():
    return pd.concat(
        [
            _tidy(1e-2, "wang-lsm", "a1", [-1.97, -1.98, -1.975, -1.976]),
            _tidy(1e-2, "wang-lsm", "fitness", F_LSM),
            _tidy(1e-2, "wang-lsm-inv", "fitness", F_INV),
            _tidy(1e-2, "oracle", "fitness", F0),
            _tidy(1e-2, "wang", "a1", [-1.95, -1.96, -1.955, -1.956]),
            _tidy(1e-2, "wang", "fitness", [70.0, 60.0, 65.0, 40.0]),
            _tidy(1e-2, "wang-step-ii", "fitness", [55.0, 45.0, 35.0, 25.0]),
        ],
        ignore_index=True,
    )


def _cells(frame):
    return frame.set_index(["table", "row", "column", "method"])


def test_fitness_runs_exact_on_hand_made_values():
    """clip0: the mean of max(F, 0); nonnegative: the mean of the runs with F >= 0 (n = their
    number); every Table 5 cell (F and F0), no Table 4 cell."""
    rows = _rows()
    base = _cells(pc.compare_tables45(rows))
    clip = _cells(pc.compare_tables45(rows, pl.Config(fitness_runs="clip0")))
    keep = _cells(pc.compare_tables45(rows, pl.Config(fitness_runs="nonnegative")))
    f = (5, 1e-2, "F", "wang-lsm")
    assert base.loc[f, "ours"] == pytest.approx(25.0)
    assert clip.loc[f, "ours"] == pytest.approx(32.5)
    assert clip.loc[f, "ours_std"] == pytest.approx(np.std([80.0, 0.0, 50.0, 0.0], ddof=1))
    assert keep.loc[f, "ours"] == pytest.approx(65.0)
    assert keep.loc[f, "ours_std"] == pytest.approx(np.std([80.0, 50.0], ddof=1))
    want = z_score(65.0, float(np.std([80.0, 50.0], ddof=1)), 2, 49.0576, 24.879, 100, 1e-4)
    assert keep.loc[f, "z"] == pytest.approx(want)  # n is the runs kept
    inv = (5, 1e-2, "F", "wang-lsm-inv")
    assert clip.loc[inv, "ours"] == pytest.approx(15.0)
    assert keep.loc[inv, "ours"] == pytest.approx(20.0)
    f0 = (5, 1e-2, "F0", "oracle")
    assert clip.loc[f0, "ours"] == pytest.approx(58.75)
    assert keep.loc[f0, "ours"] == pytest.approx(235.0 / 3)
    t4 = base.index.get_level_values("table") == 4
    pd.testing.assert_frame_equal(base[t4], clip[t4])
    pd.testing.assert_frame_equal(base[t4], keep[t4])


def test_fitness_bound_scores_the_f0_columns_alone():
    """Config.fitness_bound: the F0 columns read their own scaling's quantity, F_LSM and F_INV
    keep ``fitness``'s; without it every column reads ``fitness``'s."""
    ls = [85.0, 0.0, 60.0, 30.0]
    rows = pd.concat(
        [
            _rows(),
            _tidy(1e-2, "wang-lsm", "fitness_ls", ls),
            _tidy(1e-2, "wang-lsm-inv", "fitness_ls", [40.0, -50.0, 15.0, 25.0]),
            _tidy(1e-2, "oracle", "fitness_ls", [91.0, 0.0, 71.0, 76.0]),
        ],
        ignore_index=True,
    )
    both = _cells(pc.compare_tables45(rows, pl.Config(fitness="ls")))
    split = _cells(pc.compare_tables45(rows, pl.Config(fitness="ls", fitness_bound="gain")))
    f, inv, f0 = (
        (5, 1e-2, "F", "wang-lsm"),
        (5, 1e-2, "F", "wang-lsm-inv"),
        (5, 1e-2, "F0", "oracle"),
    )
    assert both.loc[f, "ours"] == split.loc[f, "ours"] == pytest.approx(np.mean(ls))
    assert both.loc[inv, "ours"] == split.loc[inv, "ours"] == pytest.approx(7.5)
    assert both.loc[f0, "ours"] == pytest.approx(59.5)
    assert split.loc[f0, "ours"] == pytest.approx(np.mean(F0))  # the true gain's
    assert pl.Config(fitness="ls", fitness_bound="gain").bound_fitness == "gain"
    assert pl.Config(fitness="ls").bound_fitness == "ls"
    assert pl.Config(fitness_bound="gain-centred").custom_loop
    for bad in ({"fitness": "none"}, {"fitness_bound": "median"}):
        with pytest.raises(InputError, match="must be one of"):
            pl.Config(**bad)


def test_fitness_runs_helper_keeps_missing_runs_missing():
    v = np.array([-1.0, np.nan, 3.0, 0.0])
    np.testing.assert_array_equal(pc.fitness_runs(v, "all"), v)
    np.testing.assert_array_equal(pc.fitness_runs(v, "clip0"), [0.0, np.nan, 3.0, 0.0])
    np.testing.assert_array_equal(pc.fitness_runs(v, "nonnegative"), [np.nan, 3.0, 0.0])
    with pytest.raises(InputError):
        pc.fitness_runs(v, "positive")
    with pytest.raises(InputError):
        pl.Config(fitness_runs="positive")


def test_defaults_are_unchanged_byte_for_byte():
    """The new keys at their defaults average every run, F_LSM from ``lsm``: the comparison is
    the same bytes whether they are given or not, and its F is the plain mean of all runs."""
    rows = _rows()
    default = pc.compare_tables45(rows).to_csv(index=False, float_format="%.10g")
    spelled = pl.Config(fitness_runs="all", f_lsm=None)
    explicit = pl.Config(fitness_runs="all", f_lsm="wang-lsm")
    for config in (spelled, explicit):
        again = pc.compare_tables45(rows, config).to_csv(index=False, float_format="%.10g")
        assert again == default
    cells = _cells(pc.compare_tables45(rows))
    assert cells.loc[(5, 1e-2, "F", "wang-lsm"), "ours"] == pytest.approx(np.mean(F_LSM))
    # the defaults' provenance names the new keys with their default values
    desc = pl.Config().describe()
    assert desc["fitness_runs"] == "all" and desc["f_lsm"] is None
    assert pl.Config().f_lsm_method == "wang-lsm"
    assert pl.Config(lsm="wang").f_lsm_method == "wang"


def test_f_lsm_moves_f_lsm_alone():
    """Config.f_lsm: Table 5's F_LSM from the paper's step (ii) / steps (ii)+(iv); Table 4's
    LSM rows keep wang-lsm; the investigation matches every cell with the defaults' (slot)."""
    rows = _rows()
    before = pc.compare_tables45(rows)
    for method, mean in (("wang-step-ii", 40.0), ("wang", 58.75)):
        after = pc.compare_tables45(rows, pl.Config(f_lsm=method))
        cells = _cells(after)
        assert cells.loc[(5, 1e-2, "F", method), "ours"] == pytest.approx(mean)
        assert cells.loc[(4, 1e-2, "a1", "wang-lsm"), "ours"] == pytest.approx(-1.97525)
        changed = before["ours"].to_numpy() != after["ours"].to_numpy()
        changed &= np.isfinite(before["ours"].to_numpy())
        moved = before[changed]
        cells_moved = zip(moved["table"], moved["column"], moved["method"], strict=True)
        assert list(cells_moved) == [(5, "F", "wang-lsm")]
        row = pi.investigation_row(pl.Config(label="f", f_lsm=method), before, after)
        assert row["cells"] == int(np.isfinite(before["z"]).sum())


def test_gain_centred_fitness_is_the_gain_fitness_without_the_mean_error():
    """F_gc = 100 (1 - sqrt(||e||^2 - K mean(e)^2) / ||U - mean U||), e = U_est / b1 - U, on the
    samples both signals define; >= F_gain, = F_gain when mean(e) = 0."""
    rng = np.random.default_rng(3)
    U = rng.standard_normal((3, 50))
    gain = np.array([2.0, 0.5, 1.5])
    noise = 0.2 * rng.standard_normal((3, 50))
    est = gain[:, None] * (U + noise + np.array([0.3, -0.1, 0.0])[:, None])
    est[1, :7] = np.nan
    noise[2] -= noise[2].mean()  # run 2: no mean error
    est[2] = gain[2] * (U[2] + noise[2])
    F = fitnesses(est, U, ("gain", "gain-centred"), gain, compiled=False)
    for i in range(3):
        m = np.isfinite(est[i])
        e = est[i, m] / gain[i] - U[i, m]
        den = np.linalg.norm(U[i, m] - U[i, m].mean())
        want = 100.0 * (1.0 - math.sqrt(e @ e - m.sum() * e.mean() ** 2) / den)
        assert F["gain-centred"][i] == pytest.approx(want, rel=1e-12)
        assert F["gain-centred"][i] >= F["gain"][i]
    assert F["gain-centred"][0] > F["gain"][0] + 1.0  # an offset of 0.3 is removed
    assert F["gain-centred"][2] == pytest.approx(F["gain"][2], rel=1e-12)
    np.testing.assert_array_equal(fitness(est, U, "gain-centred", gain), F["gain-centred"])
    with pytest.raises(InputError):
        fitness(est, U, "gain-centred")


def test_the_new_alternatives_are_declared():
    alts = {a.label: a for a in pi.alternatives()}
    assert alts["fitness-clip0"].fitness_runs == "clip0"
    assert alts["fitness-nonnegative-runs"].fitness_runs == "nonnegative"
    assert alts["fitness-gain-centred"].fitness == "gain-centred"
    assert alts["fitness-gain-centred"].custom_loop
    assert alts["f-lsm-step-ii"].f_lsm == "wang-step-ii"
    assert alts["f-lsm-steps-ii-iv"].f_lsm == "wang"
    for label in ("f-lsm-step-ii", "f-lsm-steps-ii-iv"):
        assert alts[label].lsm == "wang-lsm"
    # post-processed only where the default rows hold what they read ("wang" runs by default)
    assert {"fitness-clip0", "fitness-nonnegative-runs", "f-lsm-steps-ii-iv"} <= pi.POST_PROCESSED
    assert "f-lsm-step-ii" not in pi.POST_PROCESSED  # wang-step-ii is not among the defaults
    assert "wang" in pl.ALL_METHODS and "wang-step-ii" not in pl.ALL_METHODS
    assert "fitness-gain-centred" not in pi.POST_PROCESSED
    # F_LSM and F_INV from wang's estimates (F_INV's method runs for that alternative only)
    assert alts["f-steps-ii-iv"].f_lsm == "wang" and alts["f-steps-ii-iv"].f_inv == "wang-inv"
    assert "wang-inv" not in pl.ALL_METHODS and "f-steps-ii-iv" not in pi.POST_PROCESSED
    ls = alts["fitness-ls-estimates"]
    assert (ls.fitness, ls.bound_fitness) == ("ls", "gain") and ls.label in pi.POST_PROCESSED
    both = alts["f-steps-ii-iv+fitness-ls-estimates"]
    assert (both.f_lsm, both.f_inv, both.fitness, both.bound_fitness) == (
        "wang",
        "wang-inv",
        "ls",
        "gain",
    )


def test_the_inverse_variants_are_their_methods_with_the_direct_inverse():
    """``wang-lsm-inv`` is ``wang-lsm``, ``wang-inv`` is ``wang``, each with its method's
    options under the config and ``inverse='auto'``."""
    config = pl.Config(pooled=False, eq15="modulus")
    methods = pl.make_methods(config, ["wang-lsm", "wang-lsm-inv", "wang", "wang-inv"])
    for name, base in (("wang-lsm-inv", "wang-lsm"), ("wang-inv", "wang")):
        assert methods[name].name == base
        want = {**methods[base].options(), "inverse": "auto"}
        assert methods[name].options() == want
    assert methods["wang-lsm-inv"].options()["eq15"] == "modulus"
    assert "select_a" in methods["wang-inv"].options()
    assert methods["wang-inv"].options()["pooled"] is False


def test_the_scalings_are_named_once_for_the_config():
    from hbench.bench.metrics import SCALINGS

    assert tuple(pl.FITNESS_QUANTITY) == SCALINGS
    assert pc.FITNESS_QUANTITY is pl.FITNESS_QUANTITY
    assert pl.RUNNER_SCALINGS < set(SCALINGS)


def test_explained_cells_give_each_alternatives_z():
    def frame(zs):
        return pd.DataFrame(
            {
                "table": 4,
                "row": 1e-3,
                "column": [f"q{i}" for i in range(len(zs))],
                "method": "m",
                "z": zs,
            }
        ).assign(paper=1.0, paper_std=0.1, ours=1.0, ours_std=0.1)

    out = pi.explained_cells(frame([10.0, 0.5, -4.0]), {"a": frame([1.0, 0.5, -6.0])})
    assert list(out["z:a"]) == [1.0, -6.0]
    assert list(out["within_by"]) == ["a (+1.0)", ""]


def test_published_parameters_are_the_printed_rows():
    assert pr.published_parameters(1e-2, "paper-lsm") == {
        "a1": -1.9781,
        "a2": 0.9799,
        "b2": -0.7232,
    }
    assert pr.published_parameters(5e-3, "paper-ivm")["b2"] == -0.7353
    assert pr.published_units(5e-3, "paper-ivm") == pytest.approx(
        {"a1": 1e-4, "a2": 1e-4, "b2": 1e-4}
    )
    assert pr.published_parameters(1e-2, "paper-true") == {
        "a1": -1.962,
        "a2": 0.9623,
        "b2": -0.7244,
    }
    with pytest.raises(InputError):
        pr.published_parameters(1e-2, "paper-xyz")


def test_published_row_on_the_true_parameters_is_the_oracle():
    """The plant's exact parameters give the oracles' fitness run by run (same realisations,
    same seeds); the paper's printed true values (4 digits) give F within a point of them."""
    from hbench.bench.runner import methods_from_names
    from hbench.ident.identifiers import IdentifyOptions, identify
    from hbench.sim import scenarios
    from hbench.sim.simulate import simulate

    runs, seed, s2 = 4, pl.DEFAULT_SEED, 1e-3
    table = pr.published_row(runs, seed, levels=(s2,), models=("paper-true", "true"))
    scenario = scenarios.build(pl.scenario_spec(pl.Config(), s2))
    record, truth = simulate(scenario, runs, np.random.default_rng(pl.level_seed(seed, s2)))
    options = IdentifyOptions(delay_multiple=scenario.discrete_plant.delay_multiple(scenario.p))
    oracles = methods_from_names(["oracle", "oracle-inv"])
    true = table.set_index("model").loc["true"]
    printed = table.set_index("model").loc["paper-true"]
    for column, name in (("F_LSM", "oracle"), ("F_INV", "oracle-inv")):
        est = identify(oracles[name], record, options, truth)
        F = fitness(est.U, truth.U, "gain", truth.plant.gain)
        assert true[column] == pytest.approx(float(np.mean(F)), rel=1e-12)
        assert abs(printed[column] - true[column]) < 1.0
        assert true[column] > 80.0  # sigma^2 = 1e-3: the paper's F0 are 91.4 and 86.0


def test_published_row_table_and_text():
    table = pr.published_row(3, pl.DEFAULT_SEED, levels=(1e-2,))
    assert list(table["model"]) == list(pr.MODELS)
    assert {"F_LSM", "F_INV", "paper_F_LSM", "paper_F_INV", "z_F_LSM", "z_F_INV"} <= set(table)
    assert (table["paper_F_LSM"] == 49.0576).all() and (table["paper_F_INV"] == 36.0619).all()
    # the printed digits' box holds the printed point: its F lies within the corners' range
    paper = table[table["model"] != "true"]
    for column in ("F_LSM", "F_INV"):
        lo, hi = paper[f"{column}_rounding_min"], paper[f"{column}_rounding_max"]
        assert (lo <= paper[column] + 1e-9).all() and (paper[column] <= hi + 1e-9).all()
        assert (hi > lo).all()
    assert table.loc[table["model"] == "true", "F_LSM_rounding_min"].isna().all()
    text = pr.published_row_text(table)
    assert "sigma^2 = 0.01: paper-lsm F_LSM" in text and "paper: F_LSM 49.06" in text
    assert "printed digits' range" in text
    json.dumps(table.to_dict("records"))  # plain values
    with pytest.raises(InputError):
        pr.published_row(3, 1, models=("nope",))


def test_report_shows_the_cells_beyond_and_the_published_row(tmp_path):
    from hbench.report import build

    pd.DataFrame(
        {
            "table": [5, 5],
            "row": [1e-2, 5e-3],
            "column": ["F", "F"],
            "method": ["wang-lsm", "wang-lsm-inv"],
            "z": [-5.6, -4.0],
            "within_by": ["", "rbs-band-0.25 (-1.1)"],
            "z:rbs-band-0.25": [-4.2, -1.1],
        }
    ).to_csv(tmp_path / "investigation_cells.csv", index=False)
    assert build._cells_beyond_html(tmp_path / "nowhere") == []
    html = "".join(build._cells_beyond_html(tmp_path))
    assert "1 of 2 cells beyond |z| = 2" in html and "rbs-band-0.25 (-1.1)" in html
    assert "z:rbs-band-0.25" not in html.split("</p>", 1)[1]  # the wide columns stay in the CSV
    pr.published_row(2, pl.DEFAULT_SEED, levels=(1e-2,)).to_csv(
        tmp_path / "published_row.csv", index=False
    )
    html = "".join(build._cells_beyond_html(tmp_path))
    assert 'id="published-row"' in html and "paper-lsm" in html


def test_published_row_beside_our_own_mean_estimate():
    """``ours``: our Table 4 LSM means as one more fixed model, with our F cells beside."""
    means = pi._our_means(pc.compare_tables45(_rows()))
    assert means[1e-2]["a1"] == pytest.approx(-1.97525)
    assert means[1e-2]["F_LSM"] == pytest.approx(25.0)
    assert means[1e-2]["F_INV"] == pytest.approx(0.0)
    ours = {1e-2: {"a1": -1.9781, "a2": 0.9799, "b2": -0.7232, "F_LSM": 12.0, "F_INV": 7.0}}
    table = pr.published_row(2, pl.DEFAULT_SEED, levels=(1e-2,), ours=ours).set_index("model")
    assert list(table.index) == [*pr.MODELS, pr.OURS]
    # the same parameters as the paper's LSM row: the same fitness, run by run
    for column in ("F_LSM", "F_INV"):
        assert table.loc[pr.OURS, column] == table.loc["paper-lsm", column]
    assert table.loc[pr.OURS, "own_F_LSM"] == 12.0 and table.loc[pr.OURS, "own_F_INV"] == 7.0
    assert table.loc["paper-lsm", "own_F_LSM"] == 49.0576
    assert math.isnan(table.loc["true", "own_F_LSM"])
    assert "(our F cells 12.0, 7.0)" in pr.published_row_text(table.reset_index())


def test_published_means_against_the_truth():
    """z of a published mean against the plant's true value with the paper's own spread; the
    IVM's b2 at sigma^2 = 1e-3 (-0.7171 +- 0.0188 over 100 runs) is 3.9 SE off -0.72435."""
    t = pr.paper_against_truth().set_index(["sigma2", "method", "column"])
    cell = t.loc[(1e-3, "wang-iv", "b2")]
    true_b2 = cell["true"]
    assert true_b2 == pytest.approx(-0.7244, abs=5e-5)
    want = (-0.7171 - true_b2) / math.sqrt(0.0188**2 / 100 + 1e-8 / 12)
    assert cell["z_truth"] == pytest.approx(want) and 3.5 < want < 4.2
    assert len(t) == 30  # 5 noisy levels x 2 methods x 3 parameters
    text = pr.paper_against_truth_text(t.reset_index())
    assert "wang-iv b2 @ 0.001: -0.7171" in text and "wang-lsm" not in text
    assert "within 50 SE" in pr.paper_against_truth_text(t.reset_index(), limit=50.0)
