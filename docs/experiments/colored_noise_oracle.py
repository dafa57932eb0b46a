"""The oracle of ``colored-noise.md`` sections 8 and 9: the Ljung-Box noncentrality of the
true innovations ``A v`` beyond the nominal noise's moving-average order, for a one-pole and a
resonant coloured noise on one plant of each kind (the plants of calibration seeds 13002,
11001, 11036 and 11071), and the expected ``z`` of the tail route's sum
tried in section 9 (``colored-noise-tail-route.patch``) for the one-pole noise. Prints three
tables; no argument."""

from __future__ import annotations

import numpy as np
from scipy import signal

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose.generator import filter_norm

SNR = 2.2  # the coloured noise's SNR (the generator draws 1.5-3)
C1 = 0.25  # its zero (the generator draws 0 to 0.5)
LAGS = 20
TAIL_LAGS = 40  # the tail sum's last lag (section 9)


def autocovariance(b: np.ndarray, a: np.ndarray, n: int = 6000, lags: int = LAGS) -> np.ndarray:
    """Autocovariances at lags 0..lags of ``b / a`` driven by unit white noise."""
    imp = np.zeros(n)
    imp[0] = 1.0
    h = signal.lfilter(b, a, imp)
    return np.array([h[: n - k] @ h[k:] for k in range(lags + 1)])


def innovations_acf(
    case: bc.BenchCase, p: int, d: np.ndarray, c: np.ndarray, lags: int
) -> tuple[np.ndarray, int, int, int]:
    """Autocorrelations at lags 0..lags of ``A v`` (``v`` the nominal noise plus ``c / d e`` at
    SNR :data:`SNR`), the nominal noise's ``n_c``, the plant's ``na`` and the fit part's fast
    samples ``n``."""
    plant = bc.nominal_plant(case)
    dp = plant.discretize(case.T / p)
    A = np.asarray(dp.a)
    cn, dn = bc._noise_filter(plant, dp)
    scale = case.effect_params["s"] / SNR / filter_norm(c, d, 8000)
    g = autocovariance(np.convolve(cn, A), dn, lags=lags) * case.noise_sigma**2
    g = g + autocovariance(np.convolve(c, A), d, lags=lags) * scale**2
    return g / g[0], len(cn) - 1, len(A) - 1, int(case.K * p * 2 / 3)


def noncentrality(case: bc.BenchCase, p: int, d: np.ndarray, c: np.ndarray) -> float:
    """``n sum r_k^2`` over lags ``n_c + 1 .. LAGS`` of ``A v``."""
    r, nc, _, n = innovations_acf(case, p, d, c, LAGS)
    return float(n * np.sum(r[nc + 1 :] ** 2))  # lags n_c + 1 .. LAGS


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
    main()
