/* Compiled path of shipstar.attitude.solve_attitude (shipstar.attitude._ckernels), and
 * the attitude fit's residual statistics for the pipeline's noise model (quest,
 * residual_moments, noise_fit: pipeline/_conditions.py), and the normal equations of the
 * pipeline's motion fit (motion_fit: pipeline/_motion.py).
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
#include "../_csource.h"
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

/* B = sum a_i v_i w_i^T / sum a_i over the rows with active[i] (all rows: active NULL), the
 * rows normalised first when normalise is set; 0 when the weights sum to <= 0 (quest's
 * wahba.prepare and profile_matrix) */
static int weighted_profile(const double *w, const double *v, const double *a, const uint8_t *active, long n,
                            int normalise, double *b)
{
    double total = 0.0;
    for (long i = 0; i < n; i++)
        if (!active || active[i]) total += a[i];
    if (!(total > 0.0)) return 0;
    for (int k = 0; k < 9; k++) b[k] = 0.0;
    for (long i = 0; i < n; i++) {
        if (active && !active[i]) continue;
        const double *x = w + 3 * i, *y = v + 3 * i;
        double nx = 1.0, ny = 1.0;
        if (normalise) {
            nx = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
            ny = sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2]);
        }
        double ai = a[i] / total;
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) b[3 * r + c] += ai * (y[r] / ny) * (x[c] / nx);
    }
    return 1;
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
        double b[9];
        if (!weighted_profile(w, v, a, active, n, 0, b)) return FALLBACK;
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
/* F += [x]x^T W [x]x: the attitude information about the body axes of a direction x (3,)
 * with information matrix W (3, 3) (_solve.py's _fisher_body, one term) */
static void add_fisher(const double *x, const double *W, double *F)
{
    double A[9] = {0, -x[2], x[1], x[2], 0, -x[0], -x[1], x[0], 0}, WA[9];
    for (int rr = 0; rr < 3; rr++)
        for (int cc = 0; cc < 3; cc++)
            WA[3 * rr + cc] = W[3 * rr] * A[cc] + W[3 * rr + 1] * A[3 + cc] + W[3 * rr + 2] * A[6 + cc];
    for (int rr = 0; rr < 3; rr++)
        for (int cc = 0; cc < 3; cc++)
            F[3 * rr + cc] += A[rr] * WA[cc] + A[3 + rr] * WA[3 + cc] + A[6 + rr] * WA[6 + cc];
}

static int anisotropic(double *C, const double *w, const double *v, long n, const uint8_t *active,
                       const double *Ws, int sigma_given, double *P, double *r, double *scale_out)
{
    double F[9] = {0}, g[3] = {0};
    long m = 0;
    for (long i = 0; i < n; i++) {
        if (!active[i]) continue;
        m++;
        const double *x = w + 3 * i, *W = Ws + 9 * i;
        add_fisher(x, W, F);
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

/* quest(w, v, a, out_C): quest() of n rows (normalised here) with weights a (sum > 0):
 * C_ref_from_body, the same steps as shipstar.attitude._quest.quest for one problem */
static PyObject *py_quest(PyObject *self, PyObject *args)
{
    Py_buffer bw, bv, ba, oC;
    if (!PyArg_ParseTuple(args, "y*y*y*w*", &bw, &bv, &ba, &oC)) return NULL;
    long n = (long)(bw.len / (3 * sizeof(double)));
    double b[9];
    if (weighted_profile(bw.buf, bv.buf, ba.buf, NULL, n, 1, b))
        quest_b(b, oC.buf);
    else
        for (int k = 0; k < 9; k++) ((double *)oC.buf)[k] = NAN;     /* no weight: no attitude */
    PyBuffer_Release(&bw); PyBuffer_Release(&bv); PyBuffer_Release(&ba); PyBuffer_Release(&oC);
    Py_RETURN_NONE;
}

/* Gauss-Jordan inverse with partial pivoting of an n x n (n <= 10) into inv; 0 for an
 * exactly zero pivot (numpy.linalg.inv's LinAlgError) */
static int gj_inverse(const double *A, int n, double *inv)
{
    double M[10][20];
    for (int r = 0; r < n; r++)
        for (int c = 0; c < n; c++) { M[r][c] = A[n * r + c]; M[r][n + c] = r == c ? 1.0 : 0.0; }
    for (int col = 0; col < n; col++) {
        int piv = col;
        for (int r = col + 1; r < n; r++)
            if (fabs(M[r][col]) > fabs(M[piv][col])) piv = r;
        if (M[piv][col] == 0.0) return 0;
        if (piv != col)
            for (int c = 0; c < 2 * n; c++) { double t = M[col][c]; M[col][c] = M[piv][c]; M[piv][c] = t; }
        double d = M[col][col];
        for (int c = 0; c < 2 * n; c++) M[col][c] /= d;
        for (int r = 0; r < n; r++) {
            if (r == col || M[r][col] == 0.0) continue;
            double f = M[r][col];
            for (int c = 0; c < 2 * n; c++) M[r][c] -= f * M[col][c];
        }
    }
    for (int r = 0; r < n; r++)
        for (int c = 0; c < n; c++) inv[n * r + c] = M[r][n + c];
    return 1;
}

/* residual_moments(u, wts, W, G, out_X, work) -> ok: shipstar.pipeline._conditions.
 * residual_moments (its docstring has the algebra) for n stars: u (n, 3), wts (n,),
 * W (n, 2, 3) whitening, G (n, 2, 2) floor Gram; out_X (n, 3, 4); work 16 n doubles.
 * 0 (nothing written) when F or a W W^T is singular: the caller's Python path decides. */
static PyObject *py_residual_moments(PyObject *self, PyObject *args)
{
    Py_buffer bu, bw, bW, bG, oX, owk;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*w*", &bu, &bw, &bW, &bG, &oX, &owk)) return NULL;
    long n = (long)(bw.len / sizeof(double));
    const double *u = bu.buf, *wts = bw.buf, *Wa = bW.buf, *Ga = bG.buf;
    double *X = oX.buf, *R = owk.buf, *Q = R + 6 * n, *RQ = Q + 6 * n;       /* (n,2,3) (n,3,2) (n,2,2) */
    int ok = 1;
    Py_BEGIN_ALLOW_THREADS
    double F[9] = {0}, Fi[9];
    for (long i = 0; i < n; i++) {                              /* F = sum w_i (I - u u^T) */
        const double *x = u + 3 * i;
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) F[3 * r + c] += wts[i] * ((r == c ? 1.0 : 0.0) - x[r] * x[c]);
    }
    ok = gj_inverse(F, 3, Fi);
    for (long i = 0; i < n && ok; i++) {
        const double *x = u + 3 * i, *W = Wa + 6 * i;
        double ux[9] = {0, -x[2], x[1], x[2], 0, -x[0], -x[1], x[0], 0};
        /* Dm = W^T (W W^T)^-1 (3, 2) */
        double a = W[0] * W[0] + W[1] * W[1] + W[2] * W[2], b = W[0] * W[3] + W[1] * W[4] + W[2] * W[5];
        double d = W[3] * W[3] + W[4] * W[4] + W[5] * W[5], det = a * d - b * b;
        if (!isfinite(det) || det == 0.0) { ok = 0; break; }
        double i00 = d / det, i01 = -b / det, i11 = a / det, Dm[6];
        for (int r = 0; r < 3; r++) {
            Dm[2 * r] = W[r] * i00 + W[3 + r] * i01;
            Dm[2 * r + 1] = W[r] * i01 + W[3 + r] * i11;
        }
        /* R = W [u]x F^-1 (2, 3) */
        double Wux[6], *Ri = R + 6 * i, *Qi = Q + 6 * i, *RQi = RQ + 4 * i;
        for (int r = 0; r < 2; r++)
            for (int c = 0; c < 3; c++)
                Wux[3 * r + c] = W[3 * r] * ux[c] + W[3 * r + 1] * ux[3 + c] + W[3 * r + 2] * ux[6 + c];
        for (int r = 0; r < 2; r++)
            for (int c = 0; c < 3; c++)
                Ri[3 * r + c] = Wux[3 * r] * Fi[c] + Wux[3 * r + 1] * Fi[3 + c] + Wux[3 * r + 2] * Fi[6 + c];
        /* Q = w [u]x^T Dm (3, 2); RQ = R Q (2, 2) */
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 2; c++)
                Qi[2 * r + c] = wts[i] * (ux[r] * Dm[c] + ux[3 + r] * Dm[2 + c] + ux[6 + r] * Dm[4 + c]);
        for (int r = 0; r < 2; r++)
            for (int c = 0; c < 2; c++)
                RQi[2 * r + c] = Ri[3 * r] * Qi[c] + Ri[3 * r + 1] * Qi[2 + c] + Ri[3 * r + 2] * Qi[4 + c];
    }
    for (int k = 0; k < 4 && ok; k++) {            /* V: the basis E_xx, E_xy, E_yy, then G_j */
        static const double BASIS[3][4] = {{1, 0, 0, 0}, {0, 1, 1, 0}, {0, 0, 0, 1}};
        double M[9] = {0};                          /* sum_j Q_j V_j Q_j^T */
        for (long j = 0; j < n; j++) {
            const double *V = k < 3 ? BASIS[k] : Ga + 4 * j, *Qj = Q + 6 * j;
            for (int r = 0; r < 3; r++) {
                double qv0 = Qj[2 * r] * V[0] + Qj[2 * r + 1] * V[2], qv1 = Qj[2 * r] * V[1] + Qj[2 * r + 1] * V[3];
                for (int c = 0; c < 3; c++) M[3 * r + c] += qv0 * Qj[2 * c] + qv1 * Qj[2 * c + 1];
            }
        }
        for (long i = 0; i < n; i++) {
            const double *V = k < 3 ? BASIS[k] : Ga + 4 * i, *Ri = R + 6 * i, *RQi = RQ + 4 * i;
            double RQV[4], RM[6], E[4];
            for (int r = 0; r < 2; r++)
                for (int c = 0; c < 2; c++) RQV[2 * r + c] = RQi[2 * r] * V[c] + RQi[2 * r + 1] * V[2 + c];
            for (int r = 0; r < 2; r++)
                for (int c = 0; c < 3; c++)
                    RM[3 * r + c] = Ri[3 * r] * M[c] + Ri[3 * r + 1] * M[3 + c] + Ri[3 * r + 2] * M[6 + c];
            for (int r = 0; r < 2; r++)
                for (int c = 0; c < 2; c++)
                    E[2 * r + c] = V[2 * r + c] - RQV[2 * r + c] - RQV[2 * c + r]
                                   + RM[3 * r] * Ri[3 * c] + RM[3 * r + 1] * Ri[3 * c + 1] + RM[3 * r + 2] * Ri[3 * c + 2];
            X[12 * i + k] = E[0];
            X[12 * i + 4 + k] = E[1];
            X[12 * i + 8 + k] = E[3];
        }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&bu); PyBuffer_Release(&bw); PyBuffer_Release(&bW); PyBuffer_Release(&bG);
    PyBuffer_Release(&oX); PyBuffer_Release(&owk);
    return PyBool_FromLong(ok);
}

/* ---------------------------------------------------------------------------------
 * The noise model's fit (shipstar.pipeline._conditions.NoiseModel._fit, the same steps)
 * ------------------------------------------------------------------------------- */

/* _fit_shape_floor: theta (4) and sigma_f2 from A (4x4), b (4); 0 when singular/not finite */
static int fit_shape_floor(const double *A, const double *b, double min_shape, double *theta, double *sigma_f2)
{
    double Ai[16];
    if (!gj_inverse(A, 4, Ai)) return 0;
    for (int r = 0; r < 4; r++) theta[r] = Ai[4 * r] * b[0] + Ai[4 * r + 1] * b[1] + Ai[4 * r + 2] * b[2] + Ai[4 * r + 3] * b[3];
    double v = 2.0 * Ai[15];
    *sigma_f2 = sqrt(v > 0.0 ? v : 0.0);
    if (!(theta[3] > 0.0)) {                       /* the Cramer-Rao covariances explain it all */
        double A3[9] = {A[0], A[1], A[2], A[4], A[5], A[6], A[8], A[9], A[10]}, A3i[9];
        if (!gj_inverse(A3, 3, A3i)) return 0;
        for (int r = 0; r < 3; r++) theta[r] = A3i[3 * r] * b[0] + A3i[3 * r + 1] * b[1] + A3i[3 * r + 2] * b[2];
        theta[3] = 0.0;
    }
    for (int r = 0; r < 4; r++)
        if (!isfinite(theta[r])) return 0;
    double half_tr = 0.5 * (theta[0] + theta[2]), half_diff = 0.5 * (theta[0] - theta[2]);
    double rad = sqrt(half_diff * half_diff + theta[1] * theta[1]);
    if (half_tr - rad < min_shape) {
        /* S's eigenvalues raised to min_shape: S = sum max(lam, min) v v^T */
        double lo = half_tr - rad, hi = half_tr + rad;
        double phi = 0.5 * atan2(2.0 * theta[1], theta[0] - theta[2]);   /* the larger one's axis */
        double c = cos(phi), s = sin(phi);
        double l_hi = hi > min_shape ? hi : min_shape, l_lo = lo > min_shape ? lo : min_shape;
        theta[0] = l_hi * c * c + l_lo * s * s;
        theta[1] = (l_hi - l_lo) * c * s;
        theta[2] = l_hi * s * s + l_lo * c * c;
    }
    return 1;
}

/* clip_and_weights + normal equations over one frame's stars (rows of z (m, 2), zz (m, 3),
 * X (m, 3, 4)) under theta, added into A (4x4), b (4); returns the stars within clip */
static long clip_normal(const double *z, const double *zz, const double *X, long m, const double *theta,
                        double clip, double *A, double *b)
{
    static const double ROW_WEIGHTS[3] = {1.0, 2.0, 1.0};
    long used = 0;
    /* the sums in locals (A and b could alias the inputs for the compiler, which then stores
     * and reloads every term: 5 x slower); the same additions in the same order */
    double Al[16], bl[4];
    memcpy(Al, A, sizeof Al);
    memcpy(bl, b, sizeof bl);
    for (long i = 0; i < m; i++) {
        const double *Xi = X + 12 * i;
        double V[3];
        for (int r = 0; r < 3; r++)
            V[r] = Xi[4 * r] * theta[0] + Xi[4 * r + 1] * theta[1] + Xi[4 * r + 2] * theta[2] + Xi[4 * r + 3] * theta[3];
        double det = V[0] * V[2] - V[1] * V[1];
        if (!(det > 0.0)) continue;
        double z0 = z[2 * i], z1 = z[2 * i + 1];
        double chi2 = (z0 * z0 * V[2] - 2.0 * z0 * z1 * V[1] + z1 * z1 * V[0]) / det;
        if (!(chi2 < clip * clip)) continue;
        used++;
        double tr = V[0] + V[2], w = 4.0 / (tr * tr);
        for (int r = 0; r < 3; r++) {
            const double *x = Xi + 4 * r;
            double wr = w * ROW_WEIGHTS[r];
            for (int p = 0; p < 4; p++) {
                bl[p] += wr * x[p] * zz[3 * i + r];
                for (int q = 0; q < 4; q++) Al[4 * p + q] += wr * x[p] * x[q];
            }
        }
    }
    memcpy(A, Al, sizeof Al);
    memcpy(b, bl, sizeof bl);
    return used;
}

/* noise_fit(frames, min_stars, clip, min_shape, out_theta) -> (ok, sigma_f2): NoiseModel._fit
 * of frames = sequence of (t_s, A (4, 4), b (4,), m, z (m, 2), zz (m, 3), X (m, 3, 4)), the
 * arrays float64 C-ordered: the frames' normal equations summed and solved, then every star
 * re-weighted under that model (those beyond clip left out) and solved again. */
static PyObject *py_noise_fit(PyObject *self, PyObject *args)
{
    PyObject *frames, *seq = NULL;
    long min_stars;
    double clip, min_shape;
    Py_buffer otheta;
    if (!PyArg_ParseTuple(args, "Olddw*", &frames, &min_stars, &clip, &min_shape, &otheta)) return NULL;
    double *theta = otheta.buf, A[16] = {0}, b[4] = {0}, sigma_f2 = NAN;
    int ok = 0;
    Py_buffer *bufs = NULL;
    long k = 0, n_total = 0, nb = 0;
    seq = PySequence_Fast(frames, "noise_fit: frames must be a sequence");
    if (!seq) goto done;
    k = (long)PySequence_Fast_GET_SIZE(seq);
    bufs = PyMem_Calloc((size_t)(5 * k + 1), sizeof(Py_buffer));
    if (!bufs) { PyErr_NoMemory(); goto done; }
    for (long f = 0; f < k; f++) {                      /* A, b, z, zz, X of each frame */
        PyObject *fr = PySequence_Fast_GET_ITEM(seq, f);
        static const int FIELDS[5] = {1, 2, 4, 5, 6};
        for (int j = 0; j < 5; j++) {
            PyObject *item = PySequence_GetItem(fr, FIELDS[j]);
            if (!item) goto done;
            int rc = PyObject_GetBuffer(item, &bufs[nb], PyBUF_C_CONTIGUOUS);
            Py_DECREF(item);
            if (rc < 0) goto done;
            nb++;
        }
        n_total += (long)(bufs[nb - 3].len / (2 * sizeof(double)));
    }
    if (n_total < min_stars) goto done;
    for (long f = 0; f < k; f++) {
        const double *Af = bufs[5 * f].buf, *bf = bufs[5 * f + 1].buf;
        for (int j = 0; j < 16; j++) A[j] += Af[j];
        for (int j = 0; j < 4; j++) b[j] += bf[j];
    }
    double first[4], s0;
    if (!fit_shape_floor(A, b, min_shape, first, &s0)) goto done;
    memset(A, 0, sizeof A);
    memset(b, 0, sizeof b);
    long used = 0;
    for (long f = 0; f < k; f++) {
        long m = (long)(bufs[5 * f + 2].len / (2 * sizeof(double)));
        used += clip_normal(bufs[5 * f + 2].buf, bufs[5 * f + 3].buf, bufs[5 * f + 4].buf, m, first, clip, A, b);
    }
    if (used < min_stars) goto done;
    ok = fit_shape_floor(A, b, min_shape, theta, &sigma_f2);
done:
    for (long j = 0; j < nb; j++) PyBuffer_Release(&bufs[j]);
    PyMem_Free(bufs);
    Py_XDECREF(seq);
    PyBuffer_Release(&otheta);
    if (PyErr_Occurred()) return NULL;
    return Py_BuildValue("Nd", PyBool_FromLong(ok), sigma_f2);
}

/* rotation vector of a rotation matrix M (angle below pi): pipeline._motion.rotvecs */
static void rotvec3(const double *M, double *r)
{
    double s0 = M[7] - M[5], s1 = M[2] - M[6], s2 = M[3] - M[1];
    double n = sqrt(s0 * s0 + s1 * s1 + s2 * s2);
    double angle = atan2(0.5 * n, 0.5 * (M[0] + M[4] + M[8] - 1.0));
    double scale = n > 0.0 ? angle / n : 0.5;
    r[0] = s0 * scale; r[1] = s1 * scale; r[2] = s2 * scale;
}

#define MOTION_MAX_M 30    /* 3 (degree + 1), degree <= 9 */

/* motion_fit(t, C, P, newest, degree, scale_s, floor_rad2, out_coef) -> ok: the numbers of
 * pipeline._motion.fit_motion for n samples, t (n,), C (n, 3, 3), P (n, 3, 3): r_k =
 * log(C_newest^T C_k), info_k = inv(sym(P_k) + floor I), the normal equations of the
 * polynomial of the given degree in tau = (t - t_newest) / scale_s, solved by Cholesky
 * into out_coef (degree + 1, 3).  0 (nothing written) when an information matrix is
 * singular or a Cholesky pivot falls below 1e-12 of the largest diagonal term: the
 * caller's least squares (with its rank cut) decides then. */
static PyObject *py_motion_fit(PyObject *self, PyObject *args)
{
    Py_buffer bt, bc, bp, oc;
    long newest, degree;
    double scale_s, floor_rad2;
    if (!PyArg_ParseTuple(args, "y*y*y*llddw*", &bt, &bc, &bp, &newest, &degree, &scale_s, &floor_rad2, &oc))
        return NULL;
    long n = (long)(bt.len / sizeof(double));
    int m = 3 * (int)(degree + 1), ok = 0;
    if (degree < 0 || m > MOTION_MAX_M || newest < 0 || newest >= n
        || bc.len != (Py_ssize_t)(9 * n * sizeof(double)) || bp.len != bc.len
        || oc.len != (Py_ssize_t)(m * sizeof(double))) {
        PyBuffer_Release(&bt); PyBuffer_Release(&bc); PyBuffer_Release(&bp); PyBuffer_Release(&oc);
        PyErr_SetString(PyExc_ValueError, "motion_fit: bad sizes");
        return NULL;
    }
    const double *t = bt.buf, *C = bc.buf, *P = bp.buf, *R = C + 9 * newest;
    double N[MOTION_MAX_M * MOTION_MAX_M], b[MOTION_MAX_M];
    memset(N, 0, sizeof N);
    memset(b, 0, sizeof b);
    int D = (int)degree + 1;
    ok = 1;
    Py_BEGIN_ALLOW_THREADS
    for (long k = 0; k < n && ok; k++) {
        const double *Ck = C + 9 * k, *Pk = P + 9 * k;
        double M[9], r[3], Q[9], I[9], Ir[3], basis[MOTION_MAX_M / 3];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                M[3 * i + j] = R[i] * Ck[j] + R[3 + i] * Ck[3 + j] + R[6 + i] * Ck[6 + j];
        rotvec3(M, r);
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                Q[3 * i + j] = 0.5 * (Pk[3 * i + j] + Pk[3 * j + i]) + (i == j ? floor_rad2 : 0.0);
        if (!gj_inverse(Q, 3, I)) { ok = 0; break; }
        for (int a = 0; a < 3; a++) Ir[a] = I[3 * a] * r[0] + I[3 * a + 1] * r[1] + I[3 * a + 2] * r[2];
        double tau = (t[k] - t[newest]) / scale_s, p = 1.0;
        for (int i = 0; i < D; i++) { basis[i] = p; p *= tau; }
        for (int i = 0; i < D; i++) {
            for (int a = 0; a < 3; a++) b[3 * i + a] += basis[i] * Ir[a];
            for (int j = 0; j < D; j++) {
                double bb = basis[i] * basis[j];
                for (int a = 0; a < 3; a++)
                    for (int c = 0; c < 3; c++) N[(3 * i + a) * m + 3 * j + c] += bb * I[3 * a + c];
            }
        }
    }
    if (ok) {                                   /* Cholesky N = L L^T in place (lower) */
        double dmax = 0.0;
        for (int i = 0; i < m; i++) dmax = N[i * m + i] > dmax ? N[i * m + i] : dmax;
        for (int j = 0; j < m && ok; j++) {
            double d = N[j * m + j];
            for (int k = 0; k < j; k++) d -= N[j * m + k] * N[j * m + k];
            if (!(d > 1e-12 * dmax)) { ok = 0; break; }
            d = sqrt(d);
            N[j * m + j] = d;
            for (int i = j + 1; i < m; i++) {
                double v = N[i * m + j];
                for (int k = 0; k < j; k++) v -= N[i * m + k] * N[j * m + k];
                N[i * m + j] = v / d;
            }
        }
    }
    if (ok) {
        double y[MOTION_MAX_M], *x = oc.buf;
        for (int i = 0; i < m; i++) {
            double v = b[i];
            for (int k = 0; k < i; k++) v -= N[i * m + k] * y[k];
            y[i] = v / N[i * m + i];
        }
        for (int i = m - 1; i >= 0; i--) {
            double v = y[i];
            for (int k = i + 1; k < m; k++) v -= N[k * m + i] * x[k];
            x[i] = v / N[i * m + i];
        }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&bt); PyBuffer_Release(&bc); PyBuffer_Release(&bp); PyBuffer_Release(&oc);
    return PyBool_FromLong(ok);
}


/* ---- the mounts' running fit (pipeline._mounts._Track.add, solve, _rules) ---------------- */

#define TRK_NP 10

/* g^T A^-1 g for an n x n A (n <= TRK_NP); 0 when A is singular */
static int quad_inv(const double *A, const double *g, int n, double *out)
{
    double I[TRK_NP * TRK_NP];
    if (!gj_inverse(A, n, I)) return 0;
    double s = 0.0;
    for (int i = 0; i < n; i++) {
        double v = 0.0;
        for (int j = 0; j < n; j++) v += I[n * i + j] * g[j];
        s += g[i] * v;
    }
    *out = s;
    return 1;
}

typedef struct {
    double memory_s, min_monitor, gate_chi2, min_epochs, max_lag_s, max_rho, vf_memory_s, min_wave_std_deg,
        enter_sigmas, stay_sigmas, max_apply_sigma_s;
} TrackParams;

typedef struct {
    double *sc, *N, *b, *a_sum, *aa_sum, *uu_lag;
    const double *limits;
    TrackParams p;
} Track;

static double trk_correlation_factor(const Track *T)
{
    if (T->uu_lag[1] <= 0.0 || T->sc[2] < T->p.min_epochs) return 1.0;
    double rho = T->uu_lag[0] / T->uu_lag[1];
    rho = rho > 0.0 ? rho : 0.0;
    rho = rho < T->p.max_rho ? rho : T->p.max_rho;
    return (1.0 + rho) / (1.0 - rho);
}

/* _Track._fit: theta (10), cov (10 x 10) of the parameters keep (the others 0); 0: singular */
static int trk_fit(const Track *T, const unsigned char *keep, double *theta, double *cov)
{
    int idx[TRK_NP], n = 0;
    for (int i = 0; i < TRK_NP; i++) if (keep[i]) idx[n++] = i;
    /* (A zeroed: gcc cannot see that gj_inverse reads only the n x n written below) */
    double A[TRK_NP * TRK_NP] = {0}, Nk[TRK_NP * TRK_NP], bk[TRK_NP], C[TRK_NP * TRK_NP], th[TRK_NP], tr = 0.0;
    for (int i = 0; i < n; i++) {
        bk[i] = T->b[idx[i]];
        for (int j = 0; j < n; j++) Nk[n * i + j] = T->N[TRK_NP * idx[i] + idx[j]];
        tr += Nk[n * i + i];
    }
    double ridge = 1e-9 * (tr > 1.0 ? tr : 1.0);
    memcpy(A, Nk, sizeof(double) * n * n);
    for (int i = 0; i < n; i++) A[n * i + i] += ridge;
    if (!gj_inverse(A, n, C)) return 0;
    double thb = 0.0, thNth = 0.0;
    for (int i = 0; i < n; i++) {
        double v = 0.0;
        for (int j = 0; j < n; j++) v += C[n * i + j] * bk[j];
        th[i] = v;
        thb += v * bk[i];
    }
    for (int i = 0; i < n; i++) {
        double v = 0.0;
        for (int j = 0; j < n; j++) v += Nk[n * i + j] * th[j];
        thNth += th[i] * v;
    }
    double chi2 = T->sc[0] - 2.0 * thb + thNth;
    chi2 = chi2 > 0.0 ? chi2 : 0.0;
    double dof = 3.0 * T->sc[1] - n, scale = 1.0;
    if (dof > 0) scale = chi2 / dof > 1.0 ? chi2 / dof : 1.0;
    scale *= trk_correlation_factor(T);
    memset(theta, 0, sizeof(double) * TRK_NP);
    memset(cov, 0, sizeof(double) * TRK_NP * TRK_NP);
    for (int i = 0; i < n; i++) {
        theta[idx[i]] = th[i];
        for (int j = 0; j < n; j++) cov[TRK_NP * idx[i] + idx[j]] = C[n * i + j] * scale;
    }
    return 1;
}

/* mount_step(sc, N, b, a_sum, aa_sum, uu_lag, u_prev, theta, cov, theta_full, cov_full, keep,
 *            y, info, a, omega, params, limits,
 *            o_theta, o_cov, o_theta_full, o_cov_full, o_keep, o_u) -> flags or -1
 * One _Track.add (the innovation gate, the running sums, solve and the rules) with the
 * track's arrays updated in place and its scalars in sc (see pipeline/_mounts.py,
 * _SC_*).  -1: nothing changed (a singular matrix where NumPy would raise): the caller's
 * Python path runs.  Flags: 1 a new innovation u in o_u, 2 a new fit in o_theta / o_cov,
 * 4 a new full fit in o_theta_full / o_cov_full and keep in o_keep. */
static PyObject *py_mount_step(PyObject *self, PyObject *args)
{
    Py_buffer B[24];
    if (!PyArg_ParseTuple(args, "w*w*w*w*w*w*y*y*y*y*y*y*y*y*y*y*y*y*w*w*w*w*w*w*", &B[0], &B[1], &B[2], &B[3],
                          &B[4], &B[5], &B[6], &B[7], &B[8], &B[9], &B[10], &B[11], &B[12], &B[13], &B[14],
                          &B[15], &B[16], &B[17], &B[18], &B[19], &B[20], &B[21], &B[22], &B[23]))
        return NULL;
    static const Py_ssize_t size[24] = {16 * 8, 100 * 8, 10 * 8, 2 * 8, 4 * 8, 2 * 8, 3 * 8, 10 * 8, 100 * 8,
                                        10 * 8, 100 * 8, 10, 3 * 8, 9 * 8, 2 * 8, 3 * 8, 11 * 8, 22 * 8,
                                        10 * 8, 100 * 8, 10 * 8, 100 * 8, 10, 3 * 8};
    for (int i = 0; i < 24; i++)
        if (B[i].len != size[i]) {
            for (int j = 0; j < 24; j++) PyBuffer_Release(&B[j]);
            PyErr_Format(PyExc_ValueError, "mount_step: argument %d has %zd bytes, not %zd", i, B[i].len, size[i]);
            return NULL;
        }
    Track T;
    T.sc = B[0].buf; T.N = B[1].buf; T.b = B[2].buf; T.a_sum = B[3].buf; T.aa_sum = B[4].buf;
    T.uu_lag = B[5].buf; T.limits = B[17].buf;
    const double *prm = B[16].buf;
    T.p = (TrackParams){prm[0], prm[1], prm[2], prm[3], prm[4], prm[5], prm[6], prm[7], prm[8], prm[9], prm[10]};
    const double *u_prev = B[6].buf, *theta = B[7].buf, *cov = B[8].buf, *theta_full = B[9].buf,
                 *cov_full = B[10].buf, *y = B[12].buf, *info = B[13].buf, *a = B[14].buf, *omega = B[15].buf;
    const unsigned char *keep = B[11].buf;
    double *o_theta = B[18].buf, *o_cov = B[19].buf, *o_theta_full = B[20].buf, *o_cov_full = B[21].buf,
           *o_u = B[23].buf;
    unsigned char *o_keep = B[22].buf;
    double *sc = T.sc, t = sc[14];
    int flags = 0;
    /* X (3 x 10): s, G (roll, pitch), delta */
    double X[3 * TRK_NP];
    memset(X, 0, sizeof X);
    for (int i = 0; i < 3; i++) {
        X[TRK_NP * i + i] = 1.0;
        X[TRK_NP * i + 3 + i] = a[0];
        X[TRK_NP * i + 6 + i] = a[1];
        X[TRK_NP * i + 9] = omega[i];
    }
    /* the innovation gate (computed first: nothing is changed when a matrix is singular) */
    int gate = 0, gated = 0, have_u = 0;
    double chi2 = 0.0, u[3] = {0, 0, 0};
    if (sc[2] >= T.p.min_monitor) {
        gate = 1;
        for (int i = 0; i < TRK_NP; i++) if (!isfinite(theta_full[i])) { gate = 0; break; }
    }
    if (gate) {
        double Ii[9], S[9], v[3], XC[3 * TRK_NP];
        if (!gj_inverse(info, 3, Ii)) goto fallback;
        for (int i = 0; i < 3; i++) {
            double s = y[i];
            for (int j = 0; j < TRK_NP; j++) s -= X[TRK_NP * i + j] * theta_full[j];
            v[i] = s;
            for (int j = 0; j < TRK_NP; j++) {
                double w = 0.0;
                for (int k = 0; k < TRK_NP; k++) w += X[TRK_NP * i + k] * cov_full[TRK_NP * k + j];
                XC[TRK_NP * i + j] = w;
            }
        }
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double w = 0.0;
                for (int k = 0; k < TRK_NP; k++) w += XC[TRK_NP * i + k] * X[TRK_NP * j + k];
                S[3 * i + j] = Ii[3 * i + j] + w;
            }
        if (!quad_inv(S, v, 3, &chi2)) goto fallback;
        /* the whitened innovation u = L^-1 v (Cholesky of S; none when S is not positive) */
        double L[9] = {0};
        have_u = 1;
        for (int j = 0; j < 3 && have_u; j++) {
            double d = S[3 * j + j];
            for (int k = 0; k < j; k++) d -= L[3 * j + k] * L[3 * j + k];
            if (!(d > 0.0)) { have_u = 0; break; }
            d = sqrt(d);
            L[3 * j + j] = d;
            for (int i = j + 1; i < 3; i++) {
                double w = S[3 * i + j];
                for (int k = 0; k < j; k++) w -= L[3 * i + k] * L[3 * j + k];
                L[3 * i + j] = w / d;
            }
        }
        if (have_u)
            for (int i = 0; i < 3; i++) {
                double w = v[i];
                for (int k = 0; k < i; k++) w -= L[3 * i + k] * u[k];
                u[i] = w / L[3 * i + i];
            }
    }
    /* forgetting */
    if (!isnan(sc[4])) {
        double dt = t - sc[4], lam = exp(-(dt > 0.0 ? dt : 0.0) / T.p.memory_s);
        for (int i = 0; i < 100; i++) T.N[i] *= lam;
        for (int i = 0; i < 10; i++) T.b[i] *= lam;
        sc[0] *= lam; sc[1] *= lam;
        T.a_sum[0] *= lam; T.a_sum[1] *= lam;
        for (int i = 0; i < 4; i++) T.aa_sum[i] *= lam;
    }
    sc[4] = t;
    if (gate) {
        /* _add_variance */
        double c = chi2 < T.p.gate_chi2 ? chi2 : T.p.gate_chi2;
        if (!isnan(sc[10])) {
            double dt = t - sc[10], lam = exp(-(dt > 0.0 ? dt : 0.0) / T.p.vf_memory_s);
            sc[8] *= lam; sc[9] *= lam;
        }
        sc[10] = t; sc[8] += c; sc[9] += 1.0;
        /* _add_correlation */
        if (have_u) {
            if (chi2 > T.p.gate_chi2) {
                double f = sqrt(T.p.gate_chi2 / chi2);
                for (int i = 0; i < 3; i++) u[i] = u[i] * f;
            }
            int had = sc[13] != 0.0;
            double t_prev = sc[7];
            memcpy(o_u, u, sizeof u);
            flags |= 1;
            sc[13] = 1.0; sc[7] = t;
            if (had && t - t_prev > 0.0 && t - t_prev <= T.p.max_lag_s) {
                double lam = exp(-(t - t_prev) / T.p.memory_s), up = 0.0, uu = 0.0, pp = 0.0;
                T.uu_lag[0] *= lam; T.uu_lag[1] *= lam;
                for (int i = 0; i < 3; i++) { up += u[i] * u_prev[i]; uu += u[i] * u[i]; pp += u_prev[i] * u_prev[i]; }
                T.uu_lag[0] += up;
                T.uu_lag[1] += 0.5 * (uu + pp);
            }
        }
        if (chi2 > T.p.gate_chi2) { sc[3] += 1.0; gated = 1; }
    }
    if (!gated) {
        double XI[TRK_NP * 3];                         /* X^T info (10 x 3) */
        for (int i = 0; i < TRK_NP; i++)
            for (int j = 0; j < 3; j++) {
                double w = 0.0;
                for (int k = 0; k < 3; k++) w += X[TRK_NP * k + i] * info[3 * k + j];
                XI[3 * i + j] = w;
            }
        for (int i = 0; i < TRK_NP; i++) {
            for (int j = 0; j < TRK_NP; j++) {
                double w = 0.0;
                for (int k = 0; k < 3; k++) w += XI[3 * i + k] * X[TRK_NP * k + j];
                T.N[TRK_NP * i + j] += w;
            }
            double w = 0.0;
            for (int k = 0; k < 3; k++) w += XI[3 * i + k] * y[k];
            T.b[i] += w;
        }
        double yIy = 0.0;
        for (int i = 0; i < 3; i++) {
            double w = 0.0;
            for (int k = 0; k < 3; k++) w += info[3 * i + k] * y[k];
            yIy += y[i] * w;
        }
        sc[0] += yIy; sc[1] += 1.0; sc[2] += 1.0;
        T.a_sum[0] += a[0]; T.a_sum[1] += a[1];
        T.aa_sum[0] += a[0] * a[0]; T.aa_sum[1] += a[0] * a[1]; T.aa_sum[2] += a[1] * a[0]; T.aa_sum[3] += a[1] * a[1];
        /* solve */
        const double *th_now = theta, *cov_now = cov;
        const unsigned char *keep_now = keep;
        if (sc[2] >= T.p.min_monitor) {
            unsigned char active[TRK_NP];
            double var[2] = {0.0, 0.0};
            if (sc[1] > 0) {
                double m0 = T.a_sum[0] / sc[1], m1 = T.a_sum[1] / sc[1];
                var[0] = T.aa_sum[0] / sc[1] - m0 * m0;
                var[1] = T.aa_sum[3] / sc[1] - m1 * m1;
            }
            for (int i = 0; i < TRK_NP; i++) active[i] = 1;
            for (int j = 0; j < 2; j++)
                if (!(var[j] > T.p.min_wave_std_deg * T.p.min_wave_std_deg))
                    for (int i = 3 + 3 * j; i < 6 + 3 * j; i++) active[i] = 0;
            double fth[TRK_NP], fcov[TRK_NP * TRK_NP];
            if (trk_fit(&T, active, fth, fcov)) {
                unsigned char kp[TRK_NP];
                memcpy(kp, active, sizeof kp);
                for (int j = 0; j < 2; j++) {
                    int c0 = 3 + 3 * j;
                    if (!(active[c0] && active[c0 + 1] && active[c0 + 2])) { sc[11 + j] = 0.0; continue; }
                    double g[3], C[9], q;
                    for (int i = 0; i < 3; i++) {
                        g[i] = fth[c0 + i];
                        for (int k = 0; k < 3; k++) C[3 * i + k] = fcov[TRK_NP * (c0 + i) + c0 + k];
                    }
                    if (!quad_inv(C, g, 3, &q)) q = INFINITY;
                    int used = sc[11 + j] != 0.0;
                    used = q > T.limits[used ? 0 : 1];
                    sc[11 + j] = used;
                    for (int i = c0; i < c0 + 3; i++) kp[i] = kp[i] && used;
                }
                int same = memcmp(kp, active, sizeof kp) == 0, ok = 1;
                if (same) {
                    memcpy(o_theta, fth, sizeof fth);
                    memcpy(o_cov, fcov, sizeof fcov);
                } else {
                    ok = trk_fit(&T, kp, o_theta, o_cov);
                }
                if (ok) {
                    memcpy(o_theta_full, fth, sizeof fth);
                    memcpy(o_cov_full, fcov, sizeof fcov);
                    memcpy(o_keep, kp, sizeof kp);
                    flags |= 6;
                    th_now = o_theta; cov_now = o_cov; keep_now = o_keep;
                }
            }
        }
        /* _rules */
        int finite = 1;
        for (int i = 0; i < TRK_NP; i++) if (!isfinite(th_now[i])) { finite = 0; break; }
        if (sc[2] >= T.p.min_epochs && finite) {
            double off = th_now[9] * 1e-3, c99 = cov_now[TRK_NP * 9 + 9];
            double sig = isfinite(c99) ? sqrt(c99) * 1e-3 : NAN;
            double k = sc[5] != 0.0 ? T.p.stay_sigmas : T.p.enter_sigmas;
            sc[5] = (sig <= T.p.max_apply_sigma_s && fabs(off) > k * sig) ? 1.0 : 0.0;
            int idx[9], n = 0;
            for (int i = 0; i < 9; i++) if (keep_now[i]) idx[n++] = i;
            double f[9], C[81], q;
            for (int i = 0; i < n; i++) {
                f[i] = th_now[idx[i]];
                for (int j = 0; j < n; j++) C[n * i + j] = cov_now[TRK_NP * idx[i] + idx[j]];
            }
            if (quad_inv(C, f, n, &q))
                sc[6] = q > T.limits[(sc[6] != 0.0 ? 2 : 12) + n] ? 1.0 : 0.0;
        }
    }
    for (int j = 0; j < 24; j++) PyBuffer_Release(&B[j]);
    return PyLong_FromLong(flags);
fallback:
    for (int j = 0; j < 24; j++) PyBuffer_Release(&B[j]);
    return PyLong_FromLong(-1);
}


/* ---- the engine's integrity check (pipeline._integrity.check_integrity) ---------------- */

static void expm3(const double *phi, double *R)       /* pipeline._motion.expm_rotvec */
{
    double x = phi[0], y = phi[1], z = phi[2], a = sqrt(x * x + y * y + z * z);
    if (a == 0.0) {
        for (int i = 0; i < 9; i++) R[i] = (i % 4 == 0) ? 1.0 : 0.0;
        return;
    }
    double s = sin(a) / a, c1 = (1.0 - cos(a)) / (a * a);
    R[0] = 1.0 - c1 * (y * y + z * z); R[1] = c1 * x * y - s * z; R[2] = c1 * x * z + s * y;
    R[3] = c1 * x * y + s * z; R[4] = 1.0 - c1 * (x * x + z * z); R[5] = c1 * y * z - s * x;
    R[6] = c1 * x * z - s * y; R[7] = c1 * y * z + s * x; R[8] = 1.0 - c1 * (x * x + y * y);
}

static void mul_t3(const double *A, const double *B, double *out)    /* A^T B */
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[3 * i + j] = A[i] * B[j] + A[3 + i] * B[3 + j] + A[6 + i] * B[6 + j];
}

#define INTEGRITY_MAX_N 16

/* integrity(C, P, floor_rad2, out_d, out_chi2k) -> 1, 0 (a singular matrix: the caller's
 * Python path) or -1 (a covariance not finite: not checked).  For n sensors, C (n, 3, 3)
 * their deck attitudes, P (n, 3, 3) covariances, floor_rad2 (n,): infos I_k =
 * inv(sym(P_k) + floor_k I), r_k = log(C_0^T C_k), the information-weighted mean
 * C_mean = C_0 exp(solve(sum I_k, sum I_k r_k)), d_k = log(C_mean^T C_k) into out_d (n, 3)
 * and d_k^T I_k d_k into out_chi2k (n,). */
static PyObject *py_integrity(PyObject *self, PyObject *args)
{
    Py_buffer bc, bp, bf, od, oq;
    if (!PyArg_ParseTuple(args, "y*y*y*w*w*", &bc, &bp, &bf, &od, &oq)) return NULL;
    long n = (long)(bf.len / sizeof(double));
    int ok = 1;
    if (n < 1 || n > INTEGRITY_MAX_N || bc.len != (Py_ssize_t)(9 * n * sizeof(double)) || bp.len != bc.len
        || od.len != (Py_ssize_t)(3 * n * sizeof(double)) || oq.len != bf.len) {
        PyBuffer_Release(&bc); PyBuffer_Release(&bp); PyBuffer_Release(&bf); PyBuffer_Release(&od);
        PyBuffer_Release(&oq);
        PyErr_SetString(PyExc_ValueError, "integrity: bad sizes");
        return NULL;
    }
    const double *C = bc.buf, *P = bp.buf, *fl = bf.buf;
    double *d = od.buf, *q = oq.buf;
    double I[INTEGRITY_MAX_N][9], F[9] = {0}, h[3] = {0}, Fi[9], rm[3], E[9], Cm[9], M[9];
    for (long k = 0; k < n && ok == 1; k++) {
        double Q[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                Q[3 * i + j] = 0.5 * (P[9 * k + 3 * i + j] + P[9 * k + 3 * j + i]) + (i == j ? fl[k] : 0.0);
        for (int i = 0; i < 9; i++) if (!isfinite(Q[i])) { ok = -1; break; }
        if (ok == 1 && !gj_inverse(Q, 3, I[k])) ok = 0;
    }
    if (ok == 1) {
        for (long k = 0; k < n; k++) {
            double r[3];
            mul_t3(C, C + 9 * k, M);
            rotvec3(M, r);
            for (int i = 0; i < 3; i++) {
                for (int j = 0; j < 3; j++) F[3 * i + j] += I[k][3 * i + j];
                h[i] += I[k][3 * i] * r[0] + I[k][3 * i + 1] * r[1] + I[k][3 * i + 2] * r[2];
            }
        }
        if (!gj_inverse(F, 3, Fi)) ok = 0;
    }
    if (ok == 1) {
        for (int i = 0; i < 3; i++) rm[i] = Fi[3 * i] * h[0] + Fi[3 * i + 1] * h[1] + Fi[3 * i + 2] * h[2];
        expm3(rm, E);
        for (int i = 0; i < 3; i++)                                     /* C_mean = C_0 E */
            for (int j = 0; j < 3; j++)
                Cm[3 * i + j] = C[3 * i] * E[j] + C[3 * i + 1] * E[3 + j] + C[3 * i + 2] * E[6 + j];
        for (long k = 0; k < n; k++) {
            double *dk = d + 3 * k;
            mul_t3(Cm, C + 9 * k, M);
            rotvec3(M, dk);
            double s = 0.0;
            for (int i = 0; i < 3; i++)
                s += dk[i] * (I[k][3 * i] * dk[0] + I[k][3 * i + 1] * dk[1] + I[k][3 * i + 2] * dk[2]);
            q[k] = s;
        }
    }
    PyBuffer_Release(&bc); PyBuffer_Release(&bp); PyBuffer_Release(&bf); PyBuffer_Release(&od);
    PyBuffer_Release(&oq);
    return PyLong_FromLong(ok);
}

/* direction_info(w (n, 3), cov (n, 2, 2), S (2, 2), out_info (n, 3, 3), out_whiten (n, 2, 3), out_gram (n, 2, 2),
 *                n, rad_per_px, floor2) -> the number of covariances that are not positive definite
 * (then nothing is written: the caller's NumPy path raises as before).  shipstar.pipeline._sensor.
 * direction_info star by star in closed form (its docstring has the algebra): J (3 x 2) the pinhole's
 * derivative of the direction by the pixel position, J+ = (J^T J)^-1 J^T, L L^T = cov, whiten =
 * L^-1 J+, G = L^-1 L^-T, info = whiten^T (S + floor2 G)^-1 whiten; the same values as NumPy's
 * LAPACK calls to rounding. */
static PyObject *py_direction_info(PyObject *self, PyObject *args)
{
    Py_buffer bw, bc, bS, oi, ow, og;
    Py_ssize_t n;
    double scale, floor2;
    if (!PyArg_ParseTuple(args, "y*y*y*w*w*w*ndd", &bw, &bc, &bS, &oi, &ow, &og, &n, &scale, &floor2)) return NULL;
    const double *w = bw.buf, *cov = bc.buf, *S = bS.buf;
    double *info = oi.buf, *whiten = ow.buf, *gram = og.buf;
    Py_ssize_t bad = 0;
    for (Py_ssize_t s = 0; s < n; s++) {
        const double *c = cov + 4 * s;
        double l00 = c[0] > 0.0 ? sqrt(c[0]) : NAN;
        double l10 = c[2] / l00, d = c[3] - l10 * l10;
        if (!(c[0] > 0.0 && d > 0.0 && isfinite(d))) bad++;
    }
    if (bad == 0) {
        for (Py_ssize_t s = 0; s < n; s++) {
            const double *u = w + 3 * s, *c = cov + 4 * s;
            double k = scale * u[0];
            double P[3][3];
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) P[a][b] = (a == b ? 1.0 : 0.0) - u[a] * u[b];
            double J[3][2];
            for (int a = 0; a < 3; a++) { J[a][0] = P[a][2] * k; J[a][1] = -P[a][1] * k; }
            double A00 = J[0][0] * J[0][0] + J[1][0] * J[1][0] + J[2][0] * J[2][0];
            double A01 = J[0][0] * J[0][1] + J[1][0] * J[1][1] + J[2][0] * J[2][1];
            double A11 = J[0][1] * J[0][1] + J[1][1] * J[1][1] + J[2][1] * J[2][1];
            double det = A00 * A11 - A01 * A01;
            double Jp[2][3];                                   /* (J^T J)^-1 J^T */
            for (int a = 0; a < 3; a++) {
                Jp[0][a] = (A11 * J[a][0] - A01 * J[a][1]) / det;
                Jp[1][a] = (A00 * J[a][1] - A01 * J[a][0]) / det;
            }
            double l00 = sqrt(c[0]), l10 = c[2] / l00, l11 = sqrt(c[3] - l10 * l10);
            double *Wt = whiten + 6 * s;                        /* L^-1 J+ by forward substitution */
            for (int a = 0; a < 3; a++) {
                Wt[a] = Jp[0][a] / l00;
                Wt[3 + a] = (Jp[1][a] - l10 * Wt[a]) / l11;
            }
            double i00 = 1.0 / l00, i10 = -l10 / (l00 * l11), i11 = 1.0 / l11;   /* L^-1 */
            double *G = gram + 4 * s;
            G[0] = i00 * i00;
            G[1] = G[2] = i00 * i10;
            G[3] = i10 * i10 + i11 * i11;
            double V00 = S[0] + floor2 * G[0], V01 = S[1] + floor2 * G[1], V10 = S[2] + floor2 * G[2],
                   V11 = S[3] + floor2 * G[3];
            double dv = V00 * V11 - V01 * V10;
            double Vi[2][2] = {{V11 / dv, -V01 / dv}, {-V10 / dv, V00 / dv}};
            double *I = info + 9 * s;
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) {
                    double t0 = Vi[0][0] * Wt[b] + Vi[0][1] * Wt[3 + b];
                    double t1 = Vi[1][0] * Wt[b] + Vi[1][1] * Wt[3 + b];
                    I[3 * a + b] = Wt[a] * t0 + Wt[3 + a] * t1;
                }
        }
    }
    PyBuffer_Release(&bw); PyBuffer_Release(&bc); PyBuffer_Release(&bS);
    PyBuffer_Release(&oi); PyBuffer_Release(&ow); PyBuffer_Release(&og);
    return PyLong_FromSsize_t(bad);
}

/* mid_exposure(w (n, 3), omega (3,), alpha (3,), exposure_s, psf_sigma_px, pixel_rad, out_mid (n, 3),
 * out_turn (n,)): pipeline._exposure.mid_exposure_vectors, star by star (its NumPy code is the
 * reference; the same arithmetic, to rounding: NumPy's dot products and scipy's ndtr against
 * these sums and libm's erf).  psf_sigma_px NaN: no streak model (time averages). */
static double along_factor(double length_px, double psf_sigma_px)
{
    double s2 = sqrt(2.0 * (psf_sigma_px * psf_sigma_px + 1.0 / 12.0));
    double x = fabs(length_px) / s2;
    if (x < 0.5) return 1.0 - x * x / 10.0 + x * x * x * x / 210.0;
    double phi0 = 1.0 / sqrt(2.0 * M_PI);
    return 3.0 + 24.0 / (x * x) - 12.0 * (0.5 * erf(x * M_SQRT1_2)) / (x * phi0 * -expm1(-0.5 * x * x));
}

static PyObject *py_mid_exposure(PyObject *self, PyObject *args)
{
    Py_buffer bw, bo, ba, om_, ot;
    double T, psf, pixel_rad;
    if (!PyArg_ParseTuple(args, "y*y*y*dddw*w*", &bw, &bo, &ba, &T, &psf, &pixel_rad, &om_, &ot)) return NULL;
    Py_ssize_t n = bw.len / (Py_ssize_t)(3 * sizeof(double));
    if (bw.len != (Py_ssize_t)(3 * n * sizeof(double)) || bo.len != (Py_ssize_t)(3 * sizeof(double))
        || ba.len != bo.len || om_.len != bw.len || ot.len != (Py_ssize_t)(n * sizeof(double))) {
        PyBuffer_Release(&bw); PyBuffer_Release(&bo); PyBuffer_Release(&ba); PyBuffer_Release(&om_);
        PyBuffer_Release(&ot);
        PyErr_SetString(PyExc_ValueError, "mid_exposure: bad sizes");
        return NULL;
    }
    const double *W = bw.buf, *om = bo.buf, *al = ba.buf;
    double *mid = om_.buf, *turn = ot.buf;
    int fitted = isfinite(psf) && isfinite(pixel_rad) && pixel_rad > 0.0;
    double oo = om[0] * om[0] + om[1] * om[1] + om[2] * om[2], scale = T * T / 24.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *wi = W + 3 * i;
        double nw = sqrt(wi[0] * wi[0] + wi[1] * wi[1] + wi[2] * wi[2]);
        double x = wi[0] / nw, y = wi[1] / nw, z = wi[2] / nw;
        double wom = x * om[0] + y * om[1] + z * om[2];
        double acc[3] = {y * al[2] - z * al[1] + (wom * om[0] - oo * x),
                         z * al[0] - x * al[2] + (wom * om[1] - oo * y),
                         x * al[1] - y * al[0] + (wom * om[2] - oo * z)};
        if (fitted) {
            double vel[3] = {y * om[2] - z * om[1], z * om[0] - x * om[2], x * om[1] - y * om[0]};
            double speed = sqrt(vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2]);
            if (speed > 0.0) {
                double k = along_factor(speed * T / pixel_rad, psf);
                double e[3] = {vel[0] / speed, vel[1] / speed, vel[2] / speed};
                double a = (k - 1.0) * (acc[0] * e[0] + acc[1] * e[1] + acc[2] * e[2]);
                for (int c = 0; c < 3; c++) acc[c] += a * e[c];
            }
        }
        double m[3] = {x - acc[0] * scale, y - acc[1] * scale, z - acc[2] * scale};
        double nm = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
        double d2 = 0.0;
        for (int c = 0; c < 3; c++) {
            m[c] /= nm;
            mid[3 * i + c] = m[c];
        }
        double dx = m[0] - x, dy = m[1] - y, dz = m[2] - z;
        d2 = dx * dx + dy * dy + dz * dz;
        double half = 0.5 * sqrt(d2);
        turn[i] = 2.0 * asin(half < 1.0 ? half : 1.0);
    }
    PyBuffer_Release(&bw); PyBuffer_Release(&bo); PyBuffer_Release(&ba); PyBuffer_Release(&om_);
    PyBuffer_Release(&ot);
    Py_RETURN_NONE;
}

/* common_mode(w (N, 3), W (N, 3, 3) or empty, sigma (N,), rows (m,) int64, P (3, 3),
 *             R (3, 3), Mmodel (3, 3), Mmount (3, 3) or empty, out (3, 3)) -> 1, or 0 (nothing
 * added: I + Mmount F singular, the caller's NumPy path decides).  One sensor's term of
 * shipstar.ship._common_mode_covariance, added to out: F = sum over ``rows`` of the
 * information about the deck axes of the unit direction u_i = w_i / |w_i| -- [u_i]x^T W_i
 * [u_i]x with information matrices, sigma_i^-2 (I - u_i u_i^T) without -- then with a mount's
 * covariance F (I + Mmount F)^-1, G = P F and out += G (R Mmodel R^T) G^T.  The same algebra
 * as the NumPy path, its 3 x 3 products summed in another order (equal to rounding). */
static PyObject *py_common_mode(PyObject *self, PyObject *args)
{
    Py_buffer bw, bW, bs, br, bP, bR, bM, bK, oo;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*w*", &bw, &bW, &bs, &br, &bP, &bR, &bM, &bK, &oo)) return NULL;
    Py_ssize_t N = bw.len / (Py_ssize_t)(3 * sizeof(double)), m = br.len / (Py_ssize_t)sizeof(int64_t);
    int aniso = bW.len > 0, mount = bK.len > 0;
    const Py_ssize_t s9 = (Py_ssize_t)(9 * sizeof(double));
    int bad = bw.len != (Py_ssize_t)(3 * N * sizeof(double)) || br.len != (Py_ssize_t)(m * sizeof(int64_t))
        || (aniso ? bW.len != (Py_ssize_t)(9 * N * sizeof(double)) : bs.len != (Py_ssize_t)(N * sizeof(double)))
        || bP.len != s9 || bR.len != s9 || bM.len != s9 || (mount && bK.len != s9) || oo.len != s9;
    const int64_t *rows = br.buf;
    for (Py_ssize_t k = 0; k < m && !bad; k++) bad = rows[k] < 0 || rows[k] >= N;
    if (bad) {
        PyBuffer_Release(&bw); PyBuffer_Release(&bW); PyBuffer_Release(&bs); PyBuffer_Release(&br);
        PyBuffer_Release(&bP); PyBuffer_Release(&bR); PyBuffer_Release(&bM); PyBuffer_Release(&bK);
        PyBuffer_Release(&oo);
        PyErr_SetString(PyExc_ValueError, "common_mode: bad sizes or rows");
        return NULL;
    }
    const double *w = bw.buf, *Wa = bW.buf, *sg = bs.buf, *P = bP.buf, *R = bR.buf, *Mm = bM.buf, *K = bK.buf;
    double *out = oo.buf;
    double F[9] = {0}, Fm[9], G[9], Q[9], T[9], X[9], Xi[9];
    int ok = 1;
    for (Py_ssize_t k = 0; k < m; k++) {
        const double *wi = w + 3 * rows[k];
        double n = sqrt(wi[0] * wi[0] + wi[1] * wi[1] + wi[2] * wi[2]);
        double u[3] = {wi[0] / n, wi[1] / n, wi[2] / n};
        if (aniso) {
            add_fisher(u, Wa + 9 * rows[k], F);
        } else {
            double s2 = 1.0 / (sg[rows[k]] * sg[rows[k]]);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    F[3 * i + j] += s2 * ((i == j ? 1.0 : 0.0) - u[i] * u[j]);
        }
    }
    if (mount) {                                             /* F (I + K F)^-1 */
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                X[3 * i + j] = (i == j ? 1.0 : 0.0) + K[3 * i] * F[j] + K[3 * i + 1] * F[3 + j] + K[3 * i + 2] * F[6 + j];
        if (!gj_inverse(X, 3, Xi)) ok = 0;
        else {
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    Fm[3 * i + j] = F[3 * i] * Xi[j] + F[3 * i + 1] * Xi[3 + j] + F[3 * i + 2] * Xi[6 + j];
            memcpy(F, Fm, sizeof F);
        }
    }
    if (ok) {
        for (int i = 0; i < 3; i++)                          /* G = P F, T = R Mmodel */
            for (int j = 0; j < 3; j++) {
                G[3 * i + j] = P[3 * i] * F[j] + P[3 * i + 1] * F[3 + j] + P[3 * i + 2] * F[6 + j];
                T[3 * i + j] = R[3 * i] * Mm[j] + R[3 * i + 1] * Mm[3 + j] + R[3 * i + 2] * Mm[6 + j];
            }
        for (int i = 0; i < 3; i++)                          /* Q = T R^T */
            for (int j = 0; j < 3; j++)
                Q[3 * i + j] = T[3 * i] * R[3 * j] + T[3 * i + 1] * R[3 * j + 1] + T[3 * i + 2] * R[3 * j + 2];
        for (int i = 0; i < 3; i++)                          /* T = G Q */
            for (int j = 0; j < 3; j++)
                T[3 * i + j] = G[3 * i] * Q[j] + G[3 * i + 1] * Q[3 + j] + G[3 * i + 2] * Q[6 + j];
        for (int i = 0; i < 3; i++)                          /* out += T G^T */
            for (int j = 0; j < 3; j++)
                out[3 * i + j] += T[3 * i] * G[3 * j] + T[3 * i + 1] * G[3 * j + 1] + T[3 * i + 2] * G[3 * j + 2];
    }
    PyBuffer_Release(&bw); PyBuffer_Release(&bW); PyBuffer_Release(&bs); PyBuffer_Release(&br);
    PyBuffer_Release(&bP); PyBuffer_Release(&bR); PyBuffer_Release(&bM); PyBuffer_Release(&bK);
    PyBuffer_Release(&oo);
    return PyLong_FromLong(ok);
}

/* sensor_rows(w (N, 3), info (N, 3, 3) or empty, model (3, 3) or empty, rows (m,) int64, R (3, 3),
 *             out_w (m, 3), out_info (m, 3, 3) or empty, out_model (3, 3) or empty): the rows
 * ``rows`` of a frame's star directions turned by R (out_w = w[rows] R^T) with their
 * information matrices (R info[rows] R^T) and the model covariance (R model R^T):
 * shipstar.pipeline._sensor.FrameResult.sensor_stars in one call, its NumPy products
 * summed in another order (equal to rounding). */
static void rot_sandwich(const double *R, const double *A, double *out)     /* R A R^T */
{
    double T[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            T[3 * i + j] = R[3 * i] * A[j] + R[3 * i + 1] * A[3 + j] + R[3 * i + 2] * A[6 + j];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[3 * i + j] = T[3 * i] * R[3 * j] + T[3 * i + 1] * R[3 * j + 1] + T[3 * i + 2] * R[3 * j + 2];
}

static PyObject *py_sensor_rows(PyObject *self, PyObject *args)
{
    Py_buffer bw, bi, bm, br, bR, ow, oi, om;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*w*w*", &bw, &bi, &bm, &br, &bR, &ow, &oi, &om)) return NULL;
    Py_ssize_t N = bw.len / (Py_ssize_t)(3 * sizeof(double)), m = br.len / (Py_ssize_t)sizeof(int64_t);
    const Py_ssize_t s9 = (Py_ssize_t)(9 * sizeof(double));
    int info = bi.len > 0, model = bm.len > 0;
    int bad = bw.len != (Py_ssize_t)(3 * N * sizeof(double)) || br.len != (Py_ssize_t)(m * sizeof(int64_t))
        || (info && bi.len != N * s9) || (model && bm.len != s9) || bR.len != s9
        || ow.len != (Py_ssize_t)(3 * m * sizeof(double)) || oi.len != (info ? m * s9 : 0)
        || om.len != (model ? s9 : 0);
    const int64_t *rows = br.buf;
    for (Py_ssize_t k = 0; k < m && !bad; k++) bad = rows[k] < 0 || rows[k] >= N;
    if (!bad) {
        const double *w = bw.buf, *I = bi.buf, *R = bR.buf;
        double *outw = ow.buf, *outi = oi.buf;
        for (Py_ssize_t k = 0; k < m; k++) {
            const double *wi = w + 3 * rows[k];
            for (int i = 0; i < 3; i++)
                outw[3 * k + i] = wi[0] * R[3 * i] + wi[1] * R[3 * i + 1] + wi[2] * R[3 * i + 2];
            if (info) rot_sandwich(R, I + 9 * rows[k], outi + 9 * k);
        }
        if (model) rot_sandwich(R, bm.buf, om.buf);
    }
    PyBuffer_Release(&bw); PyBuffer_Release(&bi); PyBuffer_Release(&bm); PyBuffer_Release(&br);
    PyBuffer_Release(&bR); PyBuffer_Release(&ow); PyBuffer_Release(&oi); PyBuffer_Release(&om);
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "sensor_rows: bad sizes or rows");
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"solve", py_solve, METH_VARARGS, "solve_attitude's QUEST path (see _solve.py)"},
    {"direction_info", py_direction_info, METH_VARARGS, "direction_info (see pipeline/_sensor.py)"},
    {"quest", py_quest, METH_VARARGS, "QUEST of weighted rows (see pipeline/_conditions.py)"},
    {"residual_moments", py_residual_moments, METH_VARARGS,
     "expected whitened residual moments of a weighted fit (see pipeline/_conditions.py)"},
    {"noise_fit", py_noise_fit, METH_VARARGS, "NoiseModel._fit (see pipeline/_conditions.py)"},
    {"motion_fit", py_motion_fit, METH_VARARGS, "fit_motion's normal equations (see pipeline/_motion.py)"},
    {"integrity", py_integrity, METH_VARARGS, "check_integrity's weighted mean and chi2 (see pipeline/_integrity.py)"},
    {"mount_step", py_mount_step, METH_VARARGS, "one epoch of the mounts' running fit (see pipeline/_mounts.py)"},
    {"mid_exposure", py_mid_exposure, METH_VARARGS, "mid_exposure_vectors (see pipeline/_exposure.py)"},
    {"sensor_rows", py_sensor_rows, METH_VARARGS, "FrameResult.sensor_stars's turned rows (see pipeline/_sensor.py)"},
    {"common_mode", py_common_mode, METH_VARARGS, "one sensor's term of _common_mode_covariance (see ship.py)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_ckernels",
                                    "Compiled path of shipstar.attitude.solve_attitude (see _solve.py).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__ckernels(void)
{
    return module_with_source_digest(PyModule_Create(&moddef));
}
