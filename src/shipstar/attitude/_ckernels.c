/* Compiled path of shipstar.attitude.solve_attitude (shipstar.attitude._ckernels).
 *
 * Plain C99 on Python's buffer protocol (no NumPy headers); shipstar/attitude/_solve.py
 * is the only caller and makes every array native float64 / uint8, C ordered.
 *
 * solve(...) runs solve_attitude's QUEST path, the same computation in the same order:
 * the rows' checks, normalisation, the rejection loop (degenerate-geometry test, QUEST
 * of the active rows, residuals, the threshold of the given sigma, the absolute limit
 * or the median (Rayleigh) estimate, the worst row out while its ratio exceeds 1), then
 * with information matrices the anisotropic Gauss-Newton step, its covariance and
 * variance factor.  Whenever the Python path would return a failure, or would leave the
 * anisotropic step (singular information), it returns FALLBACK and the caller runs the
 * Python path, which words the reason: this path only ever produces solutions.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../_cquest.h"

#define SOLVED 0
#define FALLBACK 1

/* _solve.py's constants (checked against them by the tests) */
#define PARALLEL_TOL_RAD 1e-6
#define ROBUST_MIN_VECTORS 4

/* 2 atan2(|a - b|, |a + b|): _covariance.angle_between_rad */
static double angle_between(const double *a, const double *b)
{
    double d0 = a[0] - b[0], d1 = a[1] - b[1], d2 = a[2] - b[2];
    double s0 = a[0] + b[0], s1 = a[1] + b[1], s2 = a[2] + b[2];
    return 2.0 * atan2(sqrt(d0 * d0 + d1 * d1 + d2 * d2), sqrt(s0 * s0 + s1 * s1 + s2 * s2));
}

/* largest angle of the active rows from the first active row's line (_spread_rad) */
static double spread(const double *u, const uint8_t *active, long n)
{
    const double *first = NULL;
    double worst = 0.0;
    for (long i = 0; i < n; i++) {
        if (!active[i]) continue;
        if (!first) first = u + 3 * i;
        double ang = angle_between(u + 3 * i, first);
        double m = ang < M_PI - ang ? ang : M_PI - ang;
        if (m > worst) worst = m;
    }
    return worst;
}

/* angle between v_i and C w_i for every row (residuals_rad) */
static void residuals(const double *C, const double *w, const double *v, long n, double *r)
{
    for (long i = 0; i < n; i++) {
        const double *x = w + 3 * i;
        double p[3];
        for (int j = 0; j < 3; j++) p[j] = C[3 * j] * x[0] + C[3 * j + 1] * x[1] + C[3 * j + 2] * x[2];
        r[i] = angle_between(p, v + 3 * i);
    }
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* numpy.median of m values (sorted in place) */
static double median(double *x, long m)
{
    qsort(x, (size_t)m, sizeof(double), cmp_double);
    return (m % 2) ? x[m / 2] : 0.5 * (x[m / 2 - 1] + x[m / 2]);
}

/* robust_k(k_sigma, n): the threshold multiplier for a sigma from a median of n residuals */
static double robust_k(double k_sigma, long n)
{
    double nu = 0.48 * (2.0 * (double)n - 3.0);
    return sqrt(nu * expm1(k_sigma * k_sigma / nu));
}

/* t_factor(m) */
static double t_factor(long m)
{
    long nu = 2 * m - 3;
    return nu >= 3 ? (double)nu / ((double)nu - 2.0) : 3.0;
}

/* adjugate inverse of a symmetric 3x3 (sym3_inverse); 0 when (numerically) singular */
static int sym3_inverse(const double *F, double *P)
{
    double a = F[0], b = F[1], c = F[2], d = F[4], e = F[5], f = F[8];
    double adj[9];
    adj[0] = d * f - e * e;
    adj[1] = adj[3] = c * e - b * f;
    adj[2] = adj[6] = b * e - c * d;
    adj[4] = a * f - c * c;
    adj[5] = adj[7] = b * c - a * e;
    adj[8] = a * d - b * b;
    double det = a * adj[0] + b * adj[1] + c * adj[2];
    double tr = a + d + f;
    if (!isfinite(det) || det <= 1e-14 * tr * tr * tr) return 0;
    for (int k = 0; k < 9; k++) P[k] = adj[k] / det;
    return 1;
}

/* rows W_i symmetrised: 0.5 (W + W^T) (_check_info) */
static void sym_rows(const double *W, long n, double *Ws)
{
    for (long i = 0; i < n; i++)
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)
                Ws[9 * i + 3 * r + c] = 0.5 * (W[9 * i + 3 * r + c] + W[9 * i + 3 * c + r]);
}

/* The rejection loop; FALLBACK for every case the Python path words as a failure. */
static int reject_loop(const double *w, const double *v, const double *a, const double *sigma, long n,
                       double k_sigma, double max_res_rad, long min_vectors, int reject,
                       uint8_t *active, double *C, double *r, double *work)
{
    long m = 0;
    for (long i = 0; i < n; i++) {
        active[i] = a[i] > 0.0;
        m += active[i];
    }
    if (m < min_vectors) return FALLBACK;
    for (;;) {
        if (spread(w, active, n) < PARALLEL_TOL_RAD || spread(v, active, n) < PARALLEL_TOL_RAD) return FALLBACK;
        double total = 0.0, b[9] = {0};
        for (long i = 0; i < n; i++)
            if (active[i]) total += a[i];
        if (!(total > 0.0)) return FALLBACK;
        for (long i = 0; i < n; i++) {
            if (!active[i]) continue;
            double ai = a[i] / total;
            const double *vi = v + 3 * i, *wi = w + 3 * i;
            for (int rr = 0; rr < 3; rr++)
                for (int cc = 0; cc < 3; cc++) b[3 * rr + cc] += ai * vi[rr] * wi[cc];
        }
        quest_b(b, C);
        residuals(C, w, v, n, r);
        if (!reject) return SOLVED;
        /* thresholds: the absolute limit, k sigma, else the median (Rayleigh) estimate */
        double s_robust = 0.0, mean_a = 0.0;
        int robust = max_res_rad <= 0.0 && !sigma;
        if (robust) {
            if (m < ROBUST_MIN_VECTORS) return SOLVED;
            for (long i = 0; i < n; i++)
                if (active[i]) mean_a += a[i];
            mean_a /= (double)m;
            long j = 0;
            for (long i = 0; i < n; i++)
                if (active[i]) work[j++] = r[i] * sqrt(a[i] / mean_a);
            double s = median(work, m) / sqrt(2.0 * log(2.0)) * sqrt(2.0 * (double)m / (2.0 * (double)m - 3.0));
            double floor_rad = 1e-3 * (M_PI / (180.0 * 3600.0));
            s_robust = robust_k(k_sigma, m) * (s > floor_rad ? s : floor_rad);
        }
        long worst = -1;
        double worst_ratio = -INFINITY;
        for (long i = 0; i < n; i++) {
            if (!active[i]) continue;
            double thr = max_res_rad > 0.0 ? max_res_rad
                         : sigma ? k_sigma * sigma[i]
                         : s_robust / sqrt(a[i] / mean_a);
            double ratio = r[i] / thr;
            if (isnan(ratio)) return FALLBACK;          /* the Python path decides */
            if (ratio > worst_ratio) { worst_ratio = ratio; worst = i; }
        }
        if (worst_ratio <= 1.0) return SOLVED;
        if (m - 1 < min_vectors) return FALLBACK;
        active[worst] = 0;
        m -= 1;
    }
}

/* The anisotropic step of _solution_anisotropic; FALLBACK when F is singular. */
static int anisotropic(double *C, const double *w, const double *v, long n, const uint8_t *active,
                       const double *Ws, int sigma_given, double *P, double *r, double *scale_out)
{
    double F[9] = {0}, g[3] = {0};
    long m = 0;
    for (long i = 0; i < n; i++) {
        if (!active[i]) continue;
        m++;
        const double *x = w + 3 * i, *W = Ws + 9 * i;
        /* A = [x]x; A^T W A */
        double A[9] = {0, -x[2], x[1], x[2], 0, -x[0], -x[1], x[0], 0}, WA[9];
        for (int rr = 0; rr < 3; rr++)
            for (int cc = 0; cc < 3; cc++)
                WA[3 * rr + cc] = W[3 * rr] * A[cc] + W[3 * rr + 1] * A[3 + cc] + W[3 * rr + 2] * A[6 + cc];
        for (int rr = 0; rr < 3; rr++)
            for (int cc = 0; cc < 3; cc++)
                F[3 * rr + cc] += A[rr] * WA[cc] + A[3 + rr] * WA[3 + cc] + A[6 + rr] * WA[6 + cc];
        /* u = C^T v_i, e = u - w_i, g -= u x (W e) */
        const double *y = v + 3 * i;
        double u[3], e[3], We[3];
        for (int j = 0; j < 3; j++) u[j] = y[0] * C[j] + y[1] * C[3 + j] + y[2] * C[6 + j];
        for (int j = 0; j < 3; j++) e[j] = u[j] - x[j];
        for (int j = 0; j < 3; j++) We[j] = W[3 * j] * e[0] + W[3 * j + 1] * e[1] + W[3 * j + 2] * e[2];
        g[0] -= u[1] * We[2] - u[2] * We[1];
        g[1] -= u[2] * We[0] - u[0] * We[2];
        g[2] -= u[0] * We[1] - u[1] * We[0];
    }
    if (!sym3_inverse(F, P)) return FALLBACK;
    double d[3];
    for (int j = 0; j < 3; j++) d[j] = -(P[3 * j] * g[0] + P[3 * j + 1] * g[1] + P[3 * j + 2] * g[2]);
    /* C <- C exp([d]x) (_rotation_from_vector) */
    double t = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    double K[9] = {0, -d[2], d[1], d[2], 0, -d[0], -d[1], d[0], 0}, R[9], KK[9];
    for (int rr = 0; rr < 3; rr++)
        for (int cc = 0; cc < 3; cc++)
            KK[3 * rr + cc] = K[3 * rr] * K[cc] + K[3 * rr + 1] * K[3 + cc] + K[3 * rr + 2] * K[6 + cc];
    double s1 = t < 1e-12 ? 1.0 : sin(t) / t, s2 = t < 1e-12 ? 0.0 : (1.0 - cos(t)) / (t * t);
    for (int k = 0; k < 9; k++) R[k] = (k % 4 == 0 ? 1.0 : 0.0) + s1 * K[k] + s2 * KK[k];
    double Cn[9];
    for (int rr = 0; rr < 3; rr++)
        for (int cc = 0; cc < 3; cc++)
            Cn[3 * rr + cc] = C[3 * rr] * R[cc] + C[3 * rr + 1] * R[3 + cc] + C[3 * rr + 2] * R[6 + cc];
    memcpy(C, Cn, sizeof Cn);
    residuals(C, w, v, n, r);
    double scale = 1.0;
    if (!sigma_given) {
        double chi2 = 0.0;
        for (long i = 0; i < n; i++) {
            if (!active[i]) continue;
            const double *x = w + 3 * i, *y = v + 3 * i, *W = Ws + 9 * i;
            double e[3];
            for (int j = 0; j < 3; j++) e[j] = y[0] * C[j] + y[1] * C[3 + j] + y[2] * C[6 + j] - x[j];
            for (int j = 0; j < 3; j++)
                chi2 += e[j] * (W[3 * j] * e[0] + W[3 * j + 1] * e[1] + W[3 * j + 2] * e[2]);
        }
        long dof = 2 * m - 3 > 1 ? 2 * m - 3 : 1;
        scale = chi2 / (double)dof * t_factor(m);
        for (int k = 0; k < 9; k++) P[k] *= scale;
    }
    *scale_out = scale;
    return SOLVED;
}

/* _assumed_sigma: the given sigma, else the inliers' residual scale over sqrt(a_rel);
 * and the inliers' RMS residual (rad) */
static void assumed_sigma(const double *r, const uint8_t *active, const double *a, const double *sigma, long n,
                          double *out, double *rms_rad)
{
    long m = 0;
    double mean_a = 0.0, ss = 0.0;
    for (long i = 0; i < n; i++) {
        if (!active[i]) continue;
        m++;
        mean_a += a[i];
        ss += r[i] * r[i];
    }
    *rms_rad = sqrt(ss / (double)m);
    if (sigma) {
        memcpy(out, sigma, (size_t)n * sizeof(double));
        return;
    }
    mean_a /= (double)m;
    double chi = 0.0;
    for (long i = 0; i < n; i++)
        if (active[i]) chi += a[i] / mean_a * r[i] * r[i];
    long dof = 2 * m - 3 > 1 ? 2 * m - 3 : 1;
    double s = sqrt(chi / (double)dof * t_factor(m));
    for (long i = 0; i < n; i++) {
        double a_rel = a[i] / mean_a;
        out[i] = a_rel > 0.0 ? s / sqrt(a_rel) : INFINITY;
    }
}

/* solve(w, v, a, sigma, W, params[k_sigma, max_res_rad], ints[min_vectors, reject],
 *       out_w, out_v, out_C, out_r, out_active, out_P, out_Ws, out_sigma, work)
 *   -> (status, scale, rms_rad)
 *
 * w, v (n, 3) as given; a (n,) weights; sigma (n,) or empty; W (n, 3, 3) or empty;
 * max_res_rad <= 0: none.  out_w / out_v: the unit rows; out_Ws: W symmetrised (n, 3, 3);
 * out_sigma: _assumed_sigma (with W); work: n doubles.  status SOLVED or FALLBACK;
 * scale: the anisotropic variance factor (1 with sigma given), rms_rad: the inliers' RMS
 * residual (both NaN without W: the Python _solution finishes that case). */
static PyObject *py_solve(PyObject *self, PyObject *args)
{
    Py_buffer bw, bv, ba, bs, bW, bp, bi, ow, ov, oC, or_, oa, oP, oW, osg, owk;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*w*w*w*w*w*w*w*w*w*", &bw, &bv, &ba, &bs, &bW, &bp, &bi, &ow, &ov,
                          &oC, &or_, &oa, &oP, &oW, &osg, &owk))
        return NULL;
    long n = (long)(bw.len / (3 * sizeof(double)));
    const double *w_in = bw.buf, *v_in = bv.buf, *a = ba.buf, *prm = bp.buf, *Win = bW.buf;
    const double *sigma = bs.len ? (const double *)bs.buf : NULL;
    const int64_t *ints = bi.buf;
    double *w = ow.buf, *v = ov.buf, *C = oC.buf, *r = or_.buf, *P = oP.buf, *Ws = oW.buf, *work = owk.buf;
    uint8_t *active = oa.buf;
    int status = SOLVED;
    double scale = NAN, rms_rad = NAN;
    Py_BEGIN_ALLOW_THREADS
    for (long i = 0; i < n && status == SOLVED; i++) {        /* _bad_rows and the normalisation */
        const double *x = w_in + 3 * i, *y = v_in + 3 * i;
        double nx = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        double ny = sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2]);
        if (!isfinite(nx) || !isfinite(ny) || nx == 0.0 || ny == 0.0) { status = FALLBACK; break; }
        for (int j = 0; j < 3; j++) { w[3 * i + j] = x[j] / nx; v[3 * i + j] = y[j] / ny; }
    }
    if (status == SOLVED && bW.len) {
        for (long k = 0; k < 9 * n; k++)
            if (!isfinite(Win[k])) { status = FALLBACK; break; }
    }
    if (status == SOLVED)
        status = reject_loop(w, v, a, sigma, n, prm[0], prm[1], (long)ints[0], (int)ints[1], active, C, r, work);
    if (status == SOLVED && bW.len) {
        sym_rows(Win, n, Ws);
        status = anisotropic(C, w, v, n, active, Ws, sigma != NULL, P, r, &scale);
        if (status == SOLVED) assumed_sigma(r, active, a, sigma, n, osg.buf, &rms_rad);
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&bw); PyBuffer_Release(&bv); PyBuffer_Release(&ba); PyBuffer_Release(&bs);
    PyBuffer_Release(&bW); PyBuffer_Release(&bp); PyBuffer_Release(&bi); PyBuffer_Release(&ow);
    PyBuffer_Release(&ov); PyBuffer_Release(&oC); PyBuffer_Release(&or_); PyBuffer_Release(&oa);
    PyBuffer_Release(&oP); PyBuffer_Release(&oW); PyBuffer_Release(&osg); PyBuffer_Release(&owk);
    return Py_BuildValue("idd", status, scale, rms_rad);
}

static PyMethodDef methods[] = {
    {"solve", py_solve, METH_VARARGS, "solve_attitude's QUEST path (see _solve.py)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_ckernels",
                                    "Compiled path of shipstar.attitude.solve_attitude (see _solve.py).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__ckernels(void)
{
    return PyModule_Create(&moddef);
}
