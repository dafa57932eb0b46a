/*
 * Compiled kernels of hbench, loaded by hbench/numerics/kernels.py through ctypes.
 *
 * Each function does, for one run after another, the very floating-point operations of the
 * numpy path it replaces, in the same order (sums run sequentially from the first product, as
 * hbench.numerics.ordered does, or, for the fitness's row sums, as numpy's pairwise summation; no fused
 * multiply-add: compiled with -ffp-contract=off), so the two paths give the same numbers;
 * tests/test_kernels.py checks this. A run's numbers never depend on the other runs of the
 * batch. Arrays are C-contiguous float64, checked by the Python wrappers.
 */
#include <Python.h>
#include <math.h>
#include <stdint.h>

/* The SHA-256 of this file, passed by setup.py: hbench/numerics/kernels.py refuses a build made from
 * another version of it (an editable install keeps the .so it built until `pip install -e .`
 * runs again). */
#ifndef HB_SOURCE_SHA256
#define HB_SOURCE_SHA256 "unknown"
#endif
#define HB_EXPORT __attribute__((visibility("default")))
/* runs computed side by side where a recursion makes each step wait on the previous one */
#define HB_GROUP 8
/* runs stepped together in vectorised loops over lanes (the closed loop, lfilter) */
#define HB_LANES 4
HB_EXPORT const char *hb_source_sha256(void) { return HB_SOURCE_SHA256; }

/* actuator codes (hbench.sim.loop_kernel.NONLINEARITY_CODES) */
enum { NL_LINEAR = 0, NL_DEADBAND = 1, NL_SATURATION = 2, NL_BACKLASH = 3, NL_STICTION = 4,
       NL_STICTION_HE = 5 };

/* np.minimum / np.maximum / np.clip on finite numbers, nan propagated as numpy does */
static inline double np_min(double a, double b) { return (a <= b || isnan(a)) ? a : b; }
static inline double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }
static inline double np_sign(double a) { return a > 0 ? 1.0 : (a < 0 ? -1.0 : (a == 0 ? 0.0 : a)); }

/*
 * The closed loop of hbench.sim.simulate._run_loop for R runs of K slow periods.
 *
 * Plant (lifted to the slow period): s(n+1) = Fp s(n) + Gp u(n), the fast outputs of period n
 * y0(n p + i) = Ob[i] s(n) + Db[i] u(n) (Db[0] = 0). Controller: state space (Ac, Bc, Cc, Dc),
 * nc states, then a delay line of `delay` samples. Actuator: `code` with parameters `prm` and
 * the state `nl_state` (R x 5: x_prev, u_prev, x_ss, direction, stuck), updated in place.
 * Outputs y0 (R x K p), X and U (R x K).
 *
 * The runs are stepped HB_LANES at a time, period after period, each operation over the lanes in
 * a loop the compiler vectorises (states laid out lane-minor): a lane's operations, and so a
 * run's numbers, are those of a loop over that run alone. Lanes past the last run compute on
 * zeros and are not written out.
 */

/* the actuator for one run: input x, state st (5), returns u */
static inline double actuator(int64_t code, const double *prm, double x, double *st)
{
    double u;
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
    default: { /* NL_STICTION_HE (the code is checked before the loop) */
        double eu = x - st[1];
        u = fabs(eu) > prm[0] ? x - np_sign(eu) * prm[1] : st[1];
        st[1] = u;
        break;
    }
    }
    return u;
}

HB_EXPORT int hb_closed_loop(int64_t R, int64_t K, int64_t L, int64_t p, const double *Fp, const double *Gp,
                   const double *Ob, const double *Db, int64_t nc, const double *Ac,
                   const double *Bc, const double *Cc, double Dc, int64_t delay, int64_t code,
                   const double *prm, double *nl_state, const double *r, const double *v_slow,
                   double *y0, double *X, double *U)
{
    enum { G = HB_LANES };
    const int64_t nd = delay > 0 ? delay : 1;
    if (L > 64 || nc > 64) return -1;
    if (code < NL_LINEAR || code > NL_STICTION_HE) return -3;
    /* lane-minor: s[l * G + g] is state l of lane g */
    double *mem = (double *)malloc(sizeof(double) * (size_t)(G * (2 * L + 2 * nc + nd)));
    if (!mem) return -2;
    double *s = mem, *sn = s + G * L, *sc = sn + G * L, *scn = sc + G * nc, *buf = scn + G * nc;
    double dummy[G][5];
    for (int64_t r0 = 0; r0 < R; r0 += G) {
        const int64_t g_n = R - r0 < G ? R - r0 : G;
        double *st[G];
        for (int64_t k = 0; k < G * (2 * L + 2 * nc + nd); k++) mem[k] = 0.0;
        for (int g = 0; g < G; g++) {
            for (int k = 0; k < 5; k++) dummy[g][k] = 0.0;
            st[g] = g < g_n ? nl_state + (r0 + g) * 5 : dummy[g];
        }
        for (int64_t n = 0; n < K; n++) {
            double yp[G], e[G], x[G], u[G], acc[G], in_r[G], in_v[G];
            for (int g = 0; g < G; g++) {
                in_r[g] = g < g_n ? r[(r0 + g) * K + n] : 0.0;
                in_v[g] = g < g_n ? v_slow[(r0 + g) * K + n] : 0.0;
            }
            if (L) {
                for (int g = 0; g < G; g++) yp[g] = s[g] * Ob[0];
                for (int64_t l = 1; l < L; l++)
                    for (int g = 0; g < G; g++) yp[g] = yp[g] + s[l * G + g] * Ob[l];
            } else {
                for (int g = 0; g < G; g++) yp[g] = 0.0;
            }
            for (int g = 0; g < G; g++) {
                e[g] = in_r[g] - (yp[g] + in_v[g]);
                x[g] = Dc * e[g];
            }
            if (nc) {
                for (int g = 0; g < G; g++) acc[g] = sc[g] * Cc[0];
                for (int64_t l = 1; l < nc; l++)
                    for (int g = 0; g < G; g++) acc[g] = acc[g] + sc[l * G + g] * Cc[l];
                for (int g = 0; g < G; g++) x[g] = x[g] + acc[g];
                for (int64_t m = 0; m < nc; m++) {
                    for (int g = 0; g < G; g++) acc[g] = sc[g] * Ac[m * nc];
                    for (int64_t l = 1; l < nc; l++)
                        for (int g = 0; g < G; g++) acc[g] = acc[g] + sc[l * G + g] * Ac[m * nc + l];
                    for (int g = 0; g < G; g++) scn[m * G + g] = acc[g] + e[g] * Bc[m];
                }
                for (int64_t k = 0; k < nc * G; k++) sc[k] = scn[k];
            }
            if (delay) {
                for (int g = 0; g < G; g++) {
                    double out = buf[g];
                    for (int64_t k = 0; k + 1 < delay; k++) buf[k * G + g] = buf[(k + 1) * G + g];
                    buf[(delay - 1) * G + g] = x[g];
                    x[g] = out;
                }
            }
            for (int g = 0; g < G; g++) u[g] = actuator(code, prm, x[g], st[g]);
            for (int g = 0; g < g_n; g++) {
                X[(r0 + g) * K + n] = x[g];
                U[(r0 + g) * K + n] = u[g];
                y0[(r0 + g) * K * p + n * p] = yp[g];
            }
            for (int64_t j = 1; j < p; j++) {
                if (L) {
                    for (int g = 0; g < G; g++) acc[g] = s[g] * Ob[j * L];
                    for (int64_t l = 1; l < L; l++)
                        for (int g = 0; g < G; g++) acc[g] = acc[g] + s[l * G + g] * Ob[j * L + l];
                } else {
                    for (int g = 0; g < G; g++) acc[g] = 0.0;
                }
                for (int g = 0; g < g_n; g++)
                    y0[(r0 + g) * K * p + n * p + j] = acc[g] + u[g] * Db[j];
            }
            for (int64_t m = 0; m < L; m++) {
                for (int g = 0; g < G; g++) acc[g] = s[g] * Fp[m * L];
                for (int64_t l = 1; l < L; l++)
                    for (int g = 0; g < G; g++) acc[g] = acc[g] + s[l * G + g] * Fp[m * L + l];
                for (int g = 0; g < G; g++) sn[m * G + g] = acc[g] + u[g] * Gp[m];
            }
            for (int64_t k = 0; k < L * G; k++) s[k] = sn[k];
        }
    }
    free(mem);
    return 0;
}

/*
 * w(t) = A(q) y(t) per run (hbench.ident.polyphase.filtered_output): a (R x (na + 1)), y and w
 * (R x N); w(t) = nan for t < na. With dw (not NULL, R x N), also dw = polyphase.delta(w):
 * dw(0) = nan, dw(t) = w(t) - w(t-1), computed while the run's row is in cache.
 */
HB_EXPORT void hb_filtered_output(int64_t R, int64_t N, int64_t na, const double *a,
                                  const double *restrict y, double *restrict w,
                                  double *restrict dw)
{
    for (int64_t i = 0; i < R; i++) {
        const double *ai = a + i * (na + 1), *restrict yi = y + i * N;
        double *restrict wi = w + i * N;
        for (int64_t t = 0; t < na && t < N; t++) wi[t] = NAN;
        /* lag after lag over the row (each w(t) still sums a0 y(t) + a1 y(t-1) + .. in that
         * order): the inner loop runs over t and vectorises */
        const double a0 = ai[0];
        for (int64_t t = na; t < N; t++) wi[t] = a0 * yi[t];
        for (int64_t k = 1; k <= na; k++) {
            const double ak = ai[k];
            const double *restrict yk = yi - k;
            for (int64_t t = na; t < N; t++) wi[t] = wi[t] + ak * yk[t];
        }
        if (dw != NULL && N > 0) {
            double *restrict di = dw + i * N;
            di[0] = NAN;
            for (int64_t t = 1; t < N; t++) di[t] = wi[t] - wi[t - 1];
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
    /* HB_LANES runs side by side, each operation in a loop over the lanes (lane-minor: b[k * G
     * + g]) that the compiler vectorises: a run's operations are those of a filter on its own.
     * Lanes past the last run filter zeros and are not written out. */
    enum { G = HB_LANES };
    double b[64 * G], a[64 * G], Z[64 * G], xn[G], yn[G];
    if (n > 64 || n < 2) return -1;
    for (int64_t r0 = 0; r0 < R; r0 += G) {
        const int64_t g_n = R - r0 < G ? R - r0 : G;
        for (int64_t g = 0; g < G; g++) {
            int64_t r = r0 + g;
            double a0 = g < g_n ? den[r * n] : 1.0;
            for (int64_t k = 0; k < n; k++) {
                b[k * G + g] = g < g_n ? num[r * n + k] / a0 : 0.0;
                a[k * G + g] = g < g_n ? den[r * n + k] / a0 : 0.0;
                Z[k * G + g] = 0.0;
            }
        }
        for (int64_t t = 0; t < N; t++) {
            for (int g = 0; g < G; g++) xn[g] = g < g_n ? x[(r0 + g) * x_stride + t] : 0.0;
            for (int g = 0; g < G; g++) yn[g] = Z[g] + b[g] * xn[g];
            for (int64_t k = 0; k < n - 2; k++)
                for (int g = 0; g < G; g++)
                    Z[k * G + g] = Z[(k + 1) * G + g] + xn[g] * b[(k + 1) * G + g] -
                                   yn[g] * a[(k + 1) * G + g];
            for (int g = 0; g < G; g++)
                Z[(n - 2) * G + g] = xn[g] * b[(n - 1) * G + g] - yn[g] * a[(n - 1) * G + g];
            for (int g = 0; g < g_n; g++) y[(r0 + g) * N + t] = yn[g];
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
    /* period after period, the width sums side by side (each still adds its terms in order) */
    double acc[64];
    for (int64_t r = 0; r < R; r++) {
        const double *ar = a + r * a_stride;
        for (int64_t l0 = 0; l0 < width; l0 += 64) {
            int64_t w = width - l0 < 64 ? width - l0 : 64;
            const double *a0 = ar + l0;
            for (int64_t l = 0; l < w; l++) acc[l] = a0[l] * a0[l];
            for (int64_t j = 1; j < n; j++) {
                const double *aj = a0 + j * p;
                for (int64_t l = 0; l < w; l++) acc[l] = acc[l] + aj[l] * aj[l];
            }
            for (int64_t l = 0; l < w; l++) out[r * width + l0 + l] = acc[l] / (double)n;
        }
    }
}

/* acc[l] += sq[i + l] for l < p, period after period from i to m (each sum in order) */
static inline __attribute__((always_inline)) void add_periods(double *restrict acc,
                                                              const double *restrict sq,
                                                              int64_t i, int64_t m, int64_t p)
{
    double s[64];
    for (int64_t l = 0; l < p; l++) s[l] = acc[l];
    for (; i < m; i += p)
        for (int64_t l = 0; l < p; l++) s[l] = s[l] + sq[i + l];
    for (int64_t l = 0; l < p; l++) acc[l] = s[l];
}

/*
 * Table 2's variances of Delta w, w = A(q) y, without forming w (identifiers.select_structure:
 * polyphase.filtered_phase_variances): out[r, l] = (1/n) sum_j dw(t0 + j p + l)^2 for
 * l = 0 .. p-1, j = 0 .. n-1, where w(t) = a0 y(t) + a1 y(t-1) + .. + a_na y(t - na) summed in
 * that order (hb_filtered_output's) and dw(t) = w(t) - w(t-1) (polyphase.delta's); the sums are
 * hb_period_mean_squares'. t0 - 1 >= na (every w defined), t0 + n p <= N. y has row stride N.
 */
HB_EXPORT void hb_filtered_phase_variances(int64_t R, int64_t N, int64_t na, const double *a,
                                           const double *y, int64_t p, int64_t t0, int64_t n,
                                           double *out)
{
    /* blocks of whole periods: w over the block lag after lag (the loops over samples
     * vectorise), then its differences and their squares added to the phase sums in order */
    enum { SPAN = 1024 };
    double acc[64], wbuf[SPAN], sq[SPAN];
    const int64_t per_block = SPAN / p;
    for (int64_t r = 0; r < R; r++) {
        const double *ar = a + r * (na + 1), *yr = y + r * N;
        const double a0 = ar[0];
        double prev = a0 * yr[t0 - 1];
        for (int64_t k = 1; k <= na; k++) prev = prev + ar[k] * yr[t0 - 1 - k];
        for (int64_t j0 = 0; j0 < n; j0 += per_block) {
            const int64_t m = (n - j0 < per_block ? n - j0 : per_block) * p;
            const double *yj = yr + t0 + j0 * p;
            for (int64_t i = 0; i < m; i++) wbuf[i] = a0 * yj[i];
            for (int64_t k = 1; k <= na; k++) {
                const double ak = ar[k];
                for (int64_t i = 0; i < m; i++) wbuf[i] = wbuf[i] + ak * yj[i - k];
            }
            sq[0] = (wbuf[0] - prev) * (wbuf[0] - prev);
            for (int64_t i = 1; i < m; i++) sq[i] = (wbuf[i] - wbuf[i - 1]) * (wbuf[i] - wbuf[i - 1]);
            prev = wbuf[m - 1];
            int64_t i = 0;
            if (j0 == 0) {
                for (int64_t l = 0; l < p; l++) acc[l] = sq[l];
                i = p;
            }
            switch (p) { /* a known p keeps the p sums in registers, side by side */
            case 2: add_periods(acc, sq, i, m, 2); break;
            case 3: add_periods(acc, sq, i, m, 3); break;
            case 4: add_periods(acc, sq, i, m, 4); break;
            case 5: add_periods(acc, sq, i, m, 5); break;
            case 6: add_periods(acc, sq, i, m, 6); break;
            case 7: add_periods(acc, sq, i, m, 7); break;
            case 8: add_periods(acc, sq, i, m, 8); break;
            default: add_periods(acc, sq, i, m, p);
            }
        }
        for (int64_t l = 0; l < p; l++) out[r * p + l] = acc[l] / (double)n;
    }
}

/*
 * numpy's sum of n doubles along a contiguous row (np.add.reduce, DOUBLE_pairwise_sum): below 8
 * terms one after another; up to 128 eight interleaved partial sums, joined as
 * ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), then the rest one after another; beyond,
 * the two halves (the first a multiple of 8 long) summed so and added. The reduction adds the
 * result to its initial 0. kernels.sums_are_numpys checks this against numpy once per process.
 */
static double pairwise_sum(const double *a, int64_t n)
{
    if (n < 8) {
        double res = 0.0;
        for (int64_t i = 0; i < n; i++) res += a[i];
        return res;
    }
    if (n <= 128) {
        double r[8];
        int64_t i;
        for (int64_t j = 0; j < 8; j++) r[j] = a[j];
        for (i = 8; i < n - (n % 8); i += 8)
            for (int64_t j = 0; j < 8; j++) r[j] += a[i + j];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++) res += a[i];
        return res;
    }
    int64_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise_sum(a, n2) + pairwise_sum(a + n2, n - n2);
}

static double np_sum(const double *a, int64_t n) { return 0.0 + pairwise_sum(a, n); }

/*
 * metrics.fitnesses for the scalings "gain" and "ls" (R runs of K samples, C order): the same
 * elementwise operations, each row's sums numpy's (np_sum). gain (R), out_gain and out_ls (R);
 * work holds 3 K doubles. Returns nothing: a run without two common samples gets nan.
 */
HB_EXPORT void hb_fitness(int64_t R, int64_t K, const double *Ue, const double *U,
                          const double *gain, double *out_gain, double *out_ls, double *work)
{
    double *e = work, *u = work + K, *t = work + 2 * K;
    for (int64_t r = 0; r < R; r++) {
        const double *Uer = Ue + r * K, *Ur = U + r * K;
        int64_t n = 0;
        for (int64_t i = 0; i < K; i++) {
            int m = isfinite(Uer[i]) && isfinite(Ur[i]);
            n += m;
            e[i] = m ? Uer[i] : 0.0;
            u[i] = m ? Ur[i] : 0.0;
        }
        double mean_u = np_sum(u, K) / (double)n;
        for (int64_t i = 0; i < K; i++) {
            double d = (isfinite(Uer[i]) && isfinite(Ur[i])) ? u[i] - mean_u : 0.0;
            t[i] = d * d;
        }
        double den = sqrt(np_sum(t, K));
        double g = gain[r];
        for (int64_t i = 0; i < K; i++) {
            double d = (isfinite(Uer[i]) && isfinite(Ur[i])) ? e[i] / g - u[i] : 0.0;
            t[i] = d * d;
        }
        double num = sqrt(np_sum(t, K));
        out_gain[r] = n > 1 ? 100.0 * (1.0 - num / den) : NAN;
        for (int64_t i = 0; i < K; i++) t[i] = e[i] * u[i];
        double seu = np_sum(t, K);
        for (int64_t i = 0; i < K; i++) t[i] = e[i] * e[i];
        double c = seu / np_sum(t, K);
        for (int64_t i = 0; i < K; i++) {
            double d = (isfinite(Uer[i]) && isfinite(Ur[i])) ? c * e[i] - u[i] : 0.0;
            t[i] = d * d;
        }
        num = sqrt(np_sum(t, K));
        out_ls[r] = n > 1 ? 100.0 * (1.0 - num / den) : NAN;
    }
}

/* Thomas loop of polyphase._thomas for one symmetric system (lower = upper = off), n >= 1. */
static void thomas_sym(int64_t n, const double *diag, const double *off, const double *rhs,
                       double *c, double *d, double *x)
{
    c[0] = n > 1 ? off[0] / diag[0] : 0.0;
    d[0] = rhs[0] / diag[0];
    for (int64_t i = 1; i < n; i++) {
        double den = diag[i] - off[i - 1] * c[i - 1];
        if (i < n - 1) c[i] = off[i] / den;
        d[i] = (rhs[i] - off[i - 1] * d[i - 1]) / den;
    }
    x[n - 1] = d[n - 1];
    for (int64_t i = n - 2; i >= 0; i--) x[i] = d[i] - c[i] * x[i + 1];
}

/* out = [sum h1_i^2 v_i, sum h0_i^2 v_i, sum h0_i h1_i v_i] over the channels i < p, each from
 * its first term (polyphase.inner_signal_ls's per-period sums; v is 0/1) */
static inline void channel_sums(const double *h0, const double *h1, const uint8_t *v, int64_t p,
                                double *out)
{
    double s11 = (h1[0] * h1[0]) * (double)v[0];
    double s22 = (h0[0] * h0[0]) * (double)v[0];
    double s12 = (h0[0] * h1[0]) * (double)v[0];
    for (int64_t i = 1; i < p; i++) {
        s11 = s11 + (h1[i] * h1[i]) * (double)v[i];
        s22 = s22 + (h0[i] * h0[i]) * (double)v[i];
        s12 = s12 + (h0[i] * h1[i]) * (double)v[i];
    }
    out[0] = s11;
    out[1] = s22;
    out[2] = s12;
}

/*
 * Eq. (27) through its tridiagonal normal equations (polyphase.inner_signal_ls) for R runs: the
 * blocks of run r are W[r * row_stride + start + k p + i] (period k < M, channel i < p), read
 * only where valid (M x p, 0/1) and taken as 0 elsewhere (W the blocks R x M x p with row_stride
 * M p and start 0, or the rows of w in place); channel coefficients h0 and h1 (R x p); U
 * (R x (M + 1)) receives U~(n0 - 1 ..), nan for an unknown in no equation.
 * Channel sums run from the first term. The solve is LAPACK dptsv's arithmetic (reference dpttrf,
 * then dptts2); a run with a non-finite entry, or not positive definite, or of one unknown,
 * takes the Thomas loop, as the numpy path does. The solve's recurrences are chains of divisions:
 * HB_GROUP runs are solved side by side so that their chains overlap (each run's operations, and
 * so its numbers, are those of a solve on its own).
 */
HB_EXPORT int hb_inner_signal_ls(int64_t R, int64_t M, int64_t p, const double *W,
                                 int64_t row_stride, int64_t start, const uint8_t *valid,
                                 const double *h0, const double *h1, double *U)
{
    const int64_t n = M + 1, G = HB_GROUP;
    /* per group member: diag, off, rhs, x, d, e, free flags; then Thomas scratch c, dd */
    double *buf = (double *)malloc(sizeof(double) * (size_t)(7 * G * n + 2 * n));
    if (!buf) return -2;
    double *DIAG = buf, *OFF = DIAG + G * n, *RHS = OFF + G * n, *X = RHS + G * n;
    double *D = X + G * n, *E = D + G * n, *FREE = E + G * n, *c = FREE + G * n, *dd = c + n;
    /* periods whose p samples all exist (all but the record's ends): their sums of channel
     * coefficients are the same in every such period, computed once per run */
    uint8_t *full = (uint8_t *)malloc((size_t)(M + p));
    if (!full) {
        free(buf);
        return -2;
    }
    uint8_t *ones = full + M; /* the validity of a period with every sample */
    for (int64_t i = 0; i < p; i++) ones[i] = 1;
    for (int64_t k = 0; k < M; k++) {
        full[k] = 1;
        for (int64_t i = 0; i < p; i++) full[k] = full[k] && valid[k * p + i];
    }
    for (int64_t r0 = 0; r0 < R; r0 += G) {
        int64_t g_n = R - r0 < G ? R - r0 : G;
        int lapack[HB_GROUP];
        for (int64_t g = 0; g < g_n; g++) {
            int64_t r = r0 + g;
            const double *g0 = h0 + r * p, *g1 = h1 + r * p, *Wr = W + r * row_stride + start;
            double *diag = DIAG + g * n, *off = OFF + g * n, *rhs = RHS + g * n;
            double *freed = FREE + g * n;
            double prev22 = 0.0, prev2 = 0.0;
            double f[3]; /* the sums of a period with every sample */
            channel_sums(g0, g1, ones, p, f);
            for (int64_t k = 0; k < n; k++) {
                double dg = 0.0, rh = 0.0;
                if (k < M) {
                    const uint8_t *v = valid + k * p;
                    const double *w = Wr + k * p;
                    double sv[3];
                    if (!full[k]) channel_sums(g0, g1, v, p, sv);
                    const double *sk = full[k] ? f : sv;
                    const double s11 = sk[0], s22 = sk[1], s12 = sk[2];
                    double w0 = v[0] ? w[0] : 0.0;
                    double t1 = w0 * g1[0], t2 = w0 * g0[0];
                    for (int64_t i = 1; i < p; i++) {
                        double wi = v[i] ? w[i] : 0.0;
                        t1 = t1 + wi * g1[i];
                        t2 = t2 + wi * g0[i];
                    }
                    dg = dg + s11;
                    rh = rh + t1;
                    off[k] = s12;
                    if (k >= 1) { dg = dg + prev22; rh = rh + prev2; }
                    prev22 = s22;
                    prev2 = t2;
                } else if (k >= 1) {
                    dg = dg + prev22;
                    rh = rh + prev2;
                }
                diag[k] = dg;
                rhs[k] = rh;
            }
            int finite = 1;
            for (int64_t k = 0; k < n; k++) {
                freed[k] = diag[k] <= 0.0;
                if (freed[k] != 0.0) { /* free: pinned, decoupled, reported nan */
                    diag[k] = 1.0;
                    rhs[k] = 0.0;
                    if (k < M) off[k] = 0.0;
                    if (k >= 1) off[k - 1] = 0.0;
                }
            }
            for (int64_t k = 0; k < n && finite; k++)
                finite = isfinite(diag[k]) && isfinite(rhs[k]) && (k == M || isfinite(off[k]));
            lapack[g] = finite && n > 1;
            if (lapack[g]) {
                double *d = D + g * n, *e = E + g * n, *x = X + g * n;
                for (int64_t k = 0; k < n; k++) { d[k] = diag[k]; x[k] = rhs[k]; }
                for (int64_t k = 0; k < M; k++) e[k] = off[k];
            }
        }
        /* dpttrf, side by side; a member whose pivot is not positive leaves LAPACK */
        for (int64_t i = 0; i < n - 1; i++)
            for (int64_t g = 0; g < g_n; g++) {
                if (!lapack[g]) continue;
                double *d = D + g * n, *e = E + g * n;
                if (d[i] <= 0.0) { lapack[g] = 0; continue; }
                double ei = e[i];
                e[i] = ei / d[i];
                d[i + 1] = d[i + 1] - e[i] * ei;
            }
        for (int64_t g = 0; g < g_n; g++)
            if (lapack[g] && D[g * n + n - 1] <= 0.0) lapack[g] = 0;
        /* dptts2 */
        for (int64_t i = 1; i < n; i++)
            for (int64_t g = 0; g < g_n; g++) {
                if (!lapack[g]) continue;
                double *x = X + g * n;
                x[i] = x[i] - x[i - 1] * E[g * n + i - 1];
            }
        for (int64_t g = 0; g < g_n; g++)
            if (lapack[g]) X[g * n + n - 1] = X[g * n + n - 1] / D[g * n + n - 1];
        for (int64_t i = n - 2; i >= 0; i--)
            for (int64_t g = 0; g < g_n; g++) {
                if (!lapack[g]) continue;
                double *x = X + g * n;
                x[i] = x[i] / D[g * n + i] - x[i + 1] * E[g * n + i];
            }
        for (int64_t g = 0; g < g_n; g++) {
            double *x = X + g * n, *freed = FREE + g * n, *Ur = U + (r0 + g) * n;
            if (!lapack[g]) thomas_sym(n, DIAG + g * n, OFF + g * n, RHS + g * n, c, dd, x);
            for (int64_t k = 0; k < n; k++) Ur[k] = freed[k] != 0.0 ? NAN : x[k];
        }
    }
    free(full);
    free(buf);
    return 0;
}

/*
 * The actuator maps of hbench.diagnose.core for C candidate parameter sets over one input
 * sequence x (K samples): out (C x K), row c the candidate's output. Each step does the numpy
 * path's operations on candidate c (core.BacklashStep, core.StictionStep); the candidates are
 * stepped together, sample after sample, so the loop over them vectorises.
 *
 * Backlash: u = max(x(k) - half, min(x(k) + half, u)), from u0.
 */
HB_EXPORT void hb_backlash_rows(int64_t C, int64_t K, const double *x, const double *half,
                                const double *u0, double *u, double *out)
{
    for (int64_t c = 0; c < C; c++) u[c] = u0[c];
    for (int64_t k = 0; k < K; k++) {
        const double xk = x[k];
        for (int64_t c = 0; c < C; c++) {
            u[c] = np_max(xk - half[c], np_min(xk + half[c], u[c]));
            out[c * K + k] = u[c];
        }
    }
}

/*
 * Stiction (core.StictionStep): per candidate the band S, the jump J, the direction d, the
 * half-width h = (S - J) / 2, the stick input x_ss and the output u, all candidates stuck at
 * the start and the previous input x0; d, x_ss and u are updated in place, stuck in `stuck`.
 */
HB_EXPORT void hb_stiction_rows(int64_t C, int64_t K, const double *x, double x0,
                                const double *S, const double *J, const double *h, double *d,
                                double *x_ss, double *u, uint8_t *stuck, double *out)
{
    double x_prev = x0;
    for (int64_t c = 0; c < C; c++) stuck[c] = 1;
    for (int64_t k = 0; k < K; k++) {
        const double xk = x[k];
        const double sg = np_sign(xk - x_prev);
        for (int64_t c = 0; c < C; c++) {
            const int sticks = !stuck[c] && (sg != d[c]);
            if (sticks) x_ss[c] = x_prev;
            const int st = stuck[c] || sticks;
            const double ahead = d[c] * (xk - x_ss[c]);
            const int reverse = st && (-ahead > S[c]);
            const int go_on = st && (ahead > J[c]);
            if (reverse) d[c] = -d[c];
            stuck[c] = st && !(reverse || go_on);
            if (!stuck[c]) u[c] = xk - d[c] * h[c];
            out[c * K + k] = u[c];
        }
        x_prev = xk;
    }
}

/* A module Python can import (so that setuptools builds and installs it like any extension);
 * its functions are reached through ctypes. */
static struct PyModuleDef kernels_module = {PyModuleDef_HEAD_INIT, "_kernels",
                                            "hbench's compiled kernels (see hbench.numerics.kernels).", -1,
                                            NULL};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&kernels_module); }
