"""The oracle of ``colored-noise.md`` sections 8 and 9: the Ljung-Box noncentrality of the
true innovations ``A v`` beyond the nominal noise's moving-average order, for a one-pole and a
resonant coloured noise on one plant of each kind (the plants of calibration seeds 13002,
11001, 11036 and 11071), and the expected ``z`` of the tail route's sum
tried in section 9 (``colored-noise-tail-route.patch``) for the one-pole noise. Prints three
tables without an argument.

With ``--grid START PER_CELL PLANTS`` (as ``python -m hbench.diagnose.calibrate bench``'s
options), section 10's table instead: for every ``colored-noise`` record of that grid, with the
record's own noise (its ``d1``, ``c1`` and SNR), the noncentrality ``lambda`` and the power at
5 % of :mod:`hbench.diagnose.noise_oracle`'s test of the true innovations (the oracle: the true
``A``) under both its nulls, and per plant the number of those records the test would be
expected to name."""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import noise_oracle

SNR = 2.2  # the coloured noise's SNR (the generator draws 1.5-3)
C1 = 0.25  # its zero (the generator draws 0 to 0.5)
LAGS = 20
TAIL_LAGS = 40  # the tail sum's last lag (section 9)


def innovations_acf(
    case: bc.BenchCase, p: int, d: np.ndarray, c: np.ndarray, lags: int
) -> tuple[np.ndarray, int, int, int]:
    """Autocorrelations at lags 0..lags of ``A v`` (``v`` the nominal noise plus ``c / d e`` at
    SNR :data:`SNR`), the nominal noise's ``n_c``, the plant's ``na`` (the same number) and the
    fit part's fast samples ``n`` (:func:`hbench.diagnose.noise_oracle.innovations_acf` with
    ``case`` at ``p``)."""
    rho, n_c, n = noise_oracle.innovations_acf(replace(case, p=p), c, d, SNR, lags)
    return rho, n_c, n_c, n


def noncentrality(case: bc.BenchCase, p: int, d: np.ndarray, c: np.ndarray) -> float:
    """Sections 8 and 9: ``n sum r_k^2`` over lags ``n_c + 1 .. LAGS`` of ``A v`` (the plain
    Ljung-Box sum; the package's :func:`hbench.diagnose.noise_oracle.noncentrality` weighs the
    lags by Bartlett's covariance, section 10)."""
    r, nc, _, n = innovations_acf(case, p, d, c, LAGS)
    return float(n * np.sum(r[nc + 1 :] ** 2))


def grid_table(start: int, per_cell: int, plants: tuple[str, ...]) -> None:
    """Section 10's table: the oracle under both nulls of :mod:`hbench.diagnose.noise_oracle` on
    every ``colored-noise`` record of a benchmark grid, with the chance that it names 5 or more
    of them."""
    powers: dict[str, dict[str, list[float]]] = {null: {} for null in noise_oracle.NULLS}
    for case in bc.bench_grid(start, per_cell, plants):
        if case.effect != "colored-noise":
            continue
        ep = case.effect_params
        c, d, snr = noise_oracle.coloured_filter(case)
        poles = np.sort(np.roots(bc.nominal_plant(case).discretize(case.T / case.p).a).real)
        line = [
            f"{case.seed} {case.plant:12s} p={case.p} d1={ep['d1']:.3f} "
            f"plant poles {', '.join(f'{v:.3f}' for v in poles[::-1])}:"
        ]
        for null in noise_oracle.NULLS:
            acf = noise_oracle.innovations_acf(case, c, d, snr, null=null)
            lam, _ = noise_oracle.noncentrality(*acf)
            power = noise_oracle.noise_shape_power(case, null=null)
            assert power is not None
            powers[null].setdefault(case.plant, []).append(power)
            line.append(f"{null} lambda = {lam:.2f}, power {power:.2f};")
        print(" ".join(line))
    for null, by_plant in powers.items():
        every: list[float] = []
        for plant, p in by_plant.items():
            every += p
            print(
                f"null {null}, {plant}: {len(p)} records, power {min(p):.2f}-{max(p):.2f}, "
                f"expected to be named at 5 %: {sum(p):.2f}"
            )
        dist = np.array([1.0])
        for q in every:
            dist = np.convolve(dist, [1.0 - q, q])
        print(
            f"null {null}, all: expected {sum(every):.2f} of {len(every)}; "
            f"chance of 5 or more: {dist[5:].sum():.3f}"
        )


def tail_z(case: bc.BenchCase, p: int, d: np.ndarray, c: np.ndarray) -> float:
    """The tail route's expected ``z``: the sum of ``A v``'s autocorrelations over lags
    ``na + 1 .. TAIL_LAGS`` over its standard error under the null (Bartlett's formula with
    the autocorrelations at lags up to ``na``: ``N var = sum_{|m| < M} (M - |m|) g(m)``,
    ``g(m) = sum_i rho_i rho_(i+m)``, ``M = TAIL_LAGS - na``)."""
    r, _, na, n = innovations_acf(case, p, d, c, TAIL_LAGS)
    rho = np.concatenate([r[na:0:-1], r[: na + 1]])
    g = np.correlate(rho, rho, "full")
    w = np.clip(TAIL_LAGS - na - np.abs(np.arange(-2 * na, 2 * na + 1)), 0, None)
    return float(np.sum(r[na + 1 :]) / np.sqrt(float(w @ g) / n))


def main() -> None:
    plants = {"paper": 13002, "first-order": 11001, "third-order": 11036, "nmp": 11071}
    poles = (0.3, 0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 0.97, 0.99, 0.995)
    print("one pole d1:", " ".join(f"{v:g}" for v in poles))
    for name, seed in plants.items():
        case = bc.draw_bench_case(seed, "colored-noise", "linear", name)
        for p in (5, 8) if name == "paper" else (3, 8):
            row = [noncentrality(case, p, np.array([1.0, -v]), np.array([1.0, C1])) for v in poles]
            print(f"{name:12s} p={p}", " ".join(f"{q:.0f}" for q in row))
    print(f"one pole d1, expected z of the tail sum (lags na + 1 .. {TAIL_LAGS}):")
    for name, seed in plants.items():
        case = bc.draw_bench_case(seed, "colored-noise", "linear", name)
        for p in (5, 8) if name == "paper" else (3, 8):
            row = [tail_z(case, p, np.array([1.0, -v]), np.array([1.0, C1])) for v in poles]
            print(f"{name:12s} p={p}", " ".join(f"{z:+.1f}" for z in row))
    print("resonance (period s, damping):")
    for name, seed in plants.items():
        case = bc.draw_bench_case(seed, "colored-noise", "linear", name)
        for p in (5, 8) if name == "paper" else (3, 8):
            h = case.T / p
            out = []
            for period in (2.0, 5.0, 10.0, 20.0):
                for zeta in (0.05, 0.2):
                    wn = 2 * np.pi / period
                    rho = np.exp(-zeta * wn * h)
                    th = wn * h * np.sqrt(1 - zeta**2)
                    d = np.array([1.0, -2 * rho * np.cos(th), rho**2])
                    q = noncentrality(case, p, d, np.array([1.0]))
                    out.append(f"{period:g}s/{zeta:g}:{q:.0f}")
            print(f"{name:12s} p={p}", " ".join(out))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grid", nargs=3, metavar=("START", "PER_CELL", "PLANTS"))
    args = ap.parse_args()
    if args.grid:
        grid_table(int(args.grid[0]), int(args.grid[1]), tuple(args.grid[2].split(",")))
    else:
        main()
