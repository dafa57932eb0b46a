"""The example plugin's own tests: run with the package installed (``pip install -e .``).

``hbench.bench.conformance`` holds the checks every hbench method must pass; a plugin runs them on
its method by name, which also checks that the entry point registers it."""

import numpy as np
from hbench_example_plugin import PlainLS

from hbench.bench.conformance import check_method, paper_record
from hbench.ident.identifiers import IdentifyOptions, identify
from hbench.plugins import registry


def test_plain_ls_conforms():
    check_method("plain-ls")


def test_registered_by_the_entry_point():
    assert registry().get("identifiers", "plain-ls") is PlainLS


def test_noise_free_record_gives_the_true_plant():
    """On noise-free data OLS is exact: the paper's plant, its structure, and U to 1e-6."""
    record, truth = paper_record(3, 21)
    est = identify(PlainLS(), record, IdentifyOptions(), None)
    true = truth.plant.true_params()  # a1, a2, b2 of the paper's plant
    np.testing.assert_allclose(est.a, np.tile([true["a1"], true["a2"]], (3, 1)), atol=1e-8)
    np.testing.assert_allclose(est.b, np.tile([1.0, true["b2"]], (3, 1)), atol=1e-8)
    assert (est.na == 2).all() and (est.nb == 2).all() and (est.tau == 3).all()
    U = est.U / truth.plant.gain  # up to the gain: b1 = 1, so U_est = b1_true U
    ok = np.isfinite(U)
    assert ok.sum() > 0.9 * U.size  # U is defined (an all-nan U would pass the comparison)
    np.testing.assert_allclose(U[ok], truth.U[ok], atol=1e-6)
