"""Fitting the actuator classes: on the ``(x, U)`` graph (``p >= 2``) or through the dynamics
(``p = 1``).

Every class is fitted as ``u = c f(x; theta) + d``: the inner signal of a blind method carries an
unknown gain and offset (the normalisation ``b1 = 1``), and through the dynamics the linear part
takes them. ``theta`` is searched on a grid scaled to the robust range of ``x`` (1st to 99th
percentile; a dead zone's edges at quantiles of ``x`` and, where ``x`` jumps across the band,
inside the gaps of ``x``: :func:`gap_bands`), then on a finer grid around the best point. The
memory classes also grid the state the valve started in (the record does not say where it
was): ``g0`` (where in its band) and, for stiction, ``d0`` (the direction it last moved).

Scores (the contract's ``nonlinearity.scores``): the evidence for each class over ``linear``,
larger is better and ``linear`` is 0. On the graph it is half the BIC difference
``(BIC_linear - BIC_class) / 2`` (a log Bayes factor); through the dynamics it is the gain in
simulation fit, in points of %, on the samples fitted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from hbench.diagnose import core
from hbench.diagnose.core import CLASSES, N_SHAPE, nl_batch
from hbench.diagnose.stats import lagged

#: Parameters of the contract's JSON per class (the initial-state keys stay internal).
PUBLIC: dict[str, tuple[str, ...]] = {
    "linear": (),
    "backlash": ("width",),
    "deadband": ("lower", "upper"),
    "saturation": ("u_min", "u_max"),
    "stiction": ("S", "J"),
}


def public_params(cls: str, theta: dict[str, float], gain: float | None = None) -> dict[str, Any]:
    """The class parameters for reports and JSON (finite floats or None for a one-sided limit)."""
    out: dict[str, Any] = {}
    for k in PUBLIC[cls]:
        v = float(theta[k])
        out[k] = v if np.isfinite(v) else None
    if gain is not None:
        out["gain"] = float(gain)
    return out


@dataclass
class ClassFit:
    """The best member of one class."""

    cls: str
    theta: dict[str, float]
    rss: float
    n: int
    k: int
    score: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def bic(self) -> float:
        return float(self.n * np.log(max(self.rss, 1e-300) / self.n) + self.k * np.log(self.n))


def score_against_linear(fits: dict[str, ClassFit]) -> dict[str, ClassFit]:
    """Set every fit's ``score`` to ``(BIC_linear - BIC) / 2`` (``fits`` holds ``linear``);
    returns ``fits``."""
    base = fits["linear"].bic
    for f in fits.values():
        f.score = float((base - f.bic) / 2)
    return fits


# --------------------------------------------------------------------------- candidate grids


def _mesh(**axes: np.ndarray) -> dict[str, np.ndarray]:
    grids = np.meshgrid(*axes.values(), indexing="ij")
    return {k: g.ravel() for k, g in zip(axes, grids, strict=True)}


def coarse_grid(cls: str, x: np.ndarray) -> dict[str, np.ndarray]:
    """A coarse grid of candidates for ``cls`` scaled to ``x`` (a dead zone: both edges at the
    5 %-step quantiles of ``x``, and the bands of :func:`gap_bands`)."""
    s = core.scale_of(x)
    if cls == "linear":
        return {}
    if cls == "backlash":
        return _mesh(width=s * np.geomspace(0.003, 1.2, 24), g0=np.linspace(0, 1, 5))
    if cls == "stiction":
        g = _mesh(
            S=s * np.geomspace(0.003, 1.2, 16),
            jr=np.linspace(0, 1, 6),
            d0=np.array([1.0, -1.0]),
            g0=np.linspace(0, 1, 5),
        )
        return {"S": g["S"], "J": g["S"] * g["jr"], "d0": g["d0"], "g0": g["g0"]}
    q = np.quantile(x, np.linspace(0.0, 1.0, 21))
    if cls == "deadband":
        lo, hi = np.meshgrid(q[1:-1], q[1:-1], indexing="ij")
        m = lo <= hi
        gap = gap_bands(x)
        return {
            "lower": np.concatenate([lo[m], gap["lower"]]),
            "upper": np.concatenate([hi[m], gap["upper"]]),
        }
    if cls == "saturation":
        lows = np.concatenate([[-np.inf], q[1:11]])
        highs = np.concatenate([q[10:-1], [np.inf]])
        lo, hi = np.meshgrid(lows, highs, indexing="ij")
        m = lo < hi
        return {"u_min": lo[m], "u_max": hi[m]}
    raise ValueError(cls)


#: Dead zone: the largest gaps of sorted ``x`` searched for a band (:func:`gap_bands`,
#: :func:`deadband_partitions`), each with at least :data:`TAIL_SHARE` of the samples on
#: either side ...
DEADBAND_GAPS = 5
#: ... (the quantile candidates' range, 5 % to 95 %: a gap next to the few most extreme
#: samples would give them an offset of their own, a dead zone fitting an outlier) ...
TAIL_SHARE = 0.05
#: ... and the band widths tried in each gap (equal steps up to the gap's width).
GAP_WIDTHS = 12


def _tail_count(n: int) -> int:
    """The fewest samples (at least one) on each side of a dead-zone candidate's gap or
    partition: :data:`TAIL_SHARE` of ``n``."""
    return max(1, round(TAIL_SHARE * n))


def _inner_gaps(xs: np.ndarray) -> np.ndarray:
    """Indices ``k`` of the :data:`DEADBAND_GAPS` largest gaps ``xs[k + 1] - xs[k] > 0`` of
    sorted ``xs`` with at least :data:`TAIL_SHARE` of the samples on each side, largest
    first (ties: the lower ``k`` first)."""
    n = xs.size
    m = _tail_count(n)
    gaps = np.diff(xs)
    k = np.arange(gaps.size)
    inner = (k + 1 >= m) & (n - (k + 1) >= m) & (gaps > 0)
    k, g = k[inner], gaps[inner]
    return k[np.argsort(-g, kind="stable")][:DEADBAND_GAPS]


def gap_bands(x: np.ndarray) -> dict[str, np.ndarray]:
    """Dead-zone candidates ``lower <= upper`` inside the largest gaps of sorted ``x``
    (:func:`_inner_gaps`): :data:`GAP_WIDTHS` widths per gap, from ``1 / GAP_WIDTHS`` of the
    gap to all of it, each band centred in its gap (non-finite ``x`` left out).

    In a closed loop ``x`` often jumps across a dead zone and never rests in it, so sorted
    ``x`` has a gap there and no quantile of ``x`` (the other candidates' edges) is a band
    edge. With no sample in the band only its width shows (``f(x) = x - upper`` above it,
    ``x - lower`` below it: the band's position is an offset, which the fit's own offset
    takes), so a grid of widths in the gap covers every such band; the finer grids then move
    each edge."""
    xs = np.sort(np.asarray(x, float)[np.isfinite(x)])
    top = _inner_gaps(xs) if xs.size >= 2 else np.empty(0, int)
    w = (xs[top + 1] - xs[top])[:, None] * (np.arange(1, GAP_WIDTHS + 1) / GAP_WIDTHS)[None, :]
    a, b = xs[top][:, None], xs[top + 1][:, None]
    half_rest = (b - a - w) / 2  # >= 0: the band inside [a, b], rounding included
    return {"lower": (a + half_rest).ravel(), "upper": (b - half_rest).ravel()}


def fine_grid(
    cls: str, x: np.ndarray, theta: dict[str, float], spread: float = 1.0
) -> dict[str, np.ndarray]:
    """A finer grid around ``theta``; ``spread`` < 1 narrows it by that factor (relative
    widths ``1.25 ** spread``, offsets and steps times ``spread``)."""
    s = core.scale_of(x)
    r = 1.25**spread
    if cls == "backlash":
        return _mesh(
            width=theta["width"] * np.geomspace(1 / r, r, 9),
            g0=np.clip(theta["g0"] + spread * np.linspace(-0.125, 0.125, 5), 0, 1),
        )
    if cls == "stiction":
        S0, J0 = theta["S"], theta["J"]
        jr0 = J0 / S0 if S0 > 0 else 0.0
        g = _mesh(
            S=S0 * np.geomspace(1 / r, r, 7),
            jr=np.clip(jr0 + spread * np.linspace(-0.1, 0.1, 5), 0, 1),
            d0=np.array([theta["d0"]]),
            g0=np.clip(theta["g0"] + spread * np.linspace(-0.125, 0.125, 5), 0, 1),
        )
        return {"S": g["S"], "J": g["S"] * g["jr"], "d0": g["d0"], "g0": g["g0"]}
    step = 0.05 * s * spread
    if cls == "deadband":
        g = _mesh(
            lower=theta["lower"] + step * np.linspace(-1, 1, 7),
            upper=theta["upper"] + step * np.linspace(-1, 1, 7),
        )
        m = g["lower"] <= g["upper"]
        return {k: v[m] for k, v in g.items()}
    if cls == "saturation":
        lo0, hi0 = theta["u_min"], theta["u_max"]
        lows = np.array([lo0]) if not np.isfinite(lo0) else lo0 + step * np.linspace(-1, 1, 7)
        highs = np.array([hi0]) if not np.isfinite(hi0) else hi0 + step * np.linspace(-1, 1, 7)
        g = _mesh(u_min=lows, u_max=highs)
        m = g["u_min"] < g["u_max"]
        return {k: v[m] for k, v in g.items()}
    return {}


def deadband_partitions(x: np.ndarray, U: np.ndarray) -> dict[str, np.ndarray]:
    r"""Dead-zone candidates ``(lower, upper)`` fitted to the graph ``(x, U)`` per partition of
    the data, for the grid search of :func:`fit_graph`.

    The dead zone ``f(x) = x - clip(x, lower, upper)`` is linear in its parameters once it is
    known which samples lie below the band (``L``), in it (``M``) and above it (``R``):

    .. math::

        U = c f(x) + d = c\,x\,1_{L \cup R} - c\,\mathrm{lower}\,1_L
            - c\,\mathrm{upper}\,1_R + d,

    least squares in ``(c, -c lower, -c upper, d)``. With ``M`` empty, ``d`` and the band's
    position are not identified (``1_L + 1_R = 1``): ``U = c x + b + g 1_R`` gives the width
    ``w = -g / c``, and the band is centred in the gap of ``x`` between ``L`` and ``R``. In a
    closed loop ``x`` often jumps across the dead zone and never rests in it, so sorted ``x``
    has a gap there and no quantile of ``x`` is a band edge: the coarse grid's quantile
    candidates then miss the band, which these find exactly (noise-free).

    Partitions: split positions of sorted ``x`` at its 5 %-step quantiles and after its
    largest inner gaps (:func:`_inner_gaps`); every pair ``i <= j`` (``L`` = the first ``i``
    samples, ``M`` the next ``j - i``, ``R`` the rest), with at least :data:`TAIL_SHARE` of
    the samples in ``L`` and in ``R``. Each pair's fit with a finite gain ``c``, its edges
    clipped into the partition's own intervals (so that the candidate puts the same samples
    below, in and above the band), is one candidate; the grid search scores it by its own
    least squares like any other. The sums are taken on ``x`` standardised (the edges mapped
    back), so the result does not depend on the offset and scale of ``x``. Samples with a
    non-finite ``x`` or ``U`` are left out; fewer than 8 samples, or a constant ``x``, give no
    candidate.

    Returns
    -------
    dict
        ``{"lower": array, "upper": array}``, ``lower <= upper`` elementwise (the band is
        closed: ``f = 0`` for ``lower <= x <= upper``).
    """
    ok = np.isfinite(U) & np.isfinite(x)
    order = np.argsort(x[ok], kind="stable")
    xs, us = x[ok][order], U[ok][order]
    n = xs.size
    sd = float(np.std(xs)) if n else 0.0
    if n < 8 or not sd > 0:
        return {"lower": np.empty(0), "upper": np.empty(0)}
    mu = float(np.mean(xs))
    z = (xs - mu) / sd  # the sums of the normal equations on a standardised x
    m = _tail_count(n)
    pos = set(np.round(np.linspace(0, n, 21)[1:-1]).astype(int).tolist())
    pos.update((_inner_gaps(xs) + 1).tolist())
    pos_a = np.array(sorted(p for p in pos if m <= p <= n - m))
    if pos_a.size == 0:
        return {"lower": np.empty(0), "upper": np.empty(0)}
    i, j = np.meshgrid(pos_a, pos_a, indexing="ij")
    keep = i <= j
    i, j = i[keep], j[keep]
    # sums over L (the first i samples) and R (from j on) of 1, z, z^2, U, z U: prefix sums
    cs = [np.concatenate([[0.0], np.cumsum(v)]) for v in (np.ones(n), z, z * z, us, z * us)]
    (nL, xL, qL, uL, vL), (nR, xR, qR, uR, vR) = zip(
        *((c[i], c[n] - c[j]) for c in cs), strict=True
    )
    lower = np.full(i.size, np.nan)
    upper = np.full(i.size, np.nan)
    # M non-empty: regressors (z 1_{L u R}, 1_L, 1_R, 1)
    m4 = j > i
    G = np.zeros((int(m4.sum()), 4, 4))
    r = np.zeros((int(m4.sum()), 4))
    G[:, 0, 0] = qL[m4] + qR[m4]
    G[:, 0, 1] = G[:, 1, 0] = xL[m4]
    G[:, 0, 2] = G[:, 2, 0] = xR[m4]
    G[:, 0, 3] = G[:, 3, 0] = xL[m4] + xR[m4]
    G[:, 1, 1] = G[:, 1, 3] = G[:, 3, 1] = nL[m4]
    G[:, 2, 2] = G[:, 2, 3] = G[:, 3, 2] = nR[m4]
    G[:, 3, 3] = n
    r[:, 0] = vL[m4] + vR[m4]
    r[:, 1], r[:, 2], r[:, 3] = uL[m4], uR[m4], cs[3][n]
    with np.errstate(all="ignore"):
        sol = (np.linalg.pinv(G) @ r[..., None])[..., 0]
        lower[m4] = -sol[:, 1] / sol[:, 0]
        upper[m4] = -sol[:, 2] / sol[:, 0]
    # M empty: regressors (z, 1, 1_R); the width w = -g / c, centred in the gap
    e = ~m4
    G3 = np.zeros((int(e.sum()), 3, 3))
    r3 = np.zeros((int(e.sum()), 3))
    G3[:, 0, 0] = qL[e] + qR[e]
    G3[:, 0, 1] = G3[:, 1, 0] = xL[e] + xR[e]
    G3[:, 0, 2] = G3[:, 2, 0] = xR[e]
    G3[:, 1, 1] = n
    G3[:, 1, 2] = G3[:, 2, 1] = G3[:, 2, 2] = nR[e]
    r3[:, 0] = vL[e] + vR[e]
    r3[:, 1], r3[:, 2] = cs[3][n], uR[e]
    with np.errstate(all="ignore"):
        sol3 = (np.linalg.pinv(G3) @ r3[..., None])[..., 0]
        w = -sol3[:, 2] / sol3[:, 0]
    a, b = z[i[e] - 1], z[i[e]]
    w = np.where(np.isfinite(w), np.clip(w, 0.0, b - a), np.nan)
    lower[e] = a + (b - a - w) / 2
    upper[e] = b - (b - a - w) / 2
    # a fit without a finite gain (c = 0) is no candidate; the others' edges, back on the
    # scale of x, are clipped into the partition's own intervals: L below lower, M inside, R
    # above upper (i = j, M empty: both in the same gap)
    fit = np.isfinite(lower) & np.isfinite(upper)
    lower = np.clip(mu + sd * lower, xs[i - 1], xs[i])
    upper = np.clip(mu + sd * upper, xs[j - 1], xs[j])
    good = fit & (lower <= upper)
    return {"lower": lower[good], "upper": upper[good]}


def _take(params: dict[str, np.ndarray], c: int) -> dict[str, float]:
    return {k: float(v[c]) for k, v in params.items()}


# --------------------------------------------------------------------------- on the (x, U) graph


def _graph_rss(F: np.ndarray, U: np.ndarray) -> np.ndarray:
    """RSS of ``U ~ c F[i] + d`` for every row of ``F`` (least squares, vectorised)."""
    Fm = F - F.mean(axis=1, keepdims=True)
    Um = U - U.mean()
    sff = np.einsum("cn,cn->c", Fm, Fm)
    sfu = Fm @ Um
    suu = float(Um @ Um)
    with np.errstate(divide="ignore", invalid="ignore"):
        rss = suu - np.where(sff > 1e-300, sfu**2 / np.where(sff > 1e-300, sff, 1.0), 0.0)
    return np.maximum(rss, 0.0)


def _graph_best(
    cls: str, x: np.ndarray, U: np.ndarray, ok: np.ndarray, params: dict[str, np.ndarray]
) -> tuple[dict[str, float], float]:
    F = nl_batch(cls, x, params)[:, ok]
    rss = _graph_rss(F, U[ok])
    c = int(np.argmin(rss))
    return _take(params, c), float(rss[c])


def fit_graph(
    x: np.ndarray, U: np.ndarray, classes: tuple[str, ...] = CLASSES, shift: int = 0
) -> dict[str, ClassFit]:
    """Every class fitted to the graph ``(x(n - shift), U(n))``; NaN in ``U`` are skipped.

    Returns class -> :class:`ClassFit` with ``score = (BIC_linear - BIC) / 2``.
    """
    x = np.asarray(x, float)
    U = np.asarray(U, float)
    if shift:
        x = np.concatenate([np.full(shift, x[0]), x[:-shift]])
    ok = np.isfinite(U)
    n = int(ok.sum())
    fits: dict[str, ClassFit] = {}
    for cls in classes:
        if cls == "linear":
            theta: dict[str, float] = {}
            rss = float(_graph_rss(x[None, ok], U[ok])[0])
        else:
            grid = coarse_grid(cls, x)
            if cls == "deadband":  # edges inside gaps of x, where no quantile is
                extra = deadband_partitions(x, U)
                grid = {k: np.concatenate([v, extra[k]]) for k, v in grid.items()}
            theta, rss = _graph_best(cls, x, U, ok, grid)
            for seed in nested_starts(cls, {c: f.theta for c, f in fits.items()}, x[ok]):
                rs = float(
                    _graph_rss(
                        nl_batch(cls, x, {k: np.array([v]) for k, v in seed.items()})[:, ok], U[ok]
                    )[0]
                )
                if rs < rss:
                    theta, rss = seed, rs
            for _ in range(2):
                theta2, rss2 = _graph_best(cls, x, U, ok, fine_grid(cls, x, theta))
                if rss2 < rss:
                    theta, rss = theta2, rss2
        info = shape_info(cls, theta, x[ok])
        fits[cls] = ClassFit(cls, theta, rss, n, 2 + N_SHAPE[cls], info=info)
    base = fits["linear"].bic if "linear" in fits else min(f.bic for f in fits.values())
    for f in fits.values():
        f.score = float((base - f.bic) / 2)
    return fits


def nested_starts(
    cls: str, fitted: dict[str, dict[str, float]], x: np.ndarray
) -> list[dict[str, float]]:
    """Starting points for ``cls`` at the fitted simpler class that it holds or that holds it:
    stiction at the backlash it holds as ``J = 0``; saturation at the one-sided saturation a
    :func:`one_sided` dead zone equals (:func:`one_sided_saturations`). ``fitted`` maps the
    classes fitted so far to their parameters; ``x`` the samples the tail counts are over."""
    if cls == "stiction" and fitted.get("backlash"):
        b = fitted["backlash"]
        return [{"S": b["width"], "J": 0.0, "d0": 1.0, "g0": b["g0"]}]
    if cls == "saturation" and fitted.get("deadband"):
        return one_sided_saturations(fitted["deadband"], x)
    return []


def one_sided_saturations(band: dict[str, float], x: np.ndarray) -> list[dict[str, float]]:
    """The one-sided saturation a :func:`one_sided` dead zone ``band`` equals over ``x``, up to
    an offset and the few samples beyond its far edge (none for a two-sided band):
    ``x - clip(x, lower, upper)`` is ``min(x, lower) - lower`` where no ``x`` exceeds ``upper``
    and ``max(x, upper) - upper`` where none is below ``lower``. The saturation fits start
    there too, so that such a dead zone is tested against the saturation it nests."""
    xs = np.asarray(x, float)[np.isfinite(x)]
    m = _tail_count(xs.size)
    lo, hi = float(band["lower"]), float(band["upper"])
    out = []
    # the saturation clips at least the candidates' tail share (no offset for a few extremes)
    if np.sum(xs >= hi) < m <= np.sum(xs >= lo):
        out.append({"u_min": -np.inf, "u_max": lo})
    if np.sum(xs <= lo) < m <= np.sum(xs <= hi):
        out.append({"u_min": hi, "u_max": np.inf})
    return out


def one_sided(theta: dict[str, float], x: np.ndarray) -> bool:
    """Whether the dead zone ``theta`` leaves fewer than :data:`TAIL_SHARE` of the finite
    samples of ``x`` at or beyond one of its edges (the share the quantile and gap candidates
    keep on each side; the finer grid and the partition fits can move an edge past it). Over
    the data such a band is a one-sided saturation at its other edge plus an offset
    (:func:`one_sided_saturations`) but for those few samples, so the class rules ask it to
    beat that saturation as a nested model
    (:func:`hbench.diagnose.nominal.choose_graph`)."""
    xs = np.asarray(x, float)[np.isfinite(x)]
    beyond = min(np.sum(xs <= theta["lower"]), np.sum(xs >= theta["upper"]))
    return bool(beyond < _tail_count(xs.size))


def shape_info(cls: str, theta: dict[str, float], x: np.ndarray) -> dict[str, Any]:
    """What the class rules read of a fitted map besides its score: ``strength``
    (:func:`strength`) and, for a dead zone, ``one_sided`` (:func:`one_sided`)."""
    shown = bool(theta) or cls == "linear"
    info: dict[str, Any] = {"strength": strength(cls, theta, x) if shown else 0.0}
    if cls == "deadband" and theta:
        info["one_sided"] = one_sided(theta, x)
    return info


def strength(cls: str, theta: dict[str, float], x: np.ndarray) -> float:
    """How far ``f(x; theta)`` is from a straight line in ``x`` over the data: the share of its
    variance a linear fit leaves (0 for linear; a tiny backlash or a dead zone where ``x``
    never goes is not a nonlinearity the record can show)."""
    if cls == "linear":
        return 0.0
    f = core.nl_one(cls, x, theta)
    if np.ptp(f) == 0:
        return 1.0
    r = np.corrcoef(f, x)[0, 1]
    return float(1.0 - r**2) if np.isfinite(r) else 1.0


def gain_offset(
    cls: str, theta: dict[str, float], x: np.ndarray, U: np.ndarray
) -> tuple[float, float]:
    """``(c, d)`` of ``U ~ c f(x; theta) + d`` by least squares (NaN in ``U`` skipped)."""
    f = core.nl_one(cls, x, theta)
    ok = np.isfinite(U)
    A = np.stack([f[ok], np.ones(int(ok.sum()))], axis=1)
    c, d = np.linalg.lstsq(A, U[ok], rcond=None)[0]
    return float(c), float(d)


# --------------------------------------------------------------------------- through the dynamics


#: Denominators tried in the batch stage besides the linear model's own: first-order lags and
#: double poles, enough to rank candidates before the output-error refit.
def _a_candidates(a_lin: np.ndarray) -> list[np.ndarray]:
    out = [np.asarray(a_lin, float)]
    for r in (0.0, 0.6, 0.85, 0.95):
        out.append(np.array([1.0, -r]))
    for r in (0.7, 0.9):
        out.append(np.poly([r, r]))
    return out


@dataclass
class LinearStructure:
    """The linear part's structure chosen for ``linear``: orders and delay (fast samples)."""

    na: int
    nb: int
    delay: int
    fit: core.OEFit


def select_linear(
    u: np.ndarray, y: np.ndarray, idx: np.ndarray, *, na_values=(1, 2, 3), delays=range(0, 9)
) -> LinearStructure:
    """Output-error orders ``na = nb`` and delay by BIC on ``idx``."""
    best: tuple[float, LinearStructure] | None = None
    n = idx.size
    for na in na_values:
        for d in delays:
            f = core.oe_fit(u, y, na, na, d, idx)
            bic = n * np.log(max(f.rss, 1e-300) / n) + (2 * na + 1) * np.log(n)
            if best is None or bic < best[0]:
                best = (bic, LinearStructure(na, na, d, f))
    assert best is not None
    ls = best[1]
    f = core.oe_fit(u, y, ls.na, ls.nb, ls.delay, idx, refine=True)
    if f.rss < ls.fit.rss:
        ls.fit = f
    return ls


def _delays_near(d: int, spread: int = 1) -> list[int]:
    return sorted({max(d + k, 0) for k in range(-spread, spread + 1)})


def _batch_stage(
    cls: str,
    x: np.ndarray,
    y: np.ndarray,
    p: int,
    idx: np.ndarray,
    params: dict[str, np.ndarray],
    a_set: list[np.ndarray],
    delays: list[int],
    weights: np.ndarray | None,
    prefilter: np.ndarray | None = None,
) -> np.ndarray:
    """Smallest RSS over ``a_set`` and ``delays`` per candidate (separable least squares)."""
    F = nl_batch(cls, x, params)
    if p > 1:
        F = np.repeat(F, p, axis=1)
    best = np.full(F.shape[0], np.inf)
    for a in a_set:
        rss, _, _ = core.batch_fixed_a(F, y, a, delays, 2, idx, weights, prefilter)
        best = np.minimum(best, rss.min(axis=1))
    return best


def fit_dynamic(
    cls: str,
    x: np.ndarray,
    y: np.ndarray,
    p: int,
    idx: np.ndarray,
    lin: LinearStructure,
    *,
    weights: np.ndarray | None = None,
    top: int = 3,
    prefilter: np.ndarray | None = None,
    delays: list[int] | None = None,
    a_set: list[np.ndarray] | None = None,
    theta0: dict[str, float] | None = None,
) -> tuple[ClassFit, core.OEFit]:
    """The best member of ``cls`` through the dynamics: ``y ~ G(q) f(x; theta) + m``.

    The linear part is re-fitted for every candidate: separable least squares with a few
    denominators fixed (the batch stage ranks the grid), then an output-error refit of the
    ``top`` candidates with ``lin``'s orders and the delay re-searched by +-1 (default).
    ``prefilter`` (FIR ``D``): prediction error with the noise model ``1 / D`` instead of
    output error; the returned fit's ``yhat`` and ``rss`` are then on the filtered data.
    ``theta0`` (a parameter set of ``cls`` found otherwise) is refined as one more seed.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    yf = y if prefilter is None else signal.lfilter(prefilter, [1.0], y)
    if cls == "linear" and prefilter is None:
        return ClassFit("linear", {}, lin.fit.rss, lin.fit.n, 2 * lin.na + 1), lin.fit
    a_set = _a_candidates(lin.fit.lin.a) if a_set is None else a_set
    delays = _delays_near(lin.delay, 1 if p == 1 else p) if delays is None else delays
    if cls == "linear":
        u = np.repeat(x, p) if p > 1 else x
        uf = signal.lfilter(prefilter, [1.0], u - u[0])
        best_f = None
        for d in delays:
            for kw in ({"refine": True}, {"a_fixed": lin.fit.lin.a}):
                f = core.oe_fit(uf, yf, lin.na, lin.nb, d, idx, weights=weights, **kw)
                if best_f is None or f.rss < best_f.rss:
                    best_f = f
        assert best_f is not None
        return ClassFit("linear", {}, best_f.rss, best_f.n, 2 * lin.na + 1), best_f
    params = coarse_grid(cls, x)
    score = _batch_stage(cls, x, y, p, idx, params, a_set, delays, weights, prefilter)
    order = np.argsort(score)
    seeds: list[dict[str, float]] = [dict(theta0)] if theta0 else []
    for c in order:
        th = _take(params, int(c))
        if all(any(abs(th[k] - s[k]) > 1e-12 * (1 + abs(s[k])) for k in th) for s in seeds):
            seeds.append(th)
        if len(seeds) >= top + bool(theta0):
            break
    # refine each seed on a finer grid (batch stage), then output-error refit
    found: list[tuple[float, dict[str, float], core.OEFit, bool]] = []
    for th in seeds:
        fp = fine_grid(cls, x, th)
        sc = _batch_stage(cls, x, y, p, idx, fp, a_set, delays, weights, prefilter)
        th2 = _take(fp, int(np.argmin(sc)))
        is_seed = bool(theta0) and th is seeds[0]
        for th3 in (th2, th) if is_seed else (th2,):
            u = core.nl_one(cls, x, th3)
            uf = np.repeat(u, p) if p > 1 else u
            if prefilter is not None:
                uf = signal.lfilter(prefilter, [1.0], uf - uf[0])
            best_here: core.OEFit | None = None
            for d in delays:
                for a_fixed in (None, lin.fit.lin.a):
                    f = core.oe_fit(
                        uf, yf, lin.na, lin.nb, d, idx, weights=weights, a_fixed=a_fixed
                    )
                    if best_here is None or f.rss < best_here.rss:
                        best_here = f
            assert best_here is not None
            found.append((best_here.rss, th3, best_here, is_seed and th3 is th))
    # the exact output-error refit of the two best candidates and of the given seed
    found.sort(key=lambda c: c[0])
    finalists = found[:2] + [c for c in found[2:] if c[3]]
    best: tuple[float, dict[str, float], core.OEFit] | None = None
    for rss0, th3, f0, _ in finalists:
        u = core.nl_one(cls, x, th3)
        uf = np.repeat(u, p) if p > 1 else u
        if prefilter is not None:
            uf = signal.lfilter(prefilter, [1.0], uf - uf[0])
        g = core.oe_fit(
            uf, yf, lin.na, lin.nb, f0.lin.delay, idx, weights=weights, a_init=f0.lin.a, refine=True
        )
        cand = (g.rss, th3, g) if g.rss < rss0 else (rss0, th3, f0)
        if best is None or cand[0] < best[0]:
            best = cand
    assert best is not None
    rss, theta, f = best
    return ClassFit(cls, theta, rss, f.n, 2 * lin.na + 1 + N_SHAPE[cls]), f


# --------------------------------------------------------------------------- equation error


def fit_equation_error(
    cls: str,
    x: np.ndarray,
    y: np.ndarray,
    p: int,
    idx: np.ndarray,
    na: int,
    nb: int,
    delay: int,
    theta0: dict[str, float] | None = None,
    extra: np.ndarray | None = None,
    coarse: bool = False,
    prefilter: np.ndarray | None = None,
) -> tuple[dict[str, float], float, np.ndarray]:
    """The class's parameters and an ARX linear part by equation error on ``idx``.

    ``y(t) + a1 y(t-1) + .. = b1 f(x)(t - delay - 1) + .. + m + e(t)``: the nominal noise
    model's own criterion (the paper's eq. 2); ``extra`` (shared regressors, e.g. a trend) as in
    :func:`hbench.diagnose.core.batch_arx`. A coarse grid (or the fine grid around ``theta0``),
    then a finer grid around the best; ``coarse``: the coarse grid as well when ``theta0`` is
    given (the better start wins). Returns ``(theta, rss, [a, b, m, ...])``.
    """

    if prefilter is not None:  # D(q) on y, the inputs and the shared regressors alike
        y = signal.lfilter(prefilter, [1.0], np.asarray(y, float))
        if extra is not None:
            extra = signal.lfilter(prefilter, [1.0], np.asarray(extra, float), axis=0)

    def inputs(F: np.ndarray) -> np.ndarray:
        if p > 1:
            F = np.repeat(F, p, axis=1)
        return F if prefilter is None else signal.lfilter(prefilter, [1.0], F, axis=1)

    def best_of(params: dict[str, np.ndarray]) -> tuple[dict[str, float], float, np.ndarray]:
        rss, th = core.batch_arx(inputs(nl_batch(cls, x, params)), y, na, nb, delay, idx, extra)
        c = int(np.argmin(rss))
        return _take(params, c), float(rss[c]), th[c]

    if cls == "linear":
        F = inputs(np.asarray(x, float)[None, :])
        rss, th = core.batch_arx(F, y, na, nb, delay, idx, extra)
        return {}, float(rss[0]), th[0]
    start = fine_grid(cls, x, theta0) if theta0 is not None else coarse_grid(cls, x)
    theta, rss, th = best_of(start)
    if theta0 is not None:
        t0, r0, h0 = best_of({k: np.array([v]) for k, v in theta0.items()})
        if r0 < rss:
            theta, rss, th = t0, r0, h0
        if coarse:
            t1, r1, h1 = best_of(coarse_grid(cls, x))
            if r1 < rss:
                theta, rss, th = t1, r1, h1
    for spread in (1.0, 1.0, 0.2, 0.04):  # then two narrower passes: grid steps of ~0.5 %
        t2, r2, h2 = best_of(fine_grid(cls, x, theta, spread))
        if r2 < rss:
            theta, rss, th = t2, r2, h2
    return theta, rss, th


# --------------------------------------------------------------------------- class selection


#: Denominator orders, numerator lengths and trend order of the equation-error structure the
#: class is chosen in (:func:`selection_structure`); the delay is searched from ``p`` fast
#: samples below the blind model's to ``DELAY_SPAN_SLOW`` slow samples above it.
NA_SELECT: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
NB_SELECT: tuple[int, ...] = (2, 4)
TREND_ORDER = 2
DELAY_SPAN_SLOW = 3
#: Rows whose equation error exceeds this many robust standard deviations (1.4826 MAD) of the
#: best class's residual are outliers (:func:`trim_outliers`) ...
OUTLIER_Z = 5.0
#: ... when they are at most this share of the rows (more is a misfit, not outliers; a spike
#: enters ``na + 1`` rows, and a first fit that the spikes bias flags a few more).
OUTLIER_SHARE = 0.1


def trend_columns(N: int, order: int) -> np.ndarray | None:
    """Legendre polynomials of degree ``1 .. order`` on ``t`` mapped to ``[-1, 1]``: ``(N,
    order)``, or None for ``order = 0``."""
    if order <= 0:
        return None
    t = np.linspace(-1.0, 1.0, N)
    return np.stack(
        [np.polynomial.legendre.Legendre.basis(k)(t) for k in range(1, order + 1)], axis=1
    )


@dataclass
class EqStructure:
    """The equation-error structure the class is chosen in: ``A(q) y(t) = B(q) f(x)(t - delay
    - 1) + m + T(t) c + w(t)`` with ``T`` the trend columns, on the rows ``idx``."""

    na: int
    nb: int
    delay: int
    extra: np.ndarray | None
    idx: np.ndarray

    @property
    def n(self) -> int:
        return int(np.sum(self.idx >= max(self.na, self.delay + self.nb)))

    @property
    def k_linear(self) -> int:
        """Parameters of the linear part (``a, b, m`` and the trend)."""
        k = 0 if self.extra is None else self.extra.shape[1]
        return self.na + self.nb + 1 + k


def selection_structure(
    inputs: np.ndarray,
    y: np.ndarray,
    p: int,
    idx: np.ndarray,
    delay0: int,
    trend: int = TREND_ORDER,
) -> EqStructure:
    """The structure ``(na, nb, delay)`` of :class:`EqStructure` by BIC.

    A valve class is told from ``linear`` by the likelihood ratio of two fits in one linear
    structure. If that structure is too poor (an order or a delay short of the plant's, a drift,
    noise with dynamics of its own) the nonlinearity's parameters absorb the misfit and a small
    valve drowns in it. A high-order ARX approximates any stable plant with ARMAX or Box-Jenkins
    noise (the high-order ARX approximation), a trend absorbs a drift (``A(q)`` maps a
    polynomial trend to one of the same degree), and the delay window holds a longer delay. So
    ``na`` in :data:`NA_SELECT`, ``nb`` in :data:`NB_SELECT` and the delay in
    ``[delay0 - p, delay0 + DELAY_SPAN_SLOW p]`` are chosen by the smallest
    ``n log(RSS / n) + k log n`` over the candidate inputs ``inputs`` (``(C, N)`` fast-rate
    valve outputs: ``x`` and the graph fits of the classes, so the structure is not chosen to
    suit one class).
    """
    inputs = np.atleast_2d(np.asarray(inputs, float))
    y = np.asarray(y, float)
    extra = trend_columns(y.size, trend)
    best: tuple[float, tuple[int, int, int]] | None = None
    delays = range(max(delay0 - p, 0), delay0 + DELAY_SPAN_SLOW * p + 1)
    for na in NA_SELECT:
        for nb in NB_SELECT:
            for d in delays:
                st = EqStructure(na, nb, d, extra, idx)
                rss, _ = core.batch_arx(inputs, y, na, nb, d, idx, extra)
                n = st.n
                bic = n * np.log(max(float(rss.min()), 1e-300) / n) + st.k_linear * np.log(n)
                if best is None or bic < best[0]:
                    best = (float(bic), (na, nb, d))
    assert best is not None
    na, nb, d = best[1]
    return EqStructure(na, nb, d, extra, np.asarray(idx))


def eq_residual(
    u: np.ndarray, y: np.ndarray, st: EqStructure, theta: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, w)``: the equation error ``w(t) = y(t) - phi(t)' theta`` of a fit ``theta``
    (ordered as :func:`hbench.diagnose.core.batch_arx` returns it) on the rows of ``st.idx``
    where every regressor exists."""
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    rows = st.idx[st.idx >= max(st.na, st.delay + st.nb)]
    cols = [
        -lagged(y, range(1, st.na + 1)),
        lagged(u, range(st.delay + 1, st.delay + 1 + st.nb)),
        np.ones((y.size, 1)),
    ]
    if st.extra is not None:
        cols.append(st.extra)
    Phi = np.hstack(cols)[rows]
    return rows, y[rows] - Phi @ theta


def trim_outliers(rows: np.ndarray, w: np.ndarray, na: int) -> np.ndarray | None:
    """The rows without outliers, or None when there are none (or too many to be outliers).

    A spike in ``y(t)`` enters the equation error of rows ``t .. t + na`` (as the target, then
    as a regressor): a row whose error exceeds :data:`OUTLIER_Z` robust standard deviations is
    dropped with the ``na`` rows after it, if such rows are at most :data:`OUTLIER_SHARE` of all.
    """
    w = np.asarray(w, float)
    s = 1.4826 * float(np.median(np.abs(w - np.median(w))))
    bad = np.abs(w - np.median(w)) > OUTLIER_Z * max(s, 1e-300)
    if not bad.any() or bad.mean() > OUTLIER_SHARE:
        return None
    rows = np.asarray(rows, int)
    drop: set[int] = set()
    for t in rows[bad]:  # rows flagged inside a spike's span are the spike's, not new spikes
        if int(t) not in drop:
            drop.update(range(int(t), int(t) + na + 1))
    keep = np.array([r not in drop for r in rows])
    return rows[keep]


#: Order of the AR model of the equation error that prewhitens the class fits
#: (:func:`prewhitener`).
PREWHITEN_AR = 8


def _whole_window(kept: np.ndarray, order: int) -> np.ndarray:
    """Positions (of consecutive rows) whose ``order`` predecessors and themselves are all
    ``kept``."""
    ok = np.convolve(np.asarray(kept, float), np.ones(order + 1), mode="full")[: len(kept)]
    sel = ok >= order + 1 - 1e-9
    sel[:order] = False
    return sel


def prewhitener(w: np.ndarray, kept: np.ndarray, order: int = PREWHITEN_AR) -> np.ndarray:
    """``D = [1, d1, .., d_order]``: an AR model of the equation error ``w`` (on consecutive
    rows; ``kept`` marks the rows that are no outliers), by least squares over the rows whose
    ``order`` predecessors are all kept, stabilised; ``[1]`` with too few such rows.

    Equation error is the likelihood of white ``e`` in ``A y = B f(x) + e``; with noise of
    other dynamics (Box-Jenkins, a changing plant, a missing pole) ``e`` is coloured, and the
    half-BIC differences between classes count correlated rows as independent evidence.
    Filtering ``y``, the inputs and the shared regressors by ``D(q) ~ 1 / H(q)`` (generalised
    least squares; Ljung, System Identification, 1999, sec. 7.5) whitens ``e`` and makes the
    differences likelihood ratios again."""
    use = np.flatnonzero(_whole_window(kept, order))
    if use.size <= 4 * order:
        return np.array([1.0])
    w = np.asarray(w, float)
    R = np.stack([w[use - k] for k in range(1, order + 1)], axis=1)
    th = np.linalg.lstsq(R, w[use], rcond=None)[0]
    return core.stabilise(np.concatenate([[1.0], -th]))


def prewhitened_rows(rows: np.ndarray, kept: np.ndarray, order: int) -> np.ndarray:
    """The rows (of consecutive ``rows``) whose prefiltered equation holds only kept rows: a
    row and its ``order`` predecessors all kept."""
    return np.asarray(rows, int)[_whole_window(kept, order)]
