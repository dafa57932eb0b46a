/*
 * Compiled kernels of hbench (issue 7), loaded by hbench/kernels.py through ctypes.
 *
 * Each function does, for one run after another, the very floating-point operations of the
 * numpy path it replaces, in the same order (sums run sequentially from the first product, as
 * hbench.ordered does; no fused multiply-add: compiled with -ffp-contract=off), so the two
 * paths give the same numbers;
 * tests/test_kernels.py checks this. A run's numbers never depend on the other runs of the
 * batch. Arrays are C-contiguous float64, checked by the Python wrappers.
 */
#include <Python.h>
#include <math.h>
#include <stdint.h>

/* The SHA-256 of this file, passed by setup.py: hbench/kernels.py refuses a build made from
 * another version of it (an editable install keeps the .so it built until `pip install -e .`
 * runs again). */
#ifndef HB_SOURCE_SHA256
#define HB_SOURCE_SHA256 "unknown"
#endif
#define HB_EXPORT __attribute__((visibility("default")))
HB_EXPORT const char *hb_source_sha256(void) { return HB_SOURCE_SHA256; }

/* actuator codes (hbench.kernels.NONLINEARITY_CODES) */
enum { NL_LINEAR = 0, NL_DEADBAND = 1, NL_SATURATION = 2, NL_BACKLASH = 3, NL_STICTION = 4,
       NL_STICTION_HE = 5 };

/* np.minimum / np.maximum / np.clip on finite numbers, nan propagated as numpy does */
static inline double np_min(double a, double b) { return (a <= b || isnan(a)) ? a : b; }
static inline double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }
static inline double np_sign(double a) { return a > 0 ? 1.0 : (a < 0 ? -1.0 : (a == 0 ? 0.0 : a)); }

/*
 * The closed loop of hbench.simulate._run_loop for R runs of K slow periods.
 *
 * Plant (lifted to the slow period): s(n+1) = Fp s(n) + Gp u(n), the fast outputs of period n
 * y0(n p + i) = Ob[i] s(n) + Db[i] u(n) (Db[0] = 0). Controller: state space (Ac, Bc, Cc, Dc),
 * nc states, then a delay line of `delay` samples. Actuator: `code` with parameters `prm` and
 * the state `nl_state` (R x 5: x_prev, u_prev, x_ss, direction, stuck), updated in place.
 * Outputs y0 (R x K p), X and U (R x K).
 */
HB_EXPORT int hb_closed_loop(int64_t R, int64_t K, int64_t L, int64_t p, const double *Fp, const double *Gp,
                   const double *Ob, const double *Db, int64_t nc, const double *Ac,
                   const double *Bc, const double *Cc, double Dc, int64_t delay, int64_t code,
                   const double *prm, double *nl_state, const double *r, const double *v_slow,
                   double *y0, double *X, double *U)
{
    double s[64], sn[64], sc[64], scn[64];
    double *buf = NULL;
    if (L > 64 || nc > 64) return -1;
    if (delay > 0) {
        buf = (double *)malloc(sizeof(double) * (size_t)delay);
        if (!buf) return -2;
    }
    for (int64_t i = 0; i < R; i++) {
        const double *ri = r + i * K, *vi = v_slow + i * K;
        double *yi = y0 + i * K * p, *Xi = X + i * K, *Ui = U + i * K, *st = nl_state + i * 5;
        for (int64_t l = 0; l < L; l++) s[l] = 0.0;
        for (int64_t l = 0; l < nc; l++) sc[l] = 0.0;
        for (int64_t l = 0; l < delay; l++) buf[l] = 0.0;
        for (int64_t n = 0; n < K; n++) {
            double yp = 0.0, acc, x, u;
            if (L) {
                yp = s[0] * Ob[0];
                for (int64_t l = 1; l < L; l++) yp = yp + s[l] * Ob[l];
            }
            double e = ri[n] - (yp + vi[n]);
            x = Dc * e;
            if (nc) {
                acc = sc[0] * Cc[0];
                for (int64_t l = 1; l < nc; l++) acc = acc + sc[l] * Cc[l];
                x = x + acc;
                for (int64_t m = 0; m < nc; m++) {
                    acc = sc[0] * Ac[m * nc];
                    for (int64_t l = 1; l < nc; l++) acc = acc + sc[l] * Ac[m * nc + l];
                    scn[m] = acc + e * Bc[m];
                }
                for (int64_t m = 0; m < nc; m++) sc[m] = scn[m];
            }
            if (delay) {
                double out = buf[0];
                for (int64_t k = 0; k + 1 < delay; k++) buf[k] = buf[k + 1];
                buf[delay - 1] = x;
                x = out;
            }
            switch (code) {
            case NL_LINEAR:
                u = prm[0] * x;
                break;
            case NL_DEADBAND:
                u = prm[2] * (x - np_min(np_max(x, -prm[0]), prm[1]));
                break;
            case NL_SATURATION:
                u = np_min(np_max(x, prm[0]), prm[1]);
                break;
            case NL_BACKLASH: {
                double half = prm[0] / 2;
                u = np_max(x - half, np_min(x + half, st[1]));
                st[1] = u;
                break;
            }
            case NL_STICTION: {
                double S = prm[0], J = prm[1], d = st[3];
                int stuck = st[4] != 0.0;
                int sticks = !stuck && (np_sign(x - st[0]) != d);
                double x_ss = sticks ? st[0] : st[2];
                stuck = stuck || sticks;
                double ahead = d * (x - x_ss);
                int reverse = stuck && (-ahead > S);
                int go_on = stuck && (ahead > J);
                if (reverse) d = -d;
                stuck = stuck && !(reverse || go_on);
                u = stuck ? st[1] : x - d * ((S - J) / 2);
                st[0] = x;
                st[1] = u;
                st[2] = x_ss;
                st[3] = d;
                st[4] = stuck ? 1.0 : 0.0;
                break;
            }
            case NL_STICTION_HE: {
                double eu = x - st[1];
                u = fabs(eu) > prm[0] ? x - np_sign(eu) * prm[1] : st[1];
                st[1] = u;
                break;
            }
            default:
                free(buf);
                return -3;
            }
            Xi[n] = x;
            Ui[n] = u;
            yi[n * p] = yp;
            for (int64_t j = 1; j < p; j++) {
                acc = 0.0;
                if (L) {
                    acc = s[0] * Ob[j * L];
                    for (int64_t l = 1; l < L; l++) acc = acc + s[l] * Ob[j * L + l];
                }
                yi[n * p + j] = acc + u * Db[j];
            }
            for (int64_t m = 0; m < L; m++) {
                acc = s[0] * Fp[m * L];
                for (int64_t l = 1; l < L; l++) acc = acc + s[l] * Fp[m * L + l];
                sn[m] = acc + u * Gp[m];
            }
            for (int64_t m = 0; m < L; m++) s[m] = sn[m];
        }
    }
    free(buf);
    return 0;
}

/*
 * w(t) = A(q) y(t) per run (hbench.polyphase.filtered_output): a (R x (na + 1)), y and w
 * (R x N); w(t) = nan for t < na.
 */
HB_EXPORT void hb_filtered_output(int64_t R, int64_t N, int64_t na, const double *a, const double *y,
                        double *w)
{
    for (int64_t i = 0; i < R; i++) {
        const double *ai = a + i * (na + 1), *yi = y + i * N;
        double *wi = w + i * N;
        for (int64_t t = 0; t < na && t < N; t++) wi[t] = NAN;
        for (int64_t t = na; t < N; t++) {
            double acc = ai[0] * yi[t];
            for (int64_t k = 1; k <= na; k++) acc = acc + ai[k] * yi[t - k];
            wi[t] = acc;
        }
    }
}

/*
 * scipy.signal.lfilter(num[r], den[r], x[r]) from rest for every run r (batched_lfilter):
 * the transposed direct form II of scipy's `filt`, coefficients zero-padded to a common length
 * n and divided by den[r][0], with scipy's order of operations. x has a row stride of x_stride
 * elements (a view of a wider record); num and den are R x n, y is R x N. scipy takes another
 * route (a convolution) for a denominator of length 1: the wrapper never calls this for one.
 */
HB_EXPORT int hb_lfilter_rows(int64_t R, int64_t N, int64_t n, const double *num, const double *den,
                    const double *x, int64_t x_stride, double *y)
{
    double b[64], a[64], Z[64];
    if (n > 64 || n < 2) return -1;
    for (int64_t r = 0; r < R; r++) {
        const double *xr = x + r * x_stride;
        double *yr = y + r * N;
        double a0 = den[r * n];
        for (int64_t k = 0; k < n; k++) {
            b[k] = num[r * n + k] / a0;
            a[k] = den[r * n + k] / a0;
        }
        for (int64_t k = 0; k < n - 1; k++) Z[k] = 0.0;
        for (int64_t t = 0; t < N; t++) {
            double xn = xr[t];
            double yn = Z[0] + b[0] * xn;
            for (int64_t k = 0; k < n - 2; k++) Z[k] = Z[k + 1] + xn * b[k + 1] - yn * a[k + 1];
            Z[n - 2] = xn * b[n - 1] - yn * a[n - 1];
            yr[t] = yn;
        }
    }
    return 0;
}

/*
 * Mean squares over periods (polyphase.phase_variances): out[r, l] = (1/n) sum_j a[r, j p + l]^2,
 * j = 0 .. n-1, l = 0 .. width-1, a starting at the first period's first sample with a row stride
 * of a_stride elements. numpy reduces the C-ordered (runs, n, width) squares along the periods
 * term after term when width >= 2 (pairwise only along the innermost axis), so the sum here is
 * sequential; the wrapper never calls this for width 1.
 */
HB_EXPORT void hb_period_mean_squares(int64_t R, int64_t n, int64_t p, int64_t width,
                                      const double *a, int64_t a_stride, double *out)
{
    for (int64_t r = 0; r < R; r++) {
        const double *ar = a + r * a_stride;
        for (int64_t l = 0; l < width; l++) {
            double acc = ar[l] * ar[l];
            for (int64_t j = 1; j < n; j++) {
                double v = ar[j * p + l];
                acc = acc + v * v;
            }
            out[r * width + l] = acc / (double)n;
        }
    }
}

/* A module Python can import (so that setuptools builds and installs it like any extension);
 * its functions are reached through ctypes. */
static struct PyModuleDef kernels_module = {PyModuleDef_HEAD_INIT, "_kernels",
                                            "hbench's compiled kernels (see hbench.kernels).", -1,
                                            NULL};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&kernels_module); }
