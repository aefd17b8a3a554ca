/* Compiled kernels of shipstar's star extraction (plain C99, Python's buffer protocol).
 *
 * Called only through shipstar/extract/_kernels.py, which checks dtypes, C order and sizes
 * (the kernels trust them).  Each kernel repeats, star by star, the arithmetic of the
 * vectorised NumPy code it replaced (docstrings of _kernels.py name it); the results agree
 * to rounding (sums taken in another order).  The GIL is released around the loops.
 *
 *   streak_equations  normal equations of the smeared-PSF model (tabulated pixel fractions)
 *   streak_fit        Levenberg-Marquardt fit of that model, star by star
 *   gauss_fit         Gauss-Newton fit of the pixel-integrated Gaussian (point stars), star by star
 *   gauss_normal      its normal equations
 *   block_stats       median, MAD and clipped RMS of the background mesh's block samples
 *   median3           3 x 3 median filter of the block grid
 *   grid_box_sums     3 x 3 sums around a regular grid of pixels (the mesh's box-noise factor)
 *   value_step        smallest positive step between sorted block samples
 *   mesh_at           bilinear background and noise at pixel positions
 *   candidates        pixels above their block's level (one pass), as sorted flat indices
 *   local_max         candidates that are the maximum of their 3 x 3 neighbourhood
 *   neighbours        the 8 neighbours' values of pixels
 *   tap_sum           the line filter's sum of shifted images, tile by tile
 *   line_filter       the whole line filter from the frame, row by row
 *   box3              3 x 3 mean of a float32 window (trails, _artifacts)
 *   region_shape      the trail test's region around a detection: its length and width
 *   label_runs        8- (or 4-) connected components of sorted candidate pixels (union-find on runs)
 *   suppress          greedy suppression of peaks within a stronger peak's streak footprint
 *   streak_peaks      the line filter's peaks from its candidates: suppression, components, extents
 *   point_objects     point sources from the candidates: 3 x 3 peaks, the box test, one a component
 *   erf_array         erf of an array (libm)
 *   cho_solve         the two triangular substitutions of a Cholesky solve, matrix by matrix
 *   grid_box_z        the mesh's whitened 3 x 3 sums on a regular grid (its box-noise factor)
 *   streak_start      the streak fits' start parameters (centre of light near the segment, flux)
 *   streak_footprint  the streak fits' footprints: pixel count, peak, saturated or off the image
 *   window_peaks      windowed tracking: the line filter's maximum near each window's centre
 *   ring_levels       windowed tracking: the windows' border-ring background levels
 *   gather            rectangular pixel windows (as float64) and their validity
 *   crowded_count     windowed tracking: bright pixels outside each star's footprint
 *   point_start       the point fits' start values (centre of light of the central 3 x 3, flux)
 *   too_sharp         hot pixels and cosmic rays: peaks sharper than the PSF allows
 *   component_stats   per star: pixels, peak, flags, thresholded centre of gravity and moments
 *   persistent_pairs  persistent pixels: each detection with the remembered frames near its pixel
 *   persistent_merge  persistent pixels: the remembered table with a frame's detections added
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "../_csource.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* parameter columns of p (N, 7) */
enum { PX = 0, PY = 1, PFLUX = 2, PBG = 3, PSIGMA = 4, PDX = 5, PDY = 6, NPAR = 7 };
#define KMAX 6

typedef struct {
    /* window data of one star */
    const double *values;   /* (P,) */
    const uint8_t *valid;   /* (P,) */
    double x0, y0, noise;
} Win;

typedef struct {
    int wy, wx, n, half, steps, fit_smear;
    const double *t, *w;                          /* (n,) nodes and weights */
    const double *frac, *dfrac, *dc, *ddc;        /* (steps + 1, 2 half + 1) */
    double inv_gain;
} Model;

typedef struct {
    /* per-call work memory */
    double *ex0, *ex1;      /* (n, m) x fractions and derivatives at each point's local pixels */
    double *ey0, *ey1;      /* (n, m) y ..., times the point's weight */
    int *cx0, *cy0;         /* (n,) first window column / row of each point's local pixels */
    double *jac;            /* (k, P) */
} Work;

static int work_alloc(Work *wk, const Model *md) {
    int m = 2 * md->half + 1, P = md->wy * md->wx;
    size_t nm = (size_t)md->n * (size_t)m;
    wk->ex0 = malloc(sizeof(double) * (4 * nm + (size_t)KMAX * P));
    wk->cx0 = malloc(sizeof(int) * 2 * (size_t)(md->n > 0 ? md->n : 1));
    if (!wk->ex0 || !wk->cx0) { free(wk->ex0); free(wk->cx0); return -1; }
    wk->ex1 = wk->ex0 + nm;
    wk->ey0 = wk->ex1 + nm;
    wk->ey1 = wk->ey0 + nm;
    wk->jac = wk->ey1 + nm;
    wk->cy0 = wk->cx0 + md->n;
    return 0;
}

static void work_free(Work *wk) { free(wk->ex0); free(wk->cx0); }

/* Pixel fractions of a point at c (table interpolation, as _streak._tabulated_profiles):
 * local pixel j is pixel rint(c) - half + j; writes m values of E and dE/dc (times scale). */
static void point_profile(const Model *md, double c, double scale, double *e, double *de, int *first_px) {
    int m = 2 * md->half + 1;
    double near = rint(c);
    double pos = (c - near + 0.5) * md->steps;
    long i = (long)pos;
    if (i > md->steps - 1) i = md->steps - 1;
    double wgt = pos - (double)i;
    const double *f = md->frac + i * m, *df = md->dfrac + i * m, *d = md->dc + i * m, *dd = md->ddc + i * m;
    for (int j = 0; j < m; j++) {
        e[j] = (f[j] + wgt * df[j]) * scale;
        de[j] = (d[j] + wgt * dd[j]) * scale;
    }
    *first_px = (int)near - md->half;
}

/* Model (P,), its Jacobian (k, P) [x, y, F, b, (dx, dy)] of one star at parameters q (7,). */
static void star_model(const Model *md, const Win *win, const double *q, Work *wk, double *model) {
    int m = 2 * md->half + 1, wy = md->wy, wx = md->wx, P = wy * wx, n = md->n;
    int k = md->fit_smear ? 6 : 4;
    double *jac = wk->jac;
    double *shape = jac + 2 * P, *jx = jac, *jy = jac + P;
    memset(jac, 0, sizeof(double) * (size_t)k * P);
    int x0 = (int)win->x0, y0 = (int)win->y0;
    for (int i = 0; i < n; i++) {
        double cx = q[PX] + md->t[i] * q[PDX], cy = q[PY] + md->t[i] * q[PDY];
        int fx, fy;
        point_profile(md, cx, 1.0, wk->ex0 + i * m, wk->ex1 + i * m, &fx);
        point_profile(md, cy, md->w[i], wk->ey0 + i * m, wk->ey1 + i * m, &fy);
        wk->cx0[i] = fx - x0;
        wk->cy0[i] = fy - y0;
    }
    double *jdx = md->fit_smear ? jac + 4 * P : NULL, *jdy = md->fit_smear ? jac + 5 * P : NULL;
    for (int i = 0; i < n; i++) {
        const double *ex = wk->ex0 + i * m, *dex = wk->ex1 + i * m, *ey = wk->ey0 + i * m, *dey = wk->ey1 + i * m;
        int c0 = wk->cx0[i], r0 = wk->cy0[i];
        int ja = c0 < 0 ? -c0 : 0, jb = (wx - c0 < m) ? wx - c0 : m;
        int ra = r0 < 0 ? -r0 : 0, rb = (wy - r0 < m) ? wy - r0 : m;
        double ti = md->t[i];
        for (int a = ra; a < rb; a++) {
            int base = (r0 + a) * wx + c0;
            double eya = ey[a], deya = dey[a];
            for (int b = ja; b < jb; b++) {
                shape[base + b] += eya * ex[b];
                jx[base + b] += eya * dex[b];
                jy[base + b] += deya * ex[b];
            }
            if (jdx) {
                double teya = eya * ti, tdeya = deya * ti;
                for (int b = ja; b < jb; b++) {
                    jdx[base + b] += teya * dex[b];
                    jdy[base + b] += tdeya * ex[b];
                }
            }
        }
    }
    double flux = q[PFLUX], bg = q[PBG];
    for (int p = 0; p < P; p++) {
        jx[p] *= flux;
        jy[p] *= flux;
        jac[3 * P + p] = 1.0;
        model[p] = bg + flux * shape[p];
    }
    if (jdx) {
        for (int p = 0; p < P; p++) {
            jdx[p] *= flux;
            jdy[p] *= flux;
        }
    }
}

/* Weighted normal equations at q: a (k, k), g (k,), model and var (P,); returns chi2 of
 * the residuals under the weights var_chi (NULL: var itself) and r2sum under var. */
static void star_equations(const Model *md, const Win *win, const double *q, Work *wk,
                           double *a, double *g, double *model, double *var) {
    int P = md->wy * md->wx, k = md->fit_smear ? 6 : 4;
    star_model(md, win, q, wk, model);
    double n2 = win->noise * win->noise, bg = q[PBG];
    for (int j = 0; j < k * k; j++) a[j] = 0.0;
    for (int j = 0; j < k; j++) g[j] = 0.0;
    const double *jac = wk->jac;
    for (int p = 0; p < P; p++) {
        double ex = model[p] - bg;
        double v = n2 + (ex > 0.0 ? ex : 0.0) * md->inv_gain;
        var[p] = v;
        if (!win->valid[p]) continue;
        double wt = 1.0 / v, r = win->values[p] - model[p];
        int star = 0;                   /* off every point's pixels only b's derivative (1) is not 0: */
        for (int j = 0; j < k; j++)     /* the other terms would add exact zeros */
            if (j != 3 && jac[j * P + p] != 0.0) { star = 1; break; }
        if (!star) {
            g[3] += wt * r;
            a[3 * k + 3] += wt;
            continue;
        }
        for (int j = 0; j < k; j++) {
            double jw = jac[j * P + p] * wt;
            g[j] += jw * r;
            for (int l = 0; l <= j; l++) a[j * k + l] += jw * jac[l * P + p];
        }
    }
    for (int j = 0; j < k; j++)
        for (int l = j + 1; l < k; l++) a[j * k + l] = a[l * k + j];
}

static double residual_chi2(const Win *win, const double *model, const double *var, int P) {
    double s = 0.0;
    for (int p = 0; p < P; p++) {
        if (!win->valid[p]) continue;
        double r = win->values[p] - model[p];
        s += r * r / var[p];
    }
    return s;
}

/* Cholesky with floored pivots (as _fit._cholesky) and the solve of (L L^T) x = b, m right sides. */
static void cho_solve(const double *a, int k, double *b, int m) {
    double low[KMAX * KMAX];
    memset(low, 0, sizeof(low));
    for (int j = 0; j < k; j++) {
        double d = a[j * k + j];
        for (int l = 0; l < j; l++) d -= low[j * k + l] * low[j * k + l];
        double floor_ = 1e-12 * fabs(a[j * k + j]) + 1e-300;
        double ljj = sqrt(d > floor_ ? d : floor_);
        if (isnan(d)) ljj = d;
        low[j * k + j] = ljj;
        for (int i = j + 1; i < k; i++) {
            double s = a[i * k + j];
            for (int l = 0; l < j; l++) s -= low[i * k + l] * low[j * k + l];
            low[i * k + j] = s / ljj;
        }
    }
    for (int c = 0; c < m; c++) {
        double *y = b + c;                                       /* column c, stride m */
        for (int i = 0; i < k; i++) {
            double s = y[i * m];
            for (int l = 0; l < i; l++) s -= low[i * k + l] * y[l * m];
            y[i * m] = s / low[i * k + i];
        }
        for (int i = k - 1; i >= 0; i--) {
            double s = y[i * m];
            for (int l = i + 1; l < k; l++) s -= low[l * k + i] * y[l * m];
            y[i * m] = s / low[i * k + i];
        }
    }
}

static double clipd(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* ------------------------------------------------------------------ argument parsing */

typedef struct {
    Py_buffer b[16];
    int n;
} Bufs;

static void bufs_release(Bufs *bs) {
    for (int i = 0; i < bs->n; i++) PyBuffer_Release(&bs->b[i]);
    bs->n = 0;
}

/* ------------------------------------------------------------------ streak_equations */

static PyObject *py_streak_equations(PyObject *self, PyObject *args) {
    Bufs bs = {.n = 0};
    Py_buffer *p = &bs.b[0], *values = &bs.b[1], *valid = &bs.b[2], *x0 = &bs.b[3], *y0 = &bs.b[4],
              *noise = &bs.b[5], *t = &bs.b[6], *w = &bs.b[7], *tab = &bs.b[8], *a_out = &bs.b[9],
              *g_out = &bs.b[10], *model_out = &bs.b[11], *var_out = &bs.b[12], *jac_out = &bs.b[13];
    Py_ssize_t N;
    int wy, wx, n, half, steps, fit_smear;
    double inv_gain;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*w*w*w*w*w*niiiiiid", p, values, valid, x0, y0, noise, t, w, tab,
                          a_out, g_out, model_out, var_out, jac_out, &N, &wy, &wx, &n, &half, &steps, &fit_smear,
                          &inv_gain))
        return NULL;
    bs.n = 14;
    int m = 2 * half + 1, P = wy * wx, k = fit_smear ? 6 : 4;
    size_t tab_len = (size_t)(steps + 1) * m;
    const double *tb = tab->buf;
    Model md = {wy, wx, n, half, steps, fit_smear, t->buf, w->buf, tb, tb + tab_len, tb + 2 * tab_len,
                tb + 3 * tab_len, inv_gain};
    int want_jac = jac_out->len > 0;
    Work wk;
    if (work_alloc(&wk, &md)) { bufs_release(&bs); return PyErr_NoMemory(); }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        Win win = {(const double *)values->buf + s * P, (const uint8_t *)valid->buf + s * P,
                   ((const double *)x0->buf)[s], ((const double *)y0->buf)[s], ((const double *)noise->buf)[s]};
        const double *q = (const double *)p->buf + s * NPAR;
        double *model = (double *)model_out->buf + s * P;
        star_equations(&md, &win, q, &wk, (double *)a_out->buf + s * k * k, (double *)g_out->buf + s * k, model,
                       (double *)var_out->buf + s * P);
        if (want_jac) memcpy((double *)jac_out->buf + s * (size_t)k * P, wk.jac, sizeof(double) * (size_t)k * P);
    }
    Py_END_ALLOW_THREADS
    work_free(&wk);
    bufs_release(&bs);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ streak_fit */

/* One star's Levenberg-Marquardt fit (_streak.fit_streaks / _LMState); p (7,) in/out.
 * Returns converged; a, model: the normal matrix and model of the last accepted parameters. */
static int fit_one(const Model *md, const Win *win, const double *p0, double *p, Work *wk, double *a, double *model,
                   double *scratch, int max_iterations, double tol_px, double fraction, double converged_chi2) {
    int P = md->wy * md->wx, k = md->fit_smear ? 6 : 4;
    static const int free_cols[6] = {PX, PY, PFLUX, PBG, PDX, PDY};
    double *var = scratch, *t_model = scratch + P, *t_var = scratch + 2 * P;
    double g[KMAX], t_a[KMAX * KMAX], t_g[KMAX], last[KMAX] = {0};
    star_equations(md, win, p, wk, a, g, model, var);
    double chi2 = residual_chi2(win, model, var, P);
    double lam = 1e-3;
    double cap = 0.25 * hypot(p[PDX], p[PDY]);
    cap = cap > 0.5 ? cap : 0.5;
    int watched[4] = {0, 1, k - 2, k - 1}, n_w = md->fit_smear ? 4 : 2;
    for (int it = 0; it < max_iterations; it++) {
        /* damped step and the predicted errors of the watched parameters */
        double damped[KMAX * KMAX], rhs[KMAX * 5];
        memcpy(damped, a, sizeof(double) * k * k);
        for (int j = 0; j < k; j++) damped[j * k + j] = a[j * k + j] + lam * a[j * k + j];
        int mr = 1 + n_w;
        for (int j = 0; j < k * mr; j++) rhs[j] = 0.0;
        for (int j = 0; j < k; j++) rhs[j * mr] = g[j];
        for (int c = 0; c < n_w; c++) rhs[watched[c] * mr + 1 + c] = 1.0;
        cho_solve(damped, k, rhs, mr);
        double step[KMAX], sig[4];
        for (int j = 0; j < k; j++) step[j] = rhs[j * mr];
        double num = step[0] * last[0] + step[1] * last[1], den = last[0] * last[0] + last[1] * last[1];
        double qq = -num / (den > 1e-300 ? den : 1e-300);
        double div = 1.0 + clipd(qq, 0.0, 1.0);
        for (int j = 0; j < k; j++) step[j] /= div;
        step[0] = clipd(step[0], -cap, cap);
        step[1] = clipd(step[1], -cap, cap);
        if (md->fit_smear) {
            step[k - 2] = clipd(step[k - 2], -2.0 * cap, 2.0 * cap);
            step[k - 1] = clipd(step[k - 1], -2.0 * cap, 2.0 * cap);
        }
        for (int c = 0; c < n_w; c++) sig[c] = sqrt(fabs(rhs[watched[c] * mr + 1 + c]));
        int done = 1;
        for (int c = 0; c < n_w; c++) {
            double lim = fraction * sig[c];
            lim = tol_px > lim ? tol_px : lim;
            if (!(fabs(step[watched[c]]) <= lim)) done = 0;
        }
        double dec = 0.0;
        for (int j = 0; j < k; j++) dec += step[j] * g[j];
        if (dec <= converged_chi2) done = 1;
        double trial[NPAR];
        memcpy(trial, p, sizeof(trial));
        for (int j = 0; j < k; j++) trial[free_cols[j]] += step[j];
        double fl = 1e-3 * fabs(p0[PFLUX]) + 1e-12;
        trial[PFLUX] = trial[PFLUX] > fl ? trial[PFLUX] : fl;
        trial[PSIGMA] = clipd(trial[PSIGMA], 0.25, 20.0);
        if (done) {                       /* the last, negligible step: not evaluated again */
            memcpy(p, trial, sizeof(trial));
            return 1;
        }
        star_equations(md, win, trial, wk, t_a, t_g, t_model, t_var);
        double chi_old = residual_chi2(win, t_model, var, P);
        if (chi_old <= chi2 * (1.0 + 1e-9) + 1e-9) {
            for (int j = 0; j < k; j++) last[j] = trial[free_cols[j]] - p[free_cols[j]];
            memcpy(p, trial, sizeof(trial));
            memcpy(a, t_a, sizeof(double) * k * k);
            memcpy(g, t_g, sizeof(double) * k);
            memcpy(model, t_model, sizeof(double) * P);
            memcpy(var, t_var, sizeof(double) * P);
            chi2 = residual_chi2(win, model, var, P);
            lam = lam * 0.1 > 1e-6 ? lam * 0.1 : 1e-6;
        } else {
            lam *= 10.0;
        }
    }
    return 0;
}

static PyObject *py_streak_fit(PyObject *self, PyObject *args) {
    Bufs bs = {.n = 0};
    Py_buffer *p0 = &bs.b[0], *values = &bs.b[1], *valid = &bs.b[2], *x0 = &bs.b[3], *y0 = &bs.b[4],
              *noise = &bs.b[5], *t = &bs.b[6], *w = &bs.b[7], *tab = &bs.b[8], *p_out = &bs.b[9],
              *a_out = &bs.b[10], *model_out = &bs.b[11], *conv_out = &bs.b[12];
    Py_ssize_t N;
    int wy, wx, n, half, steps, fit_smear, max_iterations;
    double inv_gain, tol_px, fraction, converged_chi2;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*w*w*w*w*niiiiiiidddd", p0, values, valid, x0, y0, noise, t, w,
                          tab, p_out, a_out, model_out, conv_out, &N, &wy, &wx, &n, &half, &steps, &fit_smear,
                          &max_iterations, &inv_gain, &tol_px, &fraction, &converged_chi2))
        return NULL;
    bs.n = 13;
    int m = 2 * half + 1, P = wy * wx, k = fit_smear ? 6 : 4;
    size_t tab_len = (size_t)(steps + 1) * m;
    const double *tb = tab->buf;
    Model md = {wy, wx, n, half, steps, fit_smear, t->buf, w->buf, tb, tb + tab_len, tb + 2 * tab_len,
                tb + 3 * tab_len, inv_gain};
    Work wk;
    double *scratch = malloc(sizeof(double) * 3 * (size_t)(P > 0 ? P : 1));
    if (!scratch || work_alloc(&wk, &md)) { free(scratch); bufs_release(&bs); return PyErr_NoMemory(); }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        Win win = {(const double *)values->buf + s * P, (const uint8_t *)valid->buf + s * P,
                   ((const double *)x0->buf)[s], ((const double *)y0->buf)[s], ((const double *)noise->buf)[s]};
        double *p = (double *)p_out->buf + s * NPAR;
        memcpy(p, (const double *)p0->buf + s * NPAR, sizeof(double) * NPAR);
        ((uint8_t *)conv_out->buf)[s] = (uint8_t)fit_one(
            &md, &win, (const double *)p0->buf + s * NPAR, p, &wk, (double *)a_out->buf + s * k * k,
            (double *)model_out->buf + s * P, scratch, max_iterations, tol_px, fraction, converged_chi2);
    }
    Py_END_ALLOW_THREADS
    work_free(&wk);
    free(scratch);
    bufs_release(&bs);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ point sources */

/* Pixel fractions of a pixel-integrated Gaussian along one axis (_fit._profile): size values
 * of E, dE/dcentre and dE/dsigma for pixels first .. first + size - 1. */
static void gauss_profile(double centre, double first, int size, double s, double *e, double *de, double *ds,
                          double *work) {
    const double inv_sqrt2 = 0.70710678118654752440, sqrt2pi = 2.50662827463100050242;
    double *cdf = work, *pdf = work + size + 1, *upd = work + 2 * (size + 1);
    for (int j = 0; j <= size; j++) {
        double u = first - 0.5 + (double)j - centre;
        double z = u / s;
        cdf[j] = 0.5 * erf(z * inv_sqrt2);
        pdf[j] = exp(-0.5 * z * z) / (sqrt2pi * s);
        upd[j] = z * pdf[j];
    }
    for (int j = 0; j < size; j++) {
        e[j] = cdf[j + 1] - cdf[j];
        de[j] = pdf[j] - pdf[j + 1];
        ds[j] = upd[j] - upd[j + 1];
    }
}

/* Normal equations (k = 4, or 5 with sigma) of one point star at q (5,): a (k, k), g (k,). */
static void gauss_equations(const Win *win, int size, const double *q, int fit_sigma, double inv_gain, double *work,
                            double *a, double *g) {
    int k = fit_sigma ? 5 : 4;
    double *ex = work, *dex = ex + size, *dsx = dex + size, *ey = dsx + size, *dey = ey + size, *dsy = dey + size;
    double *tmp = dsy + size;
    gauss_profile(q[0], win->x0, size, q[4], ex, dex, dsx, tmp);
    gauss_profile(q[1], win->y0, size, q[4], ey, dey, dsy, tmp);
    double flux = q[2], bg = q[3], n2 = win->noise * win->noise;
    for (int j = 0; j < k * k; j++) a[j] = 0.0;
    for (int j = 0; j < k; j++) g[j] = 0.0;
    for (int r = 0; r < size; r++) {
        for (int c = 0; c < size; c++) {
            int p = r * size + c;
            double jac[5];
            double shape = ey[r] * ex[c];
            jac[0] = flux * ey[r] * dex[c];
            jac[1] = flux * dey[r] * ex[c];
            jac[2] = shape;
            jac[3] = 1.0;
            if (fit_sigma) jac[4] = flux * (dsy[r] * ex[c] + ey[r] * dsx[c]);
            double model = bg + flux * shape;
            double ex_ = model - bg;
            double v = n2 + (ex_ > 0.0 ? ex_ : 0.0) * inv_gain;
            if (!win->valid[p]) continue;
            double wt = 1.0 / v, res = win->values[p] - model;
            for (int j = 0; j < k; j++) {
                double jw = jac[j] * wt;
                g[j] += jw * res;
                for (int l = 0; l <= j; l++) a[j * k + l] += jw * jac[l];
            }
        }
    }
    for (int j = 0; j < k; j++)
        for (int l = j + 1; l < k; l++) a[j * k + l] = a[l * k + j];
}

/* gauss_fit(p0, values, valid, x0, y0, noise, p_out, step_norm_out, N, size, fit_sigma, inv_gain, tol_px,
 *           tol_chi2, max_iterations): Gauss-Newton fits of _fit.fit_gaussian, star by star. */
static PyObject *py_gauss_fit(PyObject *self, PyObject *args) {
    Bufs bs = {.n = 0};
    Py_buffer *p0 = &bs.b[0], *values = &bs.b[1], *valid = &bs.b[2], *x0 = &bs.b[3], *y0 = &bs.b[4],
              *noise = &bs.b[5], *p_out = &bs.b[6], *norm_out = &bs.b[7];
    Py_ssize_t N;
    int size, fit_sigma, max_iterations;
    double inv_gain, tol_px, tol_chi2;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*w*w*niidddi", p0, values, valid, x0, y0, noise, p_out, norm_out, &N,
                          &size, &fit_sigma, &inv_gain, &tol_px, &tol_chi2, &max_iterations))
        return NULL;
    bs.n = 8;
    double *work = malloc(sizeof(double) * (9 * (size_t)size + 3));
    if (!work) { bufs_release(&bs); return PyErr_NoMemory(); }
    int P = size * size, k = fit_sigma ? 5 : 4;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        Win win = {(const double *)values->buf + s * P, (const uint8_t *)valid->buf + s * P,
                   ((const double *)x0->buf)[s], ((const double *)y0->buf)[s], ((const double *)noise->buf)[s]};
        const double *q0 = (const double *)p0->buf + s * 5;
        double *q = (double *)p_out->buf + s * 5, norm = 0.0;
        memcpy(q, q0, sizeof(double) * 5);
        for (int it = 0; it < max_iterations; it++) {
            double a[25], g[5], step[5];
            gauss_equations(&win, size, q, fit_sigma, inv_gain, work, a, g);
            memcpy(step, g, sizeof(step));
            cho_solve(a, k, step, 1);
            double dec = 0.0;
            for (int j = 0; j < k; j++) dec += step[j] * g[j];
            step[0] = clipd(step[0], -0.5, 0.5);
            step[1] = clipd(step[1], -0.5, 0.5);
            for (int j = 0; j < k; j++) q[j] += step[j];
            double fl = 1e-6 * fabs(q0[2]) + 1e-12;
            q[2] = q[2] > fl ? q[2] : fl;
            q[4] = clipd(q[4], 0.25, 20.0);
            norm = hypot(step[0], step[1]);
            if (!(norm > tol_px && dec > tol_chi2)) break;
        }
        ((double *)norm_out->buf)[s] = norm;
    }
    Py_END_ALLOW_THREADS
    free(work);
    bufs_release(&bs);
    Py_RETURN_NONE;
}

/* gauss_normal(p, values, valid, x0, y0, noise, a_out, N, size, fit_sigma, inv_gain): normal matrices. */
static PyObject *py_gauss_normal(PyObject *self, PyObject *args) {
    Bufs bs = {.n = 0};
    Py_buffer *p = &bs.b[0], *values = &bs.b[1], *valid = &bs.b[2], *x0 = &bs.b[3], *y0 = &bs.b[4],
              *noise = &bs.b[5], *a_out = &bs.b[6], *g_out = &bs.b[7];
    Py_ssize_t N;
    int size, fit_sigma;
    double inv_gain;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*w*w*niid", p, values, valid, x0, y0, noise, a_out, g_out, &N, &size,
                          &fit_sigma, &inv_gain))
        return NULL;
    bs.n = 8;
    double *work = malloc(sizeof(double) * (9 * (size_t)size + 3));
    if (!work) { bufs_release(&bs); return PyErr_NoMemory(); }
    int P = size * size, k = fit_sigma ? 5 : 4;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        Win win = {(const double *)values->buf + s * P, (const uint8_t *)valid->buf + s * P,
                   ((const double *)x0->buf)[s], ((const double *)y0->buf)[s], ((const double *)noise->buf)[s]};
        gauss_equations(&win, size, (const double *)p->buf + s * 5, fit_sigma, inv_gain, work,
                        (double *)a_out->buf + s * k * k, (double *)g_out->buf + s * k);
    }
    Py_END_ALLOW_THREADS
    free(work);
    bufs_release(&bs);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ background mesh */

/* NumPy's pairwise summation of n contiguous doubles (its add.reduce over a contiguous axis,
 * from 0: blocks of up to 128 in 8 partial sums, longer runs halved at a multiple of 8), so
 * that sums over a window are NumPy's to the bit. */
static double pairwise_sum(const double *a, Py_ssize_t n) {
    if (n < 8) {
        double res = 0.0;
        for (Py_ssize_t i = 0; i < n; i++) res += a[i];
        return res;
    }
    if (n <= 128) {
        double r[8];
        for (int j = 0; j < 8; j++) r[j] = a[j];
        Py_ssize_t i;
        for (i = 8; i < n - (n % 8); i += 8)
            for (int j = 0; j < 8; j++) r[j] += a[i + j];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++) res += a[i];
        return res;
    }
    Py_ssize_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise_sum(a, n2) + pairwise_sum(a + n2, n - n2);
}

/* np.maximum: NaN from either side */
static inline double np_maximum(double a, double b) { return (a >= b || isnan(a)) ? a : b; }

static inline double np_clip(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }

static void sort_doubles(double *v, int n) {        /* insertion sort of a few values (the hot-pixel test's 4 edges) */
    for (int i = 1; i < n; i++) {
        double x = v[i];
        int j = i - 1;
        while (j >= 0 && v[j] > x) { v[j + 1] = v[j]; j--; }
        v[j + 1] = x;
    }
}

/* The c-th smallest (from 0) of the deviations of sorted v (n,) from med: those below it,
 * L[t] = med - v[split - 1 - t], and those from it on, R[t] = v[split + t] - med (t = 0, 1, ..:
 * each increasing), as the (c + 1)-th element of their merge, found by bisecting how many of
 * the first c + 1 come from L (the same value as walking the merge: the same differences). */
static double kth_deviation(const double *v, int n, int split, double med, int c) {
    int nl = split, nr = n - split;
    int lo = c + 1 - nr > 0 ? c + 1 - nr : 0, hi = c + 1 < nl ? c + 1 : nl;
    while (lo < hi) {                    /* the smallest x with L[x] >= R[c - x] (x from L) */
        int x = (lo + hi) / 2;           /* here x < nl and 0 <= c - x < nr */
        if (med - v[split - 1 - x] < v[split + c - x] - med) lo = x + 1;
        else hi = x;
    }
    int x = lo;                          /* x from L, c + 1 - x from R */
    double a = x > 0 ? med - v[split - x] : -INFINITY;              /* L[x - 1] */
    double b = c + 1 - x > 0 ? v[split + c - x] - med : -INFINITY;  /* R[c - x] */
    return a > b ? a : b;
}

/* sorted_mad by walking the merge (samples that are not all finite: NaN sorts last, and
 * the bisection's comparisons with it are not the walk's). */
static double sorted_mad_walk(const double *v, int n, double med) {
    int lo = (n - 1) / 2, hi = n / 2, split = 0;
    while (split < n && v[split] < med) split++;
    int i = split - 1, j = split;
    double a = 0.0, b = 0.0;
    for (int c = 0; c <= hi; c++) {
        double d;
        if (i >= 0 && (j >= n || med - v[i] <= v[j] - med)) { d = med - v[i]; i--; }
        else { d = v[j] - med; j++; }
        if (c == lo) a = d;
        if (c == hi) b = d;
    }
    return 0.5 * (a + b);
}

/* The (n-1)/2-th and n/2-th smallest absolute deviations of sorted v (n,) from med: their
 * mean (the walk's numbers, in O(log n) rather than O(n) steps: 118 -> 77 us for a
 * 1024 x 1024 frame's 1024 blocks of 64 samples). */
static double sorted_mad(const double *v, int n, double med) {
    if (n < 1 || !isfinite(v[0]) || !isfinite(v[n - 1]) || !isfinite(med)) return sorted_mad_walk(v, n, med);
    int lo = (n - 1) / 2, hi = n / 2, l = 0, r = n;
    while (l < r) {                      /* split: the first value not below med */
        int m = (l + r) / 2;
        if (v[m] < med) l = m + 1; else r = m;
    }
    double a = kth_deviation(v, n, l, med, lo);
    double b = hi == lo ? a : kth_deviation(v, n, l, med, hi);
    return 0.5 * (a + b);
}

/* block_stats(sorted (B, k) f8, med_out, mad_out, rms_out, B, k, quantum): per block of sorted samples
 * the median, the median absolute deviation from it and the RMS of the deviations within
 * 3 max(1.4826 MAD, quantum) (_background.estimate_mesh before its clipped-RMS factor). */
static PyObject *py_block_stats(PyObject *self, PyObject *args) {
    Py_buffer sb, mb, db, rb;
    Py_ssize_t B;
    int k;
    double quantum;
    if (!PyArg_ParseTuple(args, "y*w*w*w*nid", &sb, &mb, &db, &rb, &B, &k, &quantum)) return NULL;
    const double *samples = sb.buf;
    double *med_out = mb.buf, *mad_out = db.buf, *rms_out = rb.buf;
    Py_BEGIN_ALLOW_THREADS
    int lo = (k - 1) / 2, hi = k / 2;
    for (Py_ssize_t b = 0; b < B; b++) {
        const double *v = samples + b * k;
        double med = 0.5 * (v[lo] + v[hi]);
        double mad = sorted_mad(v, k, med);
        double clip = 1.4826 * mad;
        clip = 3.0 * (clip > quantum ? clip : quantum);
        double sum = 0.0;
        int count = 0;
        for (int i = 0; i < k; i++) {
            double d = v[i] - med;
            if (fabs(d) <= clip) { sum += d * d; count++; }
        }
        med_out[b] = med;
        mad_out[b] = mad;
        rms_out[b] = sqrt(sum / (count > 1 ? count : 1));
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&sb); PyBuffer_Release(&mb); PyBuffer_Release(&db); PyBuffer_Release(&rb);
    Py_RETURN_NONE;
}

/* The median of 9 values (v reordered): the exchange network of Paeth / Devillard's opt_med9 (19
 * compare-exchanges), the value the sort's middle element would be (no NaN in the mesh). */
#define CX(a, b) { if (v[a] > v[b]) { double t_ = v[a]; v[a] = v[b]; v[b] = t_; } }
static double median9(double *v) {
    CX(1, 2) CX(4, 5) CX(7, 8) CX(0, 1) CX(3, 4) CX(6, 7) CX(1, 2) CX(4, 5) CX(7, 8)
    CX(0, 3) CX(5, 8) CX(4, 7) CX(3, 6) CX(1, 4) CX(2, 5) CX(4, 7) CX(4, 2) CX(6, 4) CX(4, 2)
    return v[4];
}
#undef CX

/* median3(grid (ny, nx) f8, out, ny, nx): 3 x 3 median, edges extended. */
static PyObject *py_median3(PyObject *self, PyObject *args) {
    Py_buffer gb, ob;
    Py_ssize_t ny, nx;
    if (!PyArg_ParseTuple(args, "y*w*nn", &gb, &ob, &ny, &nx)) return NULL;
    const double *g = gb.buf;
    double *out = ob.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < ny; r++) {
        for (Py_ssize_t c = 0; c < nx; c++) {
            double v[9];
            int n = 0;
            for (int dr = -1; dr <= 1; dr++) {
                Py_ssize_t rr = r + dr < 0 ? 0 : (r + dr >= ny ? ny - 1 : r + dr);
                for (int dc = -1; dc <= 1; dc++) {
                    Py_ssize_t cc = c + dc < 0 ? 0 : (c + dc >= nx ? nx - 1 : c + dc);
                    v[n++] = g[rr * nx + cc];
                }
            }
            out[r * nx + c] = median9(v);
        }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&gb); PyBuffer_Release(&ob);
    Py_RETURN_NONE;
}

/* The weights of one axis of the mesh's bilinear values between block centres. */
static void mesh_weights(double coord, double block, Py_ssize_t nb, Py_ssize_t *i0, Py_ssize_t *i1, double *f) {
    double g = (coord - (block - 1.0) / 2.0) / block;
    g = clipd(g, 0.0, (double)nb - 1.0);
    Py_ssize_t top = nb - 2 > 0 ? nb - 2 : 0;
    Py_ssize_t i = (Py_ssize_t)floor(g);
    if (i > top) i = top;
    *i0 = i;
    *i1 = i + 1 < nb - 1 ? i + 1 : nb - 1;
    *f = g - (double)i;
}

/* Bilinear bg and noise at pixel (x, y) (Mesh.at's arithmetic). */
static void mesh_pair_at(const double *bg, const double *noise, Py_ssize_t ny, Py_ssize_t nx, double block, double x,
                         double y, double *b_out, double *n_out) {
    Py_ssize_t x0, x1, y0, y1;
    double fx, fy;
    mesh_weights(x, block, nx, &x0, &x1, &fx);
    mesh_weights(y, block, ny, &y0, &y1, &fy);
    const double *grids[2] = {bg, noise};
    double out[2];
    for (int q = 0; q < 2; q++) {
        const double *g = grids[q];
        double top = g[y0 * nx + x0] * (1 - fx) + g[y0 * nx + x1] * fx;
        double bottom = g[y1 * nx + x0] * (1 - fx) + g[y1 * nx + x1] * fx;
        out[q] = top * (1 - fy) + bottom * fy;
    }
    *b_out = out[0];
    *n_out = out[1];
}

/* mesh_at(bg, noise (ny, nx), x, y (n,), bg_out, noise_out, ny, nx, n, block): bilinear values
 * between block centres (_background.Mesh.at, the same operations in the same order). */
static PyObject *py_mesh_at(PyObject *self, PyObject *args) {
    Py_buffer bb, nb_, xb, yb, ob, pb;
    Py_ssize_t ny, nx, n;
    double block;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*w*nnnd", &bb, &nb_, &xb, &yb, &ob, &pb, &ny, &nx, &n, &block))
        return NULL;
    const double *grids[2] = {bb.buf, nb_.buf}, *x = xb.buf, *y = yb.buf;
    double *outs[2] = {ob.buf, pb.buf};
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++)
        mesh_pair_at(grids[0], grids[1], ny, nx, block, x[i], y[i], &outs[0][i], &outs[1][i]);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&bb); PyBuffer_Release(&nb_); PyBuffer_Release(&xb); PyBuffer_Release(&yb);
    PyBuffer_Release(&ob); PyBuffer_Release(&pb);
    Py_RETURN_NONE;
}

/* The pixel loops (the line filter's, the candidates' threshold) are compiled twice, for AVX2
 * and for the baseline x86-64 (SSE2), and the loader picks one for the machine (GCC's
 * target_clones, an ifunc): 8 floats or 16 integers an instruction where the CPU has it.  The
 * same IEEE operations in the same order either way (no FMA: nothing is contracted), so the
 * results are the same bits. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && defined(__GLIBC__)
#define PIXEL_LOOP_CLONES __attribute__((noinline, target_clones("avx2", "default")))   /* (ifunc: glibc, not musl) */
#else
#define PIXEL_LOOP_CLONES __attribute__((noinline))
#endif

/* ------------------------------------------------------------------ detection on candidate pixels */

/* The flat indices of row r's candidates from its byte mask (w bytes of 0 or 1 and 8 zeros after
 * them), in increasing order, appended to out[n..]; returns the new n. */
static Py_ssize_t scan_mask(const uint8_t *mask, Py_ssize_t r, Py_ssize_t w, int64_t *out, Py_ssize_t n) {
    for (Py_ssize_t c = 0; c < w; c += 8) {
        uint64_t word;
        memcpy(&word, mask + c, 8);
        if (!word) continue;
#if defined(__GNUC__) && defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
        /* bytes of 0 or 1: each set bit is a candidate, byte j at bit 8 j (the 8 zeros after
           the row end the last word); one step a candidate, not a guessed branch a byte */
        do {
            out[n++] = r * w + c + (__builtin_ctzll(word) >> 3);
            word &= word - 1;
        } while (word);
#else
        for (Py_ssize_t j = c; j < c + 8 && j < w; j++)
            if (mask[j]) out[n++] = r * w + j;
#endif
    }
    return n;
}

/* One function per pixel type T (image and block levels of the same type, as
 * _detect._level_as gives them): candidates, local maxima, 3 x 3 neighbours. */
#define DETECT_KERNELS(SUF, T)                                                                          \
    /* mask[c] = row[c] > thr[c], and whether any is: a branch-free loop of its own, which the        \
       compiler vectorises (the row's mask is scanned only when it holds a candidate: most rows hold   \
       none, and scanning every row's mask was ~half the kernel's time) */                              \
    static PIXEL_LOOP_CLONES int above_##SUF(const T *restrict row, const T *restrict thr,              \
                                             uint8_t *restrict mask, Py_ssize_t n) {                    \
        uint8_t any = 0;                                                                                \
        for (Py_ssize_t j = 0; j < n; j++) {                                                            \
            const uint8_t m = row[j] > thr[j];                                                          \
            mask[j] = m;                                                                                \
            any |= m;                                                                                   \
        }                                                                                               \
        return any;                                                                                     \
    }                                                                                                   \
    /* Row by row: each pixel against its block's level (the row of levels expanded once per block     \
       row), into a byte mask read 8 bytes at a time; most words hold no candidate. */                 \
    static Py_ssize_t candidates_##SUF(const T *img, const T *level, int64_t *out, Py_ssize_t h,      \
                                       Py_ssize_t w, Py_ssize_t block, Py_ssize_t nby, Py_ssize_t nbx, \
                                       T *thr, uint8_t *mask) {                                         \
        Py_ssize_t n = 0, band = -1;                                                                    \
        for (Py_ssize_t j = w; j < w + 8; j++) mask[j] = 0;                                             \
        for (Py_ssize_t r = 0; r < h; r++) {                                                            \
            Py_ssize_t br = r / block < nby - 1 ? r / block : nby - 1;                                  \
            if (br != band) {   /* block by block: no division a pixel */                               \
                for (Py_ssize_t b = 0; b < nbx; b++) {                                                  \
                    const Py_ssize_t c1 = b == nbx - 1 || (b + 1) * block > w ? w : (b + 1) * block;    \
                    const T v = level[br * nbx + b];                                                    \
                    for (Py_ssize_t c = b * block; c < c1; c++) thr[c] = v;                             \
                }                                                                                       \
                band = br;                                                                              \
            }                                                                                           \
            if (above_##SUF(img + r * w, thr, mask, w)) n = scan_mask(mask, r, w, out, n);              \
        }                                                                                               \
        return n;                                                                                       \
    }                                                                                                   \
    static void local_max_##SUF(const T *img, const int64_t *idx, uint8_t *keep, Py_ssize_t k,         \
                                Py_ssize_t h, Py_ssize_t w) {                                           \
        for (Py_ssize_t i = 0; i < k; i++) {                                                            \
            int64_t p = idx[i];                                                                         \
            Py_ssize_t r = p / w, c = p - r * w;                                                        \
            T v = img[p];                                                                               \
            int ok = 1;                                                                                 \
            for (int dr = -1; dr <= 1 && ok; dr++) {                                                    \
                if (r + dr < 0 || r + dr >= h) continue;                                                \
                for (int dc = -1; dc <= 1; dc++) {                                                      \
                    if ((dr == 0 && dc == 0) || c + dc < 0 || c + dc >= w) continue;                    \
                    T u = img[p + dr * w + dc];                                                         \
                    if (dr * w + dc < 0 ? !(v > u) : !(v >= u)) { ok = 0; break; }                      \
                }                                                                                       \
            }                                                                                           \
            keep[i] = (uint8_t)ok;                                                                      \
        }                                                                                               \
    }                                                                                                   \
    static void neighbours_##SUF(const T *img, const int64_t *peaks, double *values, uint8_t *inside,  \
                                 Py_ssize_t k, Py_ssize_t h, Py_ssize_t w) {                            \
        static const int off[8][2] = {{-1, -1}, {-1, 0}, {-1, 1}, {0, -1}, {0, 1}, {1, -1}, {1, 0}, {1, 1}}; \
        for (Py_ssize_t i = 0; i < k; i++) {                                                            \
            int64_t p = peaks[i];                                                                       \
            Py_ssize_t r = p / w, c = p - r * w;                                                        \
            for (int j = 0; j < 8; j++) {                                                               \
                int in = r + off[j][0] >= 0 && r + off[j][0] < h && c + off[j][1] >= 0 && c + off[j][1] < w; \
                inside[i * 8 + j] = (uint8_t)in;                                                        \
                values[i * 8 + j] = (double)img[in ? p + off[j][0] * w + off[j][1] : p];                \
            }                                                                                           \
        }                                                                                               \
    }

DETECT_KERNELS(u8, uint8_t)
DETECT_KERNELS(i8, int8_t)
DETECT_KERNELS(u16, uint16_t)
DETECT_KERNELS(i16, int16_t)
DETECT_KERNELS(u32, uint32_t)
DETECT_KERNELS(i32, int32_t)
DETECT_KERNELS(u64, uint64_t)
DETECT_KERNELS(i64, int64_t)
DETECT_KERNELS(f32, float)
DETECT_KERNELS(f64, double)

/* type codes: the NumPy dtype's kind and item size, as "u2", "f4", ... */
static int type_index(const char *code) {
    static const char *codes[] = {"u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f4", "f8"};
    for (int i = 0; i < 10; i++)
        if (strcmp(code, codes[i]) == 0) return i;
    PyErr_Format(PyExc_TypeError, "no detection kernel for pixel type %s", code);
    return -1;
}

#define DISPATCH(I, CALL_U8, ...)                                                                      \
    switch (I) {                                                                                        \
    case 0: CALL_U8(u8, uint8_t); break;                                                                \
    case 1: CALL_U8(i8, int8_t); break;                                                                 \
    case 2: CALL_U8(u16, uint16_t); break;                                                              \
    case 3: CALL_U8(i16, int16_t); break;                                                               \
    case 4: CALL_U8(u32, uint32_t); break;                                                              \
    case 5: CALL_U8(i32, int32_t); break;                                                               \
    case 6: CALL_U8(u64, uint64_t); break;                                                              \
    case 7: CALL_U8(i64, int64_t); break;                                                               \
    case 8: CALL_U8(f32, float); break;                                                                 \
    default: CALL_U8(f64, double); break;                                                               \
    }

/* gather(image, values_out (N, 2 hy + 1, 2 hx + 1) f8, valid_out u8, col, row (N,) i8, bad (H, W) u8, H, W, N,
 *        hx, hy, has_bad, type): the windows centred on (col, row), their pixels as float64 (the
 * nearest pixel of the image where off it), valid where on the image and not ``bad``
 * (_streak.gather_streak_windows, _fit.gather_windows). */
#define GATHER(SUF, T)                                                                                  \
    static void gather_##SUF(const T *img, double *values, uint8_t *valid, const int64_t *col,          \
                             const int64_t *row, const uint8_t *bad, Py_ssize_t h, Py_ssize_t w,      \
                             Py_ssize_t n, Py_ssize_t hx, Py_ssize_t hy) {                              \
        Py_ssize_t wy = 2 * hy + 1, wx = 2 * hx + 1;                                                    \
        for (Py_ssize_t s = 0; s < n; s++) {                                                            \
            double *v = values + s * wy * wx;                                                           \
            uint8_t *k = valid + s * wy * wx;                                                           \
            for (Py_ssize_t i = 0; i < wy; i++) {                                                       \
                Py_ssize_t r = row[s] - hy + i;                                                         \
                int row_in = r >= 0 && r < h;                                                           \
                Py_ssize_t rc = r < 0 ? 0 : (r >= h ? h - 1 : r);                                       \
                for (Py_ssize_t j = 0; j < wx; j++) {                                                   \
                    Py_ssize_t c = col[s] - hx + j;                                                     \
                    Py_ssize_t cc = c < 0 ? 0 : (c >= w ? w - 1 : c);                                   \
                    Py_ssize_t q = rc * w + cc;                                                         \
                    v[i * wx + j] = (double)img[q];                                                     \
                    k[i * wx + j] = row_in && c >= 0 && c < w && !(bad && bad[q]);                      \
                }                                                                                       \
            }                                                                                           \
        }                                                                                               \
    }
GATHER(u8, uint8_t)
GATHER(i8, int8_t)
GATHER(u16, uint16_t)
GATHER(i16, int16_t)
GATHER(u32, uint32_t)
GATHER(i32, int32_t)
GATHER(u64, uint64_t)
GATHER(i64, int64_t)
GATHER(f32, float)
GATHER(f64, double)

static PyObject *py_gather(PyObject *self, PyObject *args) {
    Py_buffer ib, vb, kb, cb, rb, bb;
    Py_ssize_t h, w, n, hx, hy;
    int has_bad;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*w*w*y*y*y*nnnnnps", &ib, &vb, &kb, &cb, &rb, &bb, &h, &w, &n, &hx, &hy,
                          &has_bad, &code))
        return NULL;
    int t = type_index(code);
    Py_ssize_t cells = n * (2 * hy + 1) * (2 * hx + 1);
    int ok = t >= 0 && h >= 1 && w >= 1 && n >= 0 && hx >= 0 && hy >= 0
             && vb.len == (Py_ssize_t)(cells * sizeof(double)) && kb.len == cells
             && cb.len == (Py_ssize_t)(n * sizeof(int64_t)) && rb.len == cb.len && (!has_bad || bb.len == h * w);
    if (ok) {
        const uint8_t *bad = has_bad ? (const uint8_t *)bb.buf : NULL;
        Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) gather_##SUF((const T *)ib.buf, (double *)vb.buf, (uint8_t *)kb.buf, (const int64_t *)cb.buf, \
                                  (const int64_t *)rb.buf, bad, h, w, n, hx, hy)
        DISPATCH(t, CALL)
#undef CALL
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&ib); PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&cb);
    PyBuffer_Release(&rb); PyBuffer_Release(&bb);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "gather: bad sizes");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* grid_box_sums(image, out (nr, nc) f8, H, W, step, nr, nc, type): out[i, j] = the 3 x 3 sum
 * around pixel (1 + step i, 1 + step j), in float64 from 0, row by row (dr = -1, 0, 1), each
 * row left to right: _background._box_noise_factor's nine strided slices added in their
 * order, the same sums. */
#define GRID_BOX_SUMS(SUF, T)                                                                           \
    static void grid_box_sums_##SUF(const T *img, double *out, Py_ssize_t w, Py_ssize_t step,            \
                                    Py_ssize_t nr, Py_ssize_t nc) {                                     \
        for (Py_ssize_t i = 0; i < nr; i++) {                                                           \
            const T *c0 = img + (1 + step * i) * w + 1;                                                 \
            for (Py_ssize_t j = 0; j < nc; j++) {                                                       \
                const T *c = c0 + step * j;                                                             \
                double t = 0.0;                                                                         \
                for (int dr = -1; dr <= 1; dr++)                                                        \
                    for (int dc = -1; dc <= 1; dc++) t += (double)c[dr * w + dc];                       \
                out[i * nc + j] = t;                                                                    \
            }                                                                                           \
        }                                                                                               \
    }
GRID_BOX_SUMS(u8, uint8_t)
GRID_BOX_SUMS(i8, int8_t)
GRID_BOX_SUMS(u16, uint16_t)
GRID_BOX_SUMS(i16, int16_t)
GRID_BOX_SUMS(u32, uint32_t)
GRID_BOX_SUMS(i32, int32_t)
GRID_BOX_SUMS(u64, uint64_t)
GRID_BOX_SUMS(i64, int64_t)
GRID_BOX_SUMS(f32, float)
GRID_BOX_SUMS(f64, double)

static PyObject *py_grid_box_sums(PyObject *self, PyObject *args) {
    Py_buffer ib, ob;
    Py_ssize_t h, w, step, nr, nc;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*w*nnnnns", &ib, &ob, &h, &w, &step, &nr, &nc, &code)) return NULL;
    int t = type_index(code);
    int ok = t >= 0 && step >= 1 && nr >= 0 && nc >= 0 && ob.len == (Py_ssize_t)(nr * nc * sizeof(double))
             && (nr == 0 || 1 + step * (nr - 1) + 1 < h) && (nc == 0 || 1 + step * (nc - 1) + 1 < w);
    if (ok) {
        Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) grid_box_sums_##SUF((const T *)ib.buf, (double *)ob.buf, w, step, nr, nc)
        DISPATCH(t, CALL)
#undef CALL
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&ib); PyBuffer_Release(&ob);
    if (!ok) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "grid_box_sums: bad sizes");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* value_step(samples (n, k) f8 sorted along rows, n, k) -> the smallest positive difference of
 * consecutive samples in a row (0.0 when none): _background._value_step. */
static PyObject *py_value_step(PyObject *self, PyObject *args) {
    Py_buffer sb;
    Py_ssize_t n, k;
    if (!PyArg_ParseTuple(args, "y*nn", &sb, &n, &k)) return NULL;
    if (n < 0 || k < 0 || sb.len != (Py_ssize_t)(n * k * sizeof(double))) {
        PyBuffer_Release(&sb);
        PyErr_SetString(PyExc_ValueError, "value_step: bad sizes");
        return NULL;
    }
    const double *s = sb.buf;
    double best = INFINITY;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < n; r++)
        for (Py_ssize_t i = 0; i + 1 < k; i++) {
            double d = s[r * k + i + 1] - s[r * k + i];
            if (d > 0.0 && d < best) best = d;
        }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&sb);
    return PyFloat_FromDouble(isinf(best) ? 0.0 : best);
}

/* candidates(image, levels (nby, nbx), out_idx (H W,) i8, H, W, block, nby, nbx, type) -> count */
static PyObject *py_candidates(PyObject *self, PyObject *args) {
    Py_buffer ib, lb, ob;
    Py_ssize_t h, w, block, nby, nbx, n = 0;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*y*w*nnnnns", &ib, &lb, &ob, &h, &w, &block, &nby, &nbx, &code)) return NULL;
    int t = type_index(code);
    void *thr = NULL;
    uint8_t *mask = NULL;
    if (t >= 0) {
        thr = malloc((size_t)(w > 0 ? w : 1) * 8);          /* a row of levels (items of <= 8 bytes) */
        mask = malloc((size_t)w + 8);
        if (thr == NULL || mask == NULL) {
            PyErr_NoMemory();
            t = -1;
        }
    }
    if (t >= 0) {
        Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) n = candidates_##SUF((const T *)ib.buf, (const T *)lb.buf, (int64_t *)ob.buf, h, w, block, nby, nbx, \
                                          (T *)thr, mask)
        DISPATCH(t, CALL)
#undef CALL
        Py_END_ALLOW_THREADS
    }
    free(thr);
    free(mask);
    PyBuffer_Release(&ib); PyBuffer_Release(&lb); PyBuffer_Release(&ob);
    if (t < 0) return NULL;
    return PyLong_FromSsize_t(n);
}

/* local_max(image, idx (K,) i8, keep_out (K,) u1, K, H, W, type) */
static PyObject *py_local_max(PyObject *self, PyObject *args) {
    Py_buffer ib, xb, kb;
    Py_ssize_t k, h, w;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*y*w*nnns", &ib, &xb, &kb, &k, &h, &w, &code)) return NULL;
    int t = type_index(code);
    if (t >= 0) {
        Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) local_max_##SUF((const T *)ib.buf, (const int64_t *)xb.buf, (uint8_t *)kb.buf, k, h, w)
        DISPATCH(t, CALL)
#undef CALL
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&ib); PyBuffer_Release(&xb); PyBuffer_Release(&kb);
    if (t < 0) return NULL;
    Py_RETURN_NONE;
}

/* neighbours(image, peaks (N,) i8, values_out (N, 8) f8, inside_out (N, 8) u1, N, H, W, type) */
static PyObject *py_neighbours(PyObject *self, PyObject *args) {
    Py_buffer ib, pb, vb, nb;
    Py_ssize_t k, h, w;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*y*w*w*nnns", &ib, &pb, &vb, &nb, &k, &h, &w, &code)) return NULL;
    int t = type_index(code);
    if (t >= 0) {
        Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) neighbours_##SUF((const T *)ib.buf, (const int64_t *)pb.buf, (double *)vb.buf, (uint8_t *)nb.buf, k, h, w)
        DISPATCH(t, CALL)
#undef CALL
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&ib); PyBuffer_Release(&pb); PyBuffer_Release(&vb); PyBuffer_Release(&nb);
    if (t < 0) return NULL;
    Py_RETURN_NONE;
}

/* box_sums(image, peaks (K,) i8, total_out (K,) f8, count_out (K,) f8, K, H, W, type): the 3 x 3 box of
 * each peak: its value plus the sum of its neighbours on the image (NumPy's pairwise order over the 8,
 * off-image ones 0), and 1 + how many are on it (_detect.box_sums, bit for bit). */
static PyObject *py_box_sums(PyObject *self, PyObject *args) {
    Py_buffer ib, pb, tb, cb;
    Py_ssize_t k, h, w;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*y*w*w*nnns", &ib, &pb, &tb, &cb, &k, &h, &w, &code)) return NULL;
    int t = type_index(code);
    int ok = t >= 0 && k >= 0 && pb.len == (Py_ssize_t)(k * sizeof(int64_t))
             && tb.len == (Py_ssize_t)(k * sizeof(double)) && cb.len == tb.len;
    double *values = ok ? malloc(sizeof(double) * (size_t)(8 * k + 1)) : NULL;
    uint8_t *inside = ok ? malloc((size_t)(8 * k + 1)) : NULL;
    if (!ok || !values || !inside) {
        free(values); free(inside);
        PyBuffer_Release(&ib); PyBuffer_Release(&pb); PyBuffer_Release(&tb); PyBuffer_Release(&cb);
        if (!ok) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "box_sums: bad sizes"); }
        else PyErr_NoMemory();
        return NULL;
    }
    const int64_t *peaks = pb.buf;
    double *total = tb.buf, *count = cb.buf;
    Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) neighbours_##SUF((const T *)ib.buf, peaks, values, inside, k, h, w)
    DISPATCH(t, CALL)
#undef CALL
    for (Py_ssize_t i = 0; i < k; i++) {
        double e[8];
        int n_in = 0;
        for (int j = 0; j < 8; j++) {
            e[j] = inside[8 * i + j] ? values[8 * i + j] : 0.0;
            n_in += inside[8 * i + j];
        }
        double centre;
#define CENTRE(SUF, T) centre = (double)((const T *)ib.buf)[peaks[i]]
        DISPATCH(t, CENTRE)
#undef CENTRE
        total[i] = centre + (0.0 + pairwise_sum(e, 8));
        count[i] = 1.0 + (double)n_in;
    }
    Py_END_ALLOW_THREADS
    free(values); free(inside);
    PyBuffer_Release(&ib); PyBuffer_Release(&pb); PyBuffer_Release(&tb); PyBuffer_Release(&cb);
    Py_RETURN_NONE;
}

/* too_sharp(image, peaks (K,) i8, bg, noise (K,) f8, saturated (K,) u8, out (K,) u8, K, H, W, inv_gain,
 *           ratio_total, ratio_total2, ratio_edges, ratio_edges2, n_sigma, type): _point.too_sharp's
 * two one-sided tests of each peak against its neighbours (the 8 neighbours' excess, summed in
 * NumPy's pairwise order, and the two faintest edge neighbours'), ``noise`` already times the
 * box-noise factor, the ratios squared by the caller (Python's ``**``), a saturated peak never. */
static PyObject *py_too_sharp(PyObject *self, PyObject *args) {
    Py_buffer ib, pb, bb, nb_, sb, ob;
    Py_ssize_t k, h, w;
    double inv_gain, rt, rt2, re, re2, n_sigma;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*nnndddddds", &ib, &pb, &bb, &nb_, &sb, &ob, &k, &h, &w, &inv_gain,
                          &rt, &rt2, &re, &re2, &n_sigma, &code))
        return NULL;
    int t = type_index(code);
    int ok = t >= 0 && k >= 0 && pb.len == (Py_ssize_t)(k * sizeof(int64_t))
             && bb.len == (Py_ssize_t)(k * sizeof(double)) && nb_.len == bb.len && sb.len == k && ob.len == k;
    double *values = ok ? malloc(sizeof(double) * (size_t)(8 * k + 1)) : NULL;
    uint8_t *inside = ok ? malloc((size_t)(8 * k + 1)) : NULL;
    if (!ok || !values || !inside) {
        free(values); free(inside);
        PyBuffer_Release(&ib); PyBuffer_Release(&pb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_);
        PyBuffer_Release(&sb); PyBuffer_Release(&ob);
        if (!ok) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "too_sharp: bad sizes"); }
        else PyErr_NoMemory();
        return NULL;
    }
    const int64_t *peaks = pb.buf;
    const double *bg = bb.buf, *noise = nb_.buf;
    const uint8_t *saturated = sb.buf;
    uint8_t *out = ob.buf;
    static const int edge[4] = {1, 3, 4, 6};          /* (-1, 0), (0, -1), (0, 1), (1, 0) */
    Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) neighbours_##SUF((const T *)ib.buf, peaks, values, inside, k, h, w)
    DISPATCH(t, CALL)
#undef CALL
    for (Py_ssize_t i = 0; i < k; i++) {
        double centre;
#define CENTRE(SUF, T) centre = (double)((const T *)ib.buf)[peaks[i]]
        DISPATCH(t, CENTRE)
#undef CENTRE
        double peak = centre - bg[i], nz = noise[i], nz2 = nz * nz;
        double excess[8];
        int n_in = 0;
        for (int j = 0; j < 8; j++) {
            excess[j] = inside[8 * i + j] ? values[8 * i + j] - bg[i] : 0.0;
            n_in += inside[8 * i + j];
        }
        double e[4];                                   /* the edge neighbours, INFINITY off the image */
        for (int j = 0; j < 4; j++) e[j] = inside[8 * i + edge[j]] ? excess[edge[j]] : INFINITY;
        sort_doubles(e, 4);
        double e0 = isfinite(e[0]) ? e[0] : 0.0, e1 = isfinite(e[1]) ? e[1] : 0.0;
        double var_peak = nz2 + np_maximum(peak, 0.0) * inv_gain;
        double part_total = 0.0 + pairwise_sum(excess, 8), part_edges = (0.0 + e0) + e1;
        double var_total = rt2 * var_peak + (double)n_in * nz2 + np_maximum(part_total, 0.0) * inv_gain;
        double var_edges = re2 * var_peak + 2.0 * nz2 + np_maximum(part_edges, 0.0) * inv_gain;
        int sharp = (rt * peak - part_total > n_sigma * sqrt(var_total))
                    | (re * peak - part_edges > n_sigma * sqrt(var_edges));
        out[i] = (uint8_t)(sharp && !saturated[i]);
    }
    Py_END_ALLOW_THREADS
    free(values); free(inside);
    PyBuffer_Release(&ib); PyBuffer_Release(&pb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_);
    PyBuffer_Release(&sb); PyBuffer_Release(&ob);
    Py_RETURN_NONE;
}

/* component_stats(image, pix (M,) i8, who (M,) i8, bg (M,) f8, npix_out (n,) i8, peak_out, flux_out, cx_out,
 *                 cy_out, mxx_out, myy_out, mxy_out (n,) f8, flags_out (n,) i8, M, n, H, W, saturation,
 *                 elongation2, flag_sat, flag_edge, flag_elong, type): _point.component_stats's
 * per-star sums over its pixels (weights max(value - bg, 1e-12)), each added in the pixels'
 * order from 0 as np.bincount adds them. */
static PyObject *py_component_stats(PyObject *self, PyObject *args) {
    Bufs bs = {.n = 0};
    Py_buffer *ib = &bs.b[0], *pb = &bs.b[1], *wb = &bs.b[2], *bb = &bs.b[3], *o_npix = &bs.b[4], *o_peak = &bs.b[5],
              *o_flux = &bs.b[6], *o_cx = &bs.b[7], *o_cy = &bs.b[8], *o_xx = &bs.b[9], *o_yy = &bs.b[10],
              *o_xy = &bs.b[11], *o_flags = &bs.b[12];
    Py_ssize_t M, n, h, w;
    double saturation, elong2;
    long long f_sat, f_edge, f_elong;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*w*w*w*w*w*w*w*w*nnnnddLLLs", ib, pb, wb, bb, o_npix, o_peak, o_flux, o_cx,
                          o_cy, o_xx, o_yy, o_xy, o_flags, &M, &n, &h, &w, &saturation, &elong2, &f_sat, &f_edge,
                          &f_elong, &code))
        return NULL;
    bs.n = 13;
    int t = type_index(code);
    size_t dn = (size_t)n * sizeof(double);
    int ok = t >= 0 && M >= 0 && n >= 0 && pb->len == (Py_ssize_t)(M * sizeof(int64_t)) && wb->len == pb->len
             && bb->len == (Py_ssize_t)(M * sizeof(double)) && o_npix->len == (Py_ssize_t)(n * sizeof(int64_t))
             && o_flags->len == o_npix->len && o_peak->len == (Py_ssize_t)dn && o_flux->len == (Py_ssize_t)dn
             && o_cx->len == (Py_ssize_t)dn && o_cy->len == (Py_ssize_t)dn && o_xx->len == (Py_ssize_t)dn
             && o_yy->len == (Py_ssize_t)dn && o_xy->len == (Py_ssize_t)dn;
    const int64_t *who = wb->buf;
    for (Py_ssize_t i = 0; ok && i < M; i++) ok = who[i] >= 0 && who[i] < n;
    double *val = ok ? malloc(sizeof(double) * (size_t)(M + 1)) : NULL;
    double *wt = ok ? malloc(sizeof(double) * (size_t)(M + 1)) : NULL;
    double *s1 = ok ? malloc(dn + 8) : NULL, *s2 = ok ? malloc(dn + 8) : NULL;
    uint8_t *sat = ok ? calloc((size_t)n + 1, 1) : NULL, *edge = ok ? calloc((size_t)n + 1, 1) : NULL;
    if (!ok || !val || !wt || !s1 || !s2 || !sat || !edge) {
        free(val); free(wt); free(s1); free(s2); free(sat); free(edge);
        bufs_release(&bs);
        if (!ok) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "component_stats: bad sizes"); }
        else PyErr_NoMemory();
        return NULL;
    }
    const int64_t *pix = pb->buf;
    const double *bg = bb->buf;
    int64_t *npix = o_npix->buf, *flags = o_flags->buf;
    double *peak = o_peak->buf, *s0 = o_flux->buf, *cx = o_cx->buf, *cy = o_cy->buf, *mxx = o_xx->buf,
           *myy = o_yy->buf, *mxy = o_xy->buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < n; s++) {
        npix[s] = 0; peak[s] = -INFINITY; s0[s] = 0.0; s1[s] = 0.0; s2[s] = 0.0;
        mxx[s] = 0.0; myy[s] = 0.0; mxy[s] = 0.0;
    }
    for (Py_ssize_t i = 0; i < M; i++) {
#define VALUE(SUF, T) val[i] = (double)((const T *)ib->buf)[pix[i]]
        DISPATCH(t, VALUE)
#undef VALUE
    }
    for (Py_ssize_t i = 0; i < M; i++) {
        Py_ssize_t s = who[i], r = pix[i] / w, c = pix[i] - r * w;
        double wq = np_maximum(val[i] - bg[i], 1e-12);
        wt[i] = wq;
        s0[s] += wq;
        s1[s] += wq * (double)c;
        s2[s] += wq * (double)r;
        npix[s] += 1;
        peak[s] = np_maximum(peak[s], val[i]);
        if (val[i] >= saturation) sat[s] = 1;
        if (r == 0 || r == h - 1 || c == 0 || c == w - 1) edge[s] = 1;
    }
    for (Py_ssize_t s = 0; s < n; s++) {
        cx[s] = s1[s] / s0[s];
        cy[s] = s2[s] / s0[s];
    }
    for (Py_ssize_t i = 0; i < M; i++) {
        Py_ssize_t s = who[i], r = pix[i] / w, c = pix[i] - r * w;
        double dx = (double)c - cx[s], dy = (double)r - cy[s];
        mxx[s] += wt[i] * (dx * dx);
        myy[s] += wt[i] * (dy * dy);
        mxy[s] += wt[i] * (dx * dy);
    }
    for (Py_ssize_t s = 0; s < n; s++) {
        mxx[s] /= s0[s];
        myy[s] /= s0[s];
        mxy[s] /= s0[s];
        double half_diff = (mxx[s] - myy[s]) / 2.0, mean = (mxx[s] + myy[s]) / 2.0;
        double root = sqrt(half_diff * half_diff + mxy[s] * mxy[s]);
        double major = mean + root, minor = np_maximum(mean - root, 1e-12);
        int64_t f = sat[s] ? f_sat : 0;
        if (edge[s]) f |= f_edge;
        if (npix[s] >= 9 && major > elong2 * minor) f |= f_elong;
        flags[s] = f;
    }
    Py_END_ALLOW_THREADS
    free(val); free(wt); free(s1); free(s2); free(sat); free(edge);
    bufs_release(&bs);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ line filter */

/* tap_sum(src0, src1, src2, terms (T, 2) i8 [source, shift], out, span, T, double?): out[i] = sum over
 * the terms, in their order, of src[source][shift + i], i < span (float32 or float64 sources): the
 * passes of _matched.line_filter done tile by tile (the tile stays in the cache; same sums). */
#define TAP_SUM(T_)                                                                                     \
    static void tap_sum_##T_(const T_ *const *src, const int64_t *terms, T_ *out, Py_ssize_t span,      \
                             Py_ssize_t n_terms) {                                                      \
        const Py_ssize_t tile = 2048;                                                                   \
        for (Py_ssize_t i0 = 0; i0 < span; i0 += tile) {                                                \
            Py_ssize_t n = span - i0 < tile ? span - i0 : tile;                                         \
            T_ *o = out + i0;                                                                           \
            const T_ *a = src[terms[0]] + terms[1] + i0;                                                \
            for (Py_ssize_t i = 0; i < n; i++) o[i] = a[i];                                             \
            for (Py_ssize_t t = 1; t < n_terms; t++) {                                                  \
                const T_ *b = src[terms[2 * t]] + terms[2 * t + 1] + i0;                               \
                for (Py_ssize_t i = 0; i < n; i++) o[i] += b[i];                                        \
            }                                                                                           \
        }                                                                                               \
    }
TAP_SUM(float)
TAP_SUM(double)

static PyObject *py_tap_sum(PyObject *self, PyObject *args) {
    Py_buffer b0, b1, b2, tb, ob;
    Py_ssize_t span, n_terms;
    int is_double;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*nnp", &b0, &b1, &b2, &tb, &ob, &span, &n_terms, &is_double)) return NULL;
    Py_BEGIN_ALLOW_THREADS
    if (is_double) {
        const double *src[3] = {b0.buf, b1.buf, b2.buf};
        tap_sum_double(src, tb.buf, ob.buf, span, n_terms);
    } else {
        const float *src[3] = {b0.buf, b1.buf, b2.buf};
        tap_sum_float(src, tb.buf, ob.buf, span, n_terms);
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&b0); PyBuffer_Release(&b1); PyBuffer_Release(&b2); PyBuffer_Release(&tb);
    PyBuffer_Release(&ob);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ the whole line filter */

/* line_filter(image, type, H, W, fill, minor_is_row, across_px, pad, terms (T, 3) i8 [source,
 * oy, ox], n_terms, kinds (K, 2) i8 [dy, dx], K, patch_idx (P,) i8 sorted flat indices, patch_values
 * (P,) in the sum type, P, across (2 pad + 1, W + 2 pad) work (a ring of the partial sums' rows:
 * out row y reads rows y .. y + 2 pad, each made once, so the ring stays in the cache where the
 * whole padded frame of them, 4.4 MB at 1024 x 1024, went to memory and back), out (H, W), is_double):
 * _matched.line_filter's sum in one call, the same sums in the same order: the pixels cast to the
 * sum type (fill off the image; a patched pixel, the last of its index, takes its value), across[p] = ((P[p - e] + P[p + e]) + P[p])
 * + P[p + 2e] + P[p - 2e] ... over the across half-width (e one step across the smear), then
 * out[p] = the terms in order: source 0 across[p + o], source 1 + j the pair (across[p + o] +
 * across[p + o + d_j]) of kind j.  Row by row (the rows a term reads stay in the cache); the
 * loops are small functions of their own, which the compiler vectorises. */
#define LF_CAST(TS, TT, SUF, PT)                                                                        \
    static PIXEL_LOOP_CLONES void lf_cast_##TS##_##SUF(const PT *restrict r, TT *restrict d,    \
                                                               Py_ssize_t n) {                     \
        for (Py_ssize_t x = 0; x < n; x++) d[x] = (TT)r[x];                                             \
    }
#define LF_CASTS(TS, TT)                                                                                \
    LF_CAST(TS, TT, u8, uint8_t) LF_CAST(TS, TT, i8, int8_t) LF_CAST(TS, TT, u16, uint16_t)             \
    LF_CAST(TS, TT, i16, int16_t) LF_CAST(TS, TT, u32, uint32_t) LF_CAST(TS, TT, i32, int32_t)          \
    LF_CAST(TS, TT, u64, uint64_t) LF_CAST(TS, TT, i64, int64_t) LF_CAST(TS, TT, f32, float)            \
    LF_CAST(TS, TT, f64, double)
LF_CASTS(f, float)
LF_CASTS(d, double)
#define LF_CAST_ROW(TS, SUF, PT) lf_cast_##TS##_##SUF((const PT *)img + y * W, d, W)

#define LF_VEC(TS, TT)                                                                                  \
    static PIXEL_LOOP_CLONES void lf_sum3_##TS(TT *restrict a, const TT *restrict x,             \
                                                       const TT *restrict y, const TT *restrict z,       \
                                                       Py_ssize_t n) {                                   \
        for (Py_ssize_t i = 0; i < n; i++) a[i] = (x[i] + y[i]) + z[i];                                 \
    }                                                                                                   \
    static PIXEL_LOOP_CLONES void lf_add_##TS(TT *restrict a, const TT *restrict x, Py_ssize_t n) { \
        for (Py_ssize_t i = 0; i < n; i++) a[i] += x[i];                                                \
    }                                                                                                   \
    static PIXEL_LOOP_CLONES void lf_add2_##TS(TT *restrict a, const TT *restrict x,             \
                                                       const TT *restrict y, Py_ssize_t n) {             \
        for (Py_ssize_t i = 0; i < n; i++) a[i] = (a[i] + x[i]) + y[i];                                 \
    }                                                                                                   \
    static PIXEL_LOOP_CLONES void lf_pair_##TS(TT *restrict a, const TT *restrict x,             \
                                                       const TT *restrict y, Py_ssize_t n) {             \
        for (Py_ssize_t i = 0; i < n; i++) a[i] = x[i] + y[i];                                          \
    }                                                                                                   \
    static PIXEL_LOOP_CLONES void lf_add3_##TS(TT *restrict a, const TT *restrict x, const TT *restrict y, \
                                       const TT *restrict z, Py_ssize_t n) {                            \
        for (Py_ssize_t i = 0; i < n; i++) a[i] = ((a[i] + x[i]) + y[i]) + z[i];                        \
    }                                                                                                   \
    static PIXEL_LOOP_CLONES void lf_add_pair_##TS(TT *restrict a, const TT *restrict x,         \
                                                           const TT *restrict y, Py_ssize_t n) {         \
        for (Py_ssize_t i = 0; i < n; i++) a[i] += x[i] + y[i];                                         \
    }
LF_VEC(f, float)
LF_VEC(d, double)

#define LINE_FILTER(TS, TT)                                                                             \
    static void lf_row_##TS(const void *img, int t, Py_ssize_t H, Py_ssize_t W, Py_ssize_t y, Py_ssize_t pad,   \
                            Py_ssize_t ext, TT fill, const int64_t *pidx, const TT *pval, Py_ssize_t np_, \
                            TT *dst) {                                                                  \
        Py_ssize_t wp = W + 2 * pad;                                                                    \
        if (y < 0 || y >= H) { for (Py_ssize_t c = 0; c < wp + 2 * ext; c++) dst[c] = fill; return; }   \
        for (Py_ssize_t c = 0; c < ext + pad; c++) dst[c] = fill;                                       \
        for (Py_ssize_t c = ext + pad + W; c < wp + 2 * ext; c++) dst[c] = fill;                        \
        TT *d = dst + ext + pad;                                                                        \
        switch (t) {                                                                                    \
            case 0: LF_CAST_ROW(TS, u8, uint8_t); break;                                                \
            case 1: LF_CAST_ROW(TS, i8, int8_t); break;                                                 \
            case 2: LF_CAST_ROW(TS, u16, uint16_t); break;                                              \
            case 3: LF_CAST_ROW(TS, i16, int16_t); break;                                               \
            case 4: LF_CAST_ROW(TS, u32, uint32_t); break;                                              \
            case 5: LF_CAST_ROW(TS, i32, int32_t); break;                                               \
            case 6: LF_CAST_ROW(TS, u64, uint64_t); break;                                              \
            case 7: LF_CAST_ROW(TS, i64, int64_t); break;                                               \
            case 8: LF_CAST_ROW(TS, f32, float); break;                                                 \
            default: LF_CAST_ROW(TS, f64, double); break;                                               \
        }                                                                                               \
        if (np_) {                      /* the patched pixels of row y (sorted flat indices) */         \
            const int64_t r0 = (int64_t)y * W, r1 = r0 + W;                                             \
            Py_ssize_t lo = 0, hi = np_;                                                                \
            while (lo < hi) { Py_ssize_t m = (lo + hi) / 2; if (pidx[m] < r0) lo = m + 1; else hi = m; } \
            for (; lo < np_ && pidx[lo] < r1; lo++) d[pidx[lo] - r0] = pval[lo];                        \
        }                                                                                               \
    }                                                                                                   \
    static int line_filter_##TS(const void *img, int t, Py_ssize_t H, Py_ssize_t W, double fill_d,      \
                                int minor_is_row, Py_ssize_t w, Py_ssize_t pad, const int64_t *terms,   \
                                Py_ssize_t n_terms, const int64_t *kinds, const int64_t *pidx,          \
                                const TT *pval, Py_ssize_t np_, TT *A, TT *out) {                       \
        const TT fill = (TT)fill_d;                                                                     \
        const Py_ssize_t wp = W + 2 * pad, hp = H + 2 * pad, ext = minor_is_row ? 0 : w;               \
        const Py_ssize_t nrow = minor_is_row ? 2 * w + 1 : 1;                                          \
        const Py_ssize_t nr_ring = 2 * pad + 1;  /* the rows of A an out row reads: y .. y + 2 pad */   \
        TT *rows = malloc(sizeof(TT) * (size_t)nrow * (size_t)(wp + 2 * ext));                          \
        if (!rows) return -1;                                                                           \
        Py_ssize_t next = 0;                /* the next padded row of A to make (ring of nr_ring rows) */ \
        Py_ssize_t cast_next = -pad - w;    /* the next image row to cast (minor_is_row) */             \
        for (Py_ssize_t y = 0; y < H; y++) {                                                            \
          for (; next <= y + 2 * pad && next < hp; next++) {                                              \
            const Py_ssize_t pr = next;                                                                 \
            TT *restrict a = A + (pr % nr_ring) * wp;                                                               \
            if (minor_is_row) {             /* e = one row: image rows pr - pad - w .. pr - pad + w,  \
                                               each cast once into a ring of nrow rows */               \
                for (; cast_next <= pr - pad + w; cast_next++)                                          \
                    lf_row_##TS(img, t, H, W, cast_next, pad, 0, fill, pidx, pval, np_,                  \
                                rows + (((cast_next % nrow) + nrow) % nrow) * wp);                      \
                const Py_ssize_t c0 = pr - pad;                                                         \
                const TT *restrict r0 = rows + (((c0 % nrow) + nrow) % nrow) * wp;                      \
                if (w == 0) { memcpy(a, r0, sizeof(TT) * (size_t)wp); continue; }                       \
                const TT *restrict rm = rows + ((((c0 - 1) % nrow) + nrow) % nrow) * wp;                \
                const TT *restrict rp = rows + ((((c0 + 1) % nrow) + nrow) % nrow) * wp;                \
                lf_sum3_##TS(a, rm, rp, r0, wp);                                                        \
                for (Py_ssize_t j = 2; j <= w; j++) {                                                   \
                    const TT *restrict up = rows + ((((c0 + j) % nrow) + nrow) % nrow) * wp;            \
                    const TT *restrict dn = rows + ((((c0 - j) % nrow) + nrow) % nrow) * wp;            \
                    lf_add_##TS(a, up, wp);                                                             \
                    lf_add_##TS(a, dn, wp);                                                             \
                }                                                                                       \
            } else {                        /* e = one column: the padded row widened by w fills */      \
                lf_row_##TS(img, t, H, W, pr - pad, pad, ext, fill, pidx, pval, np_, rows);                              \
                const TT *restrict r0 = rows + ext;                                                     \
                if (w == 0) { memcpy(a, r0, sizeof(TT) * (size_t)wp); continue; }                       \
                lf_sum3_##TS(a, r0 - 1, r0 + 1, r0, wp);                                                \
                for (Py_ssize_t j = 2; j <= w; j++)                                                     \
                    lf_add2_##TS(a, r0 + j, r0 - j, wp);                                                \
            }                                                                                           \
          }                                                                                             \
          /* out row y: a pair's two taps added first, as the reference's pair images hold them */      \
          /* (runs of plain terms in one pass each: ((o + x) + y) + z is the same sum as three) */     \
          TT *o = out + y * W;                                                                          \
          for (Py_ssize_t k = 0; k < n_terms;) {                                                        \
              const TT *p[3];                                                                           \
              const int64_t *tm = terms + 3 * k;                                                        \
              if (tm[0]) {                                                                              \
                  const Py_ssize_t r = y + pad + tm[1];                                                 \
                  const int64_t dy = kinds[2 * (tm[0] - 1)], dx = kinds[2 * (tm[0] - 1) + 1];           \
                  const TT *pp = A + (r % nr_ring) * wp + pad + tm[2];                                  \
                  const TT *q = A + ((r + dy) % nr_ring) * wp + pad + tm[2] + dx;                       \
                  if (k == 0) lf_pair_##TS(o, pp, q, W);                                                \
                  else lf_add_pair_##TS(o, pp, q, W);                                                   \
                  k++;                                                                                  \
                  continue;                                                                             \
              }                                                                                         \
              int m = 0;                                                                                \
              while (m < 3 && k + m < n_terms && terms[3 * (k + m)] == 0) {                             \
                  const int64_t *tj = terms + 3 * (k + m);                                              \
                  p[m++] = A + ((y + pad + tj[1]) % nr_ring) * wp + pad + tj[2];                        \
              }                                                                                         \
              if (k == 0) {                                                                             \
                  if (m == 3) lf_sum3_##TS(o, p[0], p[1], p[2], W);                                     \
                  else if (m == 2) lf_pair_##TS(o, p[0], p[1], W);                                      \
                  else memcpy(o, p[0], sizeof(TT) * (size_t)W);                                         \
              } else if (m == 3) lf_add3_##TS(o, p[0], p[1], p[2], W);                                  \
              else if (m == 2) lf_add2_##TS(o, p[0], p[1], W);                                         \
              else lf_add_##TS(o, p[0], W);                                                             \
              k += m;                                                                                   \
          }                                                                                             \
        }                                                                                               \
        free(rows);                                                                                     \
        return 0;                                                                                       \
    }
LINE_FILTER(f, float)
LINE_FILTER(d, double)

static PyObject *py_line_filter(PyObject *self, PyObject *args) {
    Py_buffer ib, tb, kb, pib, pvb, ab, ob;
    Py_ssize_t h, w, across_px, pad, n_terms, n_kinds, n_patch;
    double fill;
    int minor_is_row, is_double, rc = -1;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*snndpnny*ny*ny*y*nw*w*p", &ib, &code, &h, &w, &fill, &minor_is_row,
                          &across_px, &pad, &tb, &n_terms, &kb, &n_kinds, &pib, &pvb, &n_patch, &ab, &ob,
                          &is_double))
        return NULL;
    int t = type_index(code);
    size_t item = is_double ? sizeof(double) : sizeof(float);
    int ok = t >= 0 && h > 0 && w > 0 && across_px >= 0 && pad > across_px && n_terms > 0 && n_kinds >= 0
             && tb.len == (Py_ssize_t)(3 * n_terms * sizeof(int64_t))
             && kb.len >= (Py_ssize_t)(2 * n_kinds * sizeof(int64_t))
             && ab.len >= (Py_ssize_t)((size_t)(2 * pad + 1) * (size_t)(w + 2 * pad) * item)
             && ob.len == (Py_ssize_t)((size_t)h * (size_t)w * item)
             && n_patch >= 0 && pib.len >= (Py_ssize_t)(n_patch * sizeof(int64_t))
             && pvb.len >= (Py_ssize_t)((size_t)n_patch * item);
    if (ok) {                                       /* patches sorted, on the image */
        const int64_t *pi = pib.buf;
        for (Py_ssize_t k = 0; k < n_patch && ok; k++)
            ok = pi[k] >= 0 && pi[k] < (int64_t)h * w && (k == 0 || pi[k] >= pi[k - 1]);
    }
    if (ok) {                                       /* every tap inside the padded frame */
        const int64_t *tm = tb.buf, *kd = kb.buf;
        for (Py_ssize_t k = 0; k < n_terms && ok; k++) {
            int64_t s_ = tm[3 * k], oy = tm[3 * k + 1], ox = tm[3 * k + 2];
            ok = s_ >= 0 && s_ <= n_kinds;
            if (ok) {
                int64_t dy = s_ ? kd[2 * (s_ - 1)] : 0, dx = s_ ? kd[2 * (s_ - 1) + 1] : 0;
                ok = llabs(oy) <= pad && llabs(ox) <= pad && llabs(oy + dy) <= pad && llabs(ox + dx) <= pad;
            }
        }
    }
    if (ok) {
        Py_BEGIN_ALLOW_THREADS
        rc = is_double ? line_filter_d(ib.buf, t, h, w, fill, minor_is_row, across_px, pad, tb.buf, n_terms, kb.buf,
                                       pib.buf, pvb.buf, n_patch, ab.buf, ob.buf)
                       : line_filter_f(ib.buf, t, h, w, fill, minor_is_row, across_px, pad, tb.buf, n_terms, kb.buf,
                                       pib.buf, pvb.buf, n_patch, ab.buf, ob.buf);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&ib); PyBuffer_Release(&tb); PyBuffer_Release(&kb); PyBuffer_Release(&pib);
    PyBuffer_Release(&pvb); PyBuffer_Release(&ab); PyBuffer_Release(&ob);
    if (!ok) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "line_filter: bad sizes, terms or patches");
        return NULL;
    }
    if (rc < 0) return PyErr_NoMemory();
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ 3 x 3 box mean */

/* box3(image (h, w) f4, out (h, w) f4, h, w): the 3 x 3 mean with edges extended, as
 * scipy.ndimage.uniform_filter(image, 3, mode="nearest") computes it for float32: a running
 * sum in double along axis 0, each value divided by 3 and rounded to float32, then the same
 * along axis 1. */
static void box3_line(const float *in, Py_ssize_t stride, Py_ssize_t n, float *out, Py_ssize_t ostride,
                      double *line) {
    line[0] = in[0];
    for (Py_ssize_t i = 0; i < n; i++) line[i + 1] = in[i * stride];
    line[n + 1] = in[(n - 1) * stride];
    double tmp = 0.0;
    for (int j = 0; j < 3; j++) tmp += line[j];
    out[0] = (float)(tmp / 3.0);
    for (Py_ssize_t i = 1; i < n; i++) {
        tmp += line[i + 2] - line[i - 1];
        out[i * ostride] = (float)(tmp / 3.0);
    }
}

/* box3_line along axis 0 for every column at once, row by row (the same sums per column, in
 * the same order: the running sum of line[] = the column with its ends repeated), so that
 * the loops run over contiguous rows; acc (w,) doubles. */
static void box3_axis0(const float *in, Py_ssize_t h, Py_ssize_t w, float *out, double *acc) {
#define ROW(j) (in + ((j) < 1 ? 0 : ((j) - 1 > h - 1 ? h - 1 : (j) - 1)) * w)     /* line[j] */
    const float *l0 = ROW(0), *l1 = ROW(1), *l2 = ROW(2);
    for (Py_ssize_t c = 0; c < w; c++) {
        double t = 0.0;
        t += (double)l0[c];
        t += (double)l1[c];
        t += (double)l2[c];
        acc[c] = t;
        out[c] = (float)(t / 3.0);
    }
    for (Py_ssize_t i = 1; i < h; i++) {
        const float *add = ROW(i + 2), *sub = ROW(i - 1);
        float *o = out + i * w;
        for (Py_ssize_t c = 0; c < w; c++) {
            acc[c] += (double)add[c] - (double)sub[c];
            o[c] = (float)(acc[c] / 3.0);
        }
    }
#undef ROW
}

static PyObject *py_box3(PyObject *self, PyObject *args) {
    Py_buffer ib, ob;
    Py_ssize_t h, w;
    if (!PyArg_ParseTuple(args, "y*w*nn", &ib, &ob, &h, &w)) return NULL;
    Py_ssize_t n = h > w ? h : w;
    double *line = malloc(sizeof(double) * (size_t)(n + 2));
    float *tmp = malloc(sizeof(float) * (size_t)(h * w > 0 ? h * w : 1));
    if (!line || !tmp) { free(line); free(tmp); PyBuffer_Release(&ib); PyBuffer_Release(&ob); return PyErr_NoMemory(); }
    const float *in = ib.buf;
    float *out = ob.buf;
    Py_BEGIN_ALLOW_THREADS
    box3_axis0(in, h, w, tmp, line);                                                    /* axis 0 */
    for (Py_ssize_t r = 0; r < h; r++) box3_line(tmp + r * w, 1, w, out + r * w, 1, line);  /* axis 1 */
    Py_END_ALLOW_THREADS
    free(line);
    free(tmp);
    PyBuffer_Release(&ib);
    PyBuffer_Release(&ob);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ label_runs */

static int64_t uf_find(int64_t *parent, int64_t i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

/* labels (K,) of sorted flat indices idx (K,) of an image `width` wide (work: 4 K int64); returns
 * the count.  Runs (maximal horizontal segments) joined by union-find, numbered in the order of
 * each component's first run. */
static int64_t label_runs_core(const int64_t *idx, int64_t *labels, Py_ssize_t K, Py_ssize_t width, int diagonal,
                               int64_t *work) {
    int64_t n_labels = 0;
    int64_t *run_start = work, *run_end = run_start + K, *parent = run_end + K, *label_of = parent + K;
    int64_t *run_row = label_of;                    /* (each run's row until the labels are made) */
    int64_t n_runs = 0, row = -1, row_end = INT64_MIN;
    for (Py_ssize_t i = 0; i < K; i++) {            /* runs: maximal horizontal segments */
        int64_t p = idx[i];
        int new_row = p >= row_end;                 /* (a division only where a row starts: ~40 ns each) */
        if (new_row) {
            row = p / width;
            row_end = (row + 1) * width;
        }
        if (i == 0 || new_row || p != idx[i - 1] + 1) {
            run_start[n_runs] = p;
            run_row[n_runs] = row;
            parent[n_runs] = n_runs;
            n_runs++;
        }
        run_end[n_runs - 1] = p;
        labels[i] = n_runs - 1;                     /* run number for now */
    }
    int64_t lo = 0;                                 /* first run of the next row that may touch */
    for (int64_t r = 0; r < n_runs; r++) {
        int64_t rrow = run_row[r], c0 = run_start[r] - rrow * width, c1 = run_end[r] - rrow * width;
        int64_t below = (rrow + 1) * width;
        int64_t reach = diagonal ? 1 : 0;
        int64_t first = below + (c0 - reach > 0 ? c0 - reach : 0);
        int64_t last = below + (c1 + reach < width - 1 ? c1 + reach : width - 1);
        if (lo <= r) lo = r + 1;
        while (lo < n_runs && run_end[lo] < first) lo++;
        for (int64_t q = lo; q < n_runs && run_start[q] <= last; q++) {
            int64_t a = uf_find(parent, r), b = uf_find(parent, q);
            if (a != b) {
                if (a < b) parent[b] = a; else parent[a] = b;
            }
        }
    }
    for (int64_t r = 0; r < n_runs; r++) {          /* labels in order of each component's first run */
        int64_t root = uf_find(parent, r);
        if (root == r) label_of[r] = n_labels++;
        else label_of[r] = label_of[root];
    }
    for (Py_ssize_t i = 0; i < K; i++) labels[i] = label_of[labels[i]];
    return n_labels;
}

static PyObject *py_label_runs(PyObject *self, PyObject *args) {
    Py_buffer idx_b, lab_b;
    Py_ssize_t K, width;
    int diagonal = 1;                               /* 8-connected; 0: 4-connected */
    if (!PyArg_ParseTuple(args, "y*w*nn|p", &idx_b, &lab_b, &K, &width, &diagonal)) return NULL;
    int64_t *work = malloc(sizeof(int64_t) * 4 * (size_t)(K > 0 ? K : 1));
    if (!work) { PyBuffer_Release(&idx_b); PyBuffer_Release(&lab_b); return PyErr_NoMemory(); }
    int64_t n_labels;
    Py_BEGIN_ALLOW_THREADS
    n_labels = label_runs_core(idx_b.buf, lab_b.buf, K, width, diagonal, work);
    Py_END_ALLOW_THREADS
    free(work);
    PyBuffer_Release(&idx_b);
    PyBuffer_Release(&lab_b);
    return PyLong_FromLongLong((long long)n_labels);
}

/* ------------------------------------------------------------------ region_shape */

/* region_shape(win (h, w) f4, out (2,) f8, h, w, cx, cy, cut): _artifacts._region_shape on
 * a window already cut from the frame (float32).  Its 3 x 3 mean (box3, the same values);
 * the pixels above `cut` (compared in double: the caller rounds `cut` to float32 where
 * NumPy would compare in float32); of the 4-connected regions that reach the 5 x 5 pixels
 * around (cx, cy), the one with the most pixels there (on a tie the one whose first pixel
 * comes first in raster order: the smallest of scipy.ndimage.label's numbers); then its
 * extent along and across its principal axes, (max - min + 1) of the pixels' projections
 * on the eigenvectors of their 2 x 2 second moments (closed form: LAPACK's eigh to
 * rounding; for a diagonal matrix the same axes, in the same order).  out = (0, 0) when no
 * region reaches the 5 x 5, (n, 1) for one of n < 3 pixels. */
static PyObject *py_region_shape(PyObject *self, PyObject *args) {
    Py_buffer wb, ob;
    Py_ssize_t h, w, cx, cy;
    double cut;
    if (!PyArg_ParseTuple(args, "y*w*nnnnd", &wb, &ob, &h, &w, &cx, &cy, &cut)) return NULL;
    double *out = ob.buf;
    Py_ssize_t n = h * w;
    if (h < 1 || w < 1 || wb.len != (Py_ssize_t)(n * sizeof(float)) || ob.len != (Py_ssize_t)(2 * sizeof(double))
        || cx < 0 || cx >= w || cy < 0 || cy >= h) {
        PyBuffer_Release(&wb); PyBuffer_Release(&ob);
        PyErr_SetString(PyExc_ValueError, "region_shape: bad sizes");
        return NULL;
    }
    Py_ssize_t m = h > w ? h : w;
    float *box = malloc(sizeof(float) * (size_t)n * 2);
    double *line = malloc(sizeof(double) * (size_t)(m + 2));
    int32_t *comp = malloc(sizeof(int32_t) * (size_t)n * 2);     /* region number + 1 of each pixel; a queue */
    if (!box || !line || !comp) {
        free(box); free(line); free(comp); PyBuffer_Release(&wb); PyBuffer_Release(&ob);
        return PyErr_NoMemory();
    }
    Py_BEGIN_ALLOW_THREADS
    const float *in = wb.buf;
    float *tmp = box + n;
    int32_t *queue = comp + n;
    box3_axis0(in, h, w, tmp, line);                                                    /* axis 0 */
    for (Py_ssize_t r = 0; r < h; r++) box3_line(tmp + r * w, 1, w, box + r * w, 1, line);  /* axis 1 */
    memset(comp, 0, sizeof(int32_t) * (size_t)n);
    Py_ssize_t r0 = cy - 2 > 0 ? cy - 2 : 0, r1 = cy + 3 < h ? cy + 3 : h;
    Py_ssize_t c0 = cx - 2 > 0 ? cx - 2 : 0, c1 = cx + 3 < w ? cx + 3 : w;
    /* the regions through the 5 x 5 (at most 25), each flooded once: its first pixel and size */
    int32_t n_regions = 0, best = 0;
    Py_ssize_t first[25], count[25];
    for (Py_ssize_t r = r0; r < r1; r++) {
        for (Py_ssize_t c = c0; c < c1; c++) {
            Py_ssize_t i = r * w + c;
            if (comp[i] || !((double)box[i] > cut)) continue;
            int32_t id = ++n_regions;
            Py_ssize_t head = 0, tail = 0, lo = i;
            comp[i] = id;
            queue[tail++] = (int32_t)i;
            while (head < tail) {
                Py_ssize_t p = queue[head++], pr = p / w, pc = p - pr * w;
                if (p < lo) lo = p;
                Py_ssize_t nb[4] = {pr > 0 ? p - w : -1, pc > 0 ? p - 1 : -1, pc < w - 1 ? p + 1 : -1,
                                    pr < h - 1 ? p + w : -1};
                for (int k = 0; k < 4; k++) {
                    Py_ssize_t q = nb[k];
                    if (q >= 0 && !comp[q] && (double)box[q] > cut) { comp[q] = id; queue[tail++] = (int32_t)q; }
                }
            }
            first[id - 1] = lo;
            count[id - 1] = 0;
        }
    }
    out[0] = 0.0; out[1] = 0.0;
    if (n_regions > 0) {
        for (Py_ssize_t r = r0; r < r1; r++)
            for (Py_ssize_t c = c0; c < c1; c++)
                if (comp[r * w + c]) count[comp[r * w + c] - 1]++;
        best = 1;
        for (int32_t k = 2; k <= n_regions; k++)
            if (count[k - 1] > count[best - 1] || (count[k - 1] == count[best - 1] && first[k - 1] < first[best - 1]))
                best = k;
        /* the region's pixels in raster order: their mean, then the second moments */
        double sx = 0.0, sy = 0.0;
        Py_ssize_t np_ = 0;
        for (Py_ssize_t i = first[best - 1]; i < n; i++)
            if (comp[i] == best) { sx += (double)(i % w); sy += (double)(i / w); np_++; }
        if (np_ < 3) {
            out[0] = (double)np_; out[1] = 1.0;
        } else {
            double mx = sx / (double)np_, my = sy / (double)np_, a = 0.0, b = 0.0, d = 0.0;
            for (Py_ssize_t i = first[best - 1]; i < n; i++)
                if (comp[i] == best) {
                    double x = (double)(i % w) - mx, y = (double)(i / w) - my;
                    a += x * x; b += x * y; d += y * y;
                }
            double ux, uy;                                  /* the major axis; the minor is (-uy, ux) */
            if (b == 0.0) {
                if (a > d) { ux = 1.0; uy = 0.0; } else { ux = 0.0; uy = 1.0; }
            } else {
                double th = 0.5 * atan2(2.0 * b, a - d);
                ux = cos(th); uy = sin(th);
            }
            double pmin = INFINITY, pmax = -INFINITY, qmin = INFINITY, qmax = -INFINITY;
            for (Py_ssize_t i = first[best - 1]; i < n; i++)
                if (comp[i] == best) {
                    double x = (double)(i % w) - mx, y = (double)(i / w) - my;
                    double p = x * ux + y * uy, q = y * ux - x * uy;
                    if (p < pmin) pmin = p;
                    if (p > pmax) pmax = p;
                    if (q < qmin) qmin = q;
                    if (q > qmax) qmax = q;
                }
            out[0] = pmax - pmin + 1.0;
            out[1] = qmax - qmin + 1.0;
        }
    }
    Py_END_ALLOW_THREADS
    free(box); free(line); free(comp);
    PyBuffer_Release(&wb);
    PyBuffer_Release(&ob);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ suppress */

/* dropped (M,) of peaks xy (M, 2) visited in `order` (strongest first). */
static void suppress_core(const double *xy, const int64_t *order, uint8_t *dropped, Py_ssize_t M, double ux,
                          double uy, double along_px, double across_px) {
    for (Py_ssize_t r = 0; r < M; r++) {
        int64_t i = order[r];
        if (dropped[i]) continue;
        for (Py_ssize_t s = r + 1; s < M; s++) {
            int64_t j = order[s];
            double dx = xy[2 * j] - xy[2 * i], dy = xy[2 * j + 1] - xy[2 * i + 1];
            if (fabs(dx * ux + dy * uy) <= along_px && fabs(dx * uy - dy * ux) <= across_px) dropped[j] = 1;
        }
    }
}

static PyObject *py_suppress(PyObject *self, PyObject *args) {
    Py_buffer xy_b, order_b, drop_b;
    Py_ssize_t M;
    double ux, uy, along_px, across_px;
    if (!PyArg_ParseTuple(args, "y*y*w*ndddd", &xy_b, &order_b, &drop_b, &M, &ux, &uy, &along_px, &across_px))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    suppress_core(xy_b.buf, order_b.buf, drop_b.buf, M, ux, uy, along_px, across_px);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&xy_b);
    PyBuffer_Release(&order_b);
    PyBuffer_Release(&drop_b);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ streak_peaks */

/* Stable merge sort of the indices ord (n,) by key descending (ties: the smaller index first,
 * as NumPy's stable argsort of -key); tmp (n,) work. */
static void sort_desc_stable(int64_t *ord, int64_t *tmp, Py_ssize_t n, const double *key) {
    for (Py_ssize_t width = 1; width < n; width *= 2) {
        for (Py_ssize_t lo = 0; lo < n; lo += 2 * width) {
            Py_ssize_t mid = lo + width < n ? lo + width : n, hi = lo + 2 * width < n ? lo + 2 * width : n;
            Py_ssize_t i = lo, j = mid, k = lo;
            while (i < mid && j < hi) tmp[k++] = key[ord[j]] > key[ord[i]] ? ord[j++] : ord[i++];
            while (i < mid) tmp[k++] = ord[i++];
            while (j < hi) tmp[k++] = ord[j++];
        }
        memcpy(ord, tmp, sizeof(int64_t) * (size_t)n);
    }
}

/* streak_peaks(s (H, W) f4 or f8, idx (K,) i8 sorted, bg, noise (ny, nx) f8, col_out, row_out (K,) i8,
 *              snr_out (K,) f8, label_out, npix_out (K,) i8, too_big_out (K,) u8, K, H, W, ny, nx, block,
 *              level, threshold, ux, uy, along_px, across_px, max_along_px, max_across_px, is_double)
 *   -> the number of peaks written: _matched._streak_peaks_python's steps on the line filter's
 * candidate pixels, the same arithmetic in the same order.  The candidates at or above `level`
 * whose excess over the filter's bilinear background is at least `threshold` times its noise
 * and that are the maximum of their 3 x 3 neighbourhood, strongest first; those within a
 * stronger kept one's footprint (along_px x across_px about the unit smear (ux, uy)) dropped;
 * each one's component of the candidates (8-connected), that component's pixel count and
 * whether its RMS extent along or across the smear exceeds max_along_px / max_across_px
 * (too big: only a component's strongest peak is then kept). */
static Py_ssize_t streak_peaks_core(const void *s_img, int is_double, const int64_t *idx, Py_ssize_t K,
                                    Py_ssize_t H, Py_ssize_t W, const double *bg, const double *noise, Py_ssize_t ny,
                                    Py_ssize_t nx, double block, double level, double threshold, double ux,
                                    double uy, double along_px, double across_px, double max_along_px,
                                    double max_across_px, int64_t *col_out, int64_t *row_out, double *snr_out,
                                    int64_t *label_out, int64_t *npix_out, uint8_t *too_big_out, int64_t *work) {
    /* work: 13 K int64 slots (doubles share the slots' size) and K bytes */
    int64_t *pos = work;                      /* (M,) position in idx of each peak */
    double *snr = (double *)(pos + K);        /* (M,) */
    double *xy = (double *)(pos + 2 * K);     /* (M, 2) */
    int64_t *ord = pos + 4 * K, *tmp = pos + 5 * K;
    int64_t *labels = pos + 6 * K;            /* (K,) */
    int64_t *lwork = pos + 7 * K;             /* (6 K,): the runs' work, then 6 values a component */
    uint8_t *dropped = (uint8_t *)(pos + 13 * K);
    const float *sf = s_img;
    const double *sd = s_img;
    Py_ssize_t M = 0;
    for (Py_ssize_t i = 0; i < K; i++) {
        int64_t p = idx[i];
        double v = is_double ? sd[p] : (double)sf[p];
        if (!(v >= level)) continue;
        Py_ssize_t r = p / W, c = p - r * W;
        double b, nz;
        mesh_pair_at(bg, noise, ny, nx, block, (double)c, (double)r, &b, &nz);
        double z = (v - b) / nz;
        if (!(z >= threshold)) continue;
        int ok = 1;                           /* the 3 x 3 maximum (ties: the smallest flat index) */
        for (int dr = -1; dr <= 1 && ok; dr++) {
            if (r + dr < 0 || r + dr >= H) continue;
            for (int dc = -1; dc <= 1; dc++) {
                if ((dr == 0 && dc == 0) || c + dc < 0 || c + dc >= W) continue;
                Py_ssize_t q = p + dr * W + dc;
                double u = is_double ? sd[q] : (double)sf[q];
                if (dr * W + dc < 0 ? !(v > u) : !(v >= u)) { ok = 0; break; }
            }
        }
        if (!ok) continue;
        pos[M] = i;
        snr[M] = z;
        xy[2 * M] = (double)c;
        xy[2 * M + 1] = (double)r;
        M++;
    }
    for (Py_ssize_t m = 0; m < M; m++) ord[m] = m;
    sort_desc_stable(ord, tmp, M, snr);
    memset(dropped, 0, (size_t)(M > 0 ? M : 1));
    if (M >= 2) suppress_core(xy, ord, dropped, M, ux, uy, along_px, across_px);
    Py_ssize_t n = 0;                         /* the kept peaks, strongest first */
    for (Py_ssize_t m = 0; m < M; m++)
        if (!dropped[ord[m]]) ord[n++] = ord[m];
    if (n == 0) return 0;
    int64_t n_labels = label_runs_core(idx, labels, K, W, 1, lwork);
    /* per component: pixel count, then (for those with a peak) the sums of the extent */
    int64_t *count = lwork, *slot = lwork + n_labels;              /* (n_labels,) each: the runs are done */
    double *sum_a = (double *)(lwork + 2 * n_labels), *sum_c = sum_a + n_labels;
    memset(count, 0, sizeof(int64_t) * (size_t)n_labels);
    for (Py_ssize_t i = 0; i < K; i++) count[labels[i]]++;
    for (int64_t l = 0; l < n_labels; l++) slot[l] = -1;
    uint8_t *first = (uint8_t *)tmp;          /* (n,): the component's strongest peak */
    for (Py_ssize_t m = 0; m < n; m++) {
        int64_t l = labels[pos[ord[m]]];
        first[m] = slot[l] < 0;
        slot[l] = 1;
    }
    for (int64_t l = 0; l < n_labels; l++) sum_a[l] = sum_c[l] = 0.0;
    for (Py_ssize_t i = 0; i < K; i++) {
        int64_t l = labels[i];
        if (slot[l] < 0) continue;
        double row = (double)(idx[i] / W), col = (double)(idx[i] - (idx[i] / W) * W);
        sum_a[l] += col * ux + row * uy;
        sum_c[l] += col * uy - row * ux;
    }
    for (int64_t l = 0; l < n_labels; l++)
        if (slot[l] >= 0) {
            sum_a[l] /= (double)count[l];     /* the means */
            sum_c[l] /= (double)count[l];
        }
    double *var_a = (double *)(lwork + 4 * n_labels), *var_c = var_a + n_labels;
    for (int64_t l = 0; l < n_labels; l++) var_a[l] = var_c[l] = 0.0;
    for (Py_ssize_t i = 0; i < K; i++) {
        int64_t l = labels[i];
        if (slot[l] < 0) continue;
        double row = (double)(idx[i] / W), col = (double)(idx[i] - (idx[i] / W) * W);
        double da = (col * ux + row * uy) - sum_a[l], dc = (col * uy - row * ux) - sum_c[l];
        var_a[l] += da * da;
        var_c[l] += dc * dc;
    }
    Py_ssize_t out = 0;
    for (Py_ssize_t m = 0; m < n; m++) {
        int64_t i = pos[ord[m]], l = labels[i];
        double ea = sqrt(var_a[l] / (double)count[l]), ec = sqrt(var_c[l] / (double)count[l]);
        int big = ea > max_along_px || ec > max_across_px;
        if (big && !first[m]) continue;
        row_out[out] = idx[i] / W;
        col_out[out] = idx[i] - row_out[out] * W;
        snr_out[out] = snr[ord[m]];
        label_out[out] = l;
        npix_out[out] = count[l];
        too_big_out[out] = (uint8_t)big;
        out++;
    }
    return out;
}

static PyObject *py_streak_peaks(PyObject *self, PyObject *args) {
    Py_buffer sb, xb, bb, nb_, cb, rb, zb, lb, pb, tb;
    Py_ssize_t K, H, W, ny, nx;
    double block, level, threshold, ux, uy, along_px, across_px, max_along_px, max_across_px;
    int is_double;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*w*w*w*w*w*nnnnndddddddddp", &sb, &xb, &bb, &nb_, &cb, &rb, &zb, &lb, &pb,
                          &tb, &K, &H, &W, &ny, &nx, &block, &level, &threshold, &ux, &uy, &along_px, &across_px,
                          &max_along_px, &max_across_px, &is_double))
        return NULL;
    Py_ssize_t n = -1;
    int64_t *work = malloc(sizeof(int64_t) * (13 * (size_t)K + 1) + (size_t)K + 1);
    if (work) {
        Py_BEGIN_ALLOW_THREADS
        n = streak_peaks_core(sb.buf, is_double, xb.buf, K, H, W, bb.buf, nb_.buf, ny, nx, block, level, threshold,
                              ux, uy, along_px, across_px, max_along_px, max_across_px, cb.buf, rb.buf, zb.buf,
                              lb.buf, pb.buf, tb.buf, work);
        Py_END_ALLOW_THREADS
        free(work);
    }
    PyBuffer_Release(&sb); PyBuffer_Release(&xb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_);
    PyBuffer_Release(&cb); PyBuffer_Release(&rb); PyBuffer_Release(&zb); PyBuffer_Release(&lb);
    PyBuffer_Release(&pb); PyBuffer_Release(&tb);
    if (n < 0) return PyErr_NoMemory();
    return PyLong_FromSsize_t(n);
}

/* ------------------------------------------------------------------ point_objects */

/* point_objects(image, idx (K,) i8 sorted candidates, bg, noise (ny, nx) f8, peaks_out, label_out,
 *               labels_out (K,) i8, K, H, W, ny, nx, block, level (threshold x box-noise factor), ratio, type)
 *   -> the number of objects: _point._detect_objects_python's steps after the candidates, the same
 * arithmetic in the same order.  The candidates that are the maximum of their 3 x 3
 * neighbourhood, whose 3 x 3 box excess over the bilinear background is at least
 * level sqrt(box pixels) noise and whose 8 neighbours hold at least `ratio` (SINGLE_PIXEL_RATIO) of
 * the peak pixel's excess; of each 8-connected component of the candidates (labels_out) the
 * one with the largest box excess (ties: the first), in flat-index order. */
#define POINT_OBJECTS(SUF, T)                                                                           \
    static Py_ssize_t point_objects_##SUF(const T *img, const int64_t *idx, Py_ssize_t K, Py_ssize_t H, \
                                          Py_ssize_t W, const double *bg, const double *noise,          \
                                          Py_ssize_t ny, Py_ssize_t nx, double block, double level,     \
                                          double ratio, int64_t *peaks_out, int64_t *label_out, int64_t *labels,      \
                                          int64_t *work) {                                              \
        uint8_t *is_max = (uint8_t *)(work + 6 * K);                                                    \
        int64_t *pos = work + 4 * K;          /* (M,) the stars' positions in idx */                    \
        double *excess = (double *)(work + 5 * K);                                                      \
        local_max_##SUF(img, idx, is_max, K, H, W);                                                     \
        Py_ssize_t M = 0;                                                                               \
        for (Py_ssize_t i = 0; i < K; i++) {                                                            \
            if (!is_max[i]) continue;                                                                   \
            const int64_t p = idx[i];                                                                   \
            double values[8], e[8];                                                                     \
            uint8_t inside[8];                                                                          \
            neighbours_##SUF(img, &p, values, inside, 1, H, W);                                         \
            int n_in = 0;                                                                               \
            for (int j = 0; j < 8; j++) {                                                               \
                e[j] = inside[j] ? values[j] : 0.0;                                                     \
                n_in += inside[j];                                                                      \
            }                                                                                           \
            const double v = (double)img[p];                                                            \
            const double total = v + (0.0 + pairwise_sum(e, 8)), count = 1.0 + (double)n_in;            \
            const Py_ssize_t r = p / W, c = p - r * W;                                                  \
            double b, nz;                                                                               \
            mesh_pair_at(bg, noise, ny, nx, block, (double)c, (double)r, &b, &nz);                      \
            const double box_excess = total - count * b, peak_excess = v - b;                           \
            if (box_excess >= level * sqrt(count) * nz && box_excess - peak_excess >= ratio * peak_excess) { \
                pos[M] = i;                                                                             \
                excess[M] = box_excess;                                                                 \
                M++;                                                                                    \
            }                                                                                           \
        }                                                                                               \
        /* every candidate's component (the runs' work, 4 K, ends where pos starts) */                  \
        const int64_t n_labels = label_runs_core(idx, labels, K, W, 1, work);                           \
        if (M == 0) return 0;                                                                           \
        int64_t *best = work;                 /* (n_labels,): the best star of each component */        \
        for (int64_t l = 0; l < n_labels; l++) best[l] = -1;                                            \
        for (Py_ssize_t m = 0; m < M; m++) {                                                            \
            const int64_t l = labels[pos[m]];                                                           \
            if (best[l] < 0 || excess[m] > excess[best[l]]) best[l] = m;                                \
        }                                                                                               \
        Py_ssize_t n = 0;                                                                               \
        for (Py_ssize_t m = 0; m < M; m++) {                                                            \
            const int64_t l = labels[pos[m]];                                                           \
            if (best[l] != m) continue;                                                                 \
            peaks_out[n] = idx[pos[m]];                                                                 \
            label_out[n] = l;                                                                           \
            n++;                                                                                        \
        }                                                                                               \
        return n;                                                                                       \
    }
POINT_OBJECTS(u8, uint8_t)
POINT_OBJECTS(i8, int8_t)
POINT_OBJECTS(u16, uint16_t)
POINT_OBJECTS(i16, int16_t)
POINT_OBJECTS(u32, uint32_t)
POINT_OBJECTS(i32, int32_t)
POINT_OBJECTS(u64, uint64_t)
POINT_OBJECTS(i64, int64_t)
POINT_OBJECTS(f32, float)
POINT_OBJECTS(f64, double)

static PyObject *py_point_objects(PyObject *self, PyObject *args) {
    Py_buffer ib, xb, bb, nb_, pb, lb, sb;
    Py_ssize_t K, H, W, ny, nx, n = -1;
    double block, level, ratio;
    const char *code;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*w*w*nnnnnddds", &ib, &xb, &bb, &nb_, &pb, &lb, &sb, &K, &H, &W, &ny, &nx,
                          &block, &level, &ratio, &code))
        return NULL;
    int t = type_index(code);
    /* work: the runs' 4 K, then the stars' positions and excesses (2 K), then K bytes */
    int64_t *work = t >= 0 ? malloc(sizeof(int64_t) * (6 * (size_t)K + 1) + (size_t)K + 1) : NULL;
    if (work) {
        Py_BEGIN_ALLOW_THREADS
#define CALL(SUF, T) n = point_objects_##SUF((const T *)ib.buf, xb.buf, K, H, W, bb.buf, nb_.buf, ny, nx, block, level, \
                                             ratio, pb.buf, lb.buf, sb.buf, work)
        DISPATCH(t, CALL)
#undef CALL
        Py_END_ALLOW_THREADS
        free(work);
    }
    PyBuffer_Release(&ib); PyBuffer_Release(&xb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_);
    PyBuffer_Release(&pb); PyBuffer_Release(&lb); PyBuffer_Release(&sb);
    if (t < 0) return NULL;
    if (n < 0) return PyErr_NoMemory();
    return PyLong_FromSsize_t(n);
}

/* ------------------------------------------------------------------ erf_array */

static PyObject *py_erf_array(PyObject *self, PyObject *args) {
    Py_buffer in_b, out_b;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "y*w*n", &in_b, &out_b, &n)) return NULL;
    const double *x = in_b.buf;
    double *y = out_b.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++) y[i] = erf(x[i]);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&in_b);
    PyBuffer_Release(&out_b);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ grid_box_z */

/* The bilinear interpolation of Mesh.on_grid along one axis: grid point g's blocks i0, i1 and
 * weights w0 = 1 - f, w1 = f (Mesh._weights). */
static void grid_weights(double coord, double block, Py_ssize_t nb, Py_ssize_t *i0, Py_ssize_t *i1, double *w0,
                         double *w1) {
    double f;
    mesh_weights(coord, block, nb, i0, i1, &f);
    *w0 = 1.0 - f;
    *w1 = f;
}

/* grid_box_z(total (nr, nc) f8, bg, noise (ny, nx) f8, out (nr, nc) f8, nr, nc, ny, nx, block, step):
 * (total - 9 bg) / (3 noise) at the grid pixels (1 + step i, 1 + step j), bg and noise
 * bilinear between block centres as Mesh.on_grid's products wy @ grid @ wx^T (each row's
 * two weights; a one-block axis: its single block, weight 1). */
static PyObject *py_grid_box_z(PyObject *self, PyObject *args) {
    Py_buffer tb, bb, nb_, ob;
    Py_ssize_t nr, nc, ny, nx, step;
    double block;
    if (!PyArg_ParseTuple(args, "y*y*y*w*nnnndn", &tb, &bb, &nb_, &ob, &nr, &nc, &ny, &nx, &block, &step))
        return NULL;
    int ok = nr >= 0 && nc >= 0 && ny >= 1 && nx >= 1 && tb.len == (Py_ssize_t)(nr * nc * sizeof(double))
             && ob.len == tb.len && bb.len == (Py_ssize_t)(ny * nx * sizeof(double)) && nb_.len == bb.len;
    if (ok) {
        const double *total = tb.buf, *bg = bb.buf, *noise = nb_.buf;
        double *out = ob.buf;
        /* the columns' weights once (the same for every row: 4096 -> 64 weight computations) */
        Py_ssize_t *xi = malloc(sizeof(Py_ssize_t) * 2 * (size_t)(nc > 0 ? nc : 1));
        double *xw = malloc(sizeof(double) * 2 * (size_t)(nc > 0 ? nc : 1));
        ok = xi && xw;
        if (ok) {
            Py_BEGIN_ALLOW_THREADS
            for (Py_ssize_t j = 0; j < nc; j++)
                grid_weights((double)(1 + step * j), block, nx, &xi[2 * j], &xi[2 * j + 1], &xw[2 * j], &xw[2 * j + 1]);
            for (Py_ssize_t i = 0; i < nr; i++) {
                Py_ssize_t y0, y1;
                double wy0, wy1;
                grid_weights((double)(1 + step * i), block, ny, &y0, &y1, &wy0, &wy1);
                for (Py_ssize_t j = 0; j < nc; j++) {
                    const Py_ssize_t x0 = xi[2 * j], x1 = xi[2 * j + 1];
                    const double wx0 = xw[2 * j], wx1 = xw[2 * j + 1];
                    const double *grids[2] = {bg, noise};
                    double v[2];
                    for (int g = 0; g < 2; g++) {
                        const double *q = grids[g];
                        double c0, c1;
                        if (ny > 1) {
                            c0 = wy0 * q[y0 * nx + x0] + wy1 * q[y1 * nx + x0];
                            c1 = wy0 * q[y0 * nx + x1] + wy1 * q[y1 * nx + x1];
                        } else {
                            c0 = (wy0 + wy1) * q[x0];
                            c1 = (wy0 + wy1) * q[x1];
                        }
                        v[g] = nx > 1 ? wx0 * c0 + wx1 * c1 : (wx0 + wx1) * c0;
                    }
                    out[i * nc + j] = (total[i * nc + j] - 9.0 * v[0]) / (3.0 * v[1]);
                }
            }
            Py_END_ALLOW_THREADS
        }
        free(xi);
        free(xw);
        if (!ok) {
            PyBuffer_Release(&tb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_); PyBuffer_Release(&ob);
            return PyErr_NoMemory();
        }
    }
    PyBuffer_Release(&tb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_); PyBuffer_Release(&ob);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "grid_box_z: bad sizes");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ streak_start */


/* streak_start(values (N, wy, wx) f8, valid u8, bg, noise, x0, y0, col, row, sigma (N,) f8, d (N, 2) f8,
 *              p0_out (N, 7) f8, N, wy, wx, reach, along_max, across_max): _streak.start_parameters's
 * arithmetic star by star (its NumPy reference: _streak._start_parameters_python), the window sums
 * in NumPy's pairwise order. */
/* streak_footprint(model (N, P) f8, bg (N,) f8, values (N, P) f8, valid (N, P) u8, sat (H, W) u8 or
 * one byte, col, row (N,) i8, foot_out (N, P) u8, peak_out (N,) f8, npix_out (N,) i8,
 * flags_out (N, 2) u8, N, wy, wx, H, W, has_sat, fraction): the streak path's footprint of each
 * fitted star (_smeared._footprint_python, the reference): its excess model - bg, the pixels
 * where it is at least ``fraction`` of the window's largest (none when that is NaN), their
 * count, the largest value among them that is valid or saturated (-inf: none; NaN when one is
 * NaN), and whether one is saturated (flags_out[.., 0]) or off the image ([.., 1]); the
 * window's pixel (i, j) is the image's (row + i - (wy - 1) // 2, col + j - (wx - 1) // 2). */
static PyObject *py_streak_footprint(PyObject *self, PyObject *args) {
    Bufs bs = {.n = 0};
    Py_buffer *mb = &bs.b[0], *bgb = &bs.b[1], *vb = &bs.b[2], *kb = &bs.b[3], *sb = &bs.b[4], *cb = &bs.b[5],
              *rb = &bs.b[6], *fb = &bs.b[7], *pkb = &bs.b[8], *nb_ = &bs.b[9], *flb = &bs.b[10];
    Py_ssize_t N, wy, wx, H, W;
    int has_sat;
    double fraction;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*w*w*w*w*nnnnnpd", mb, bgb, vb, kb, sb, cb, rb, fb, pkb, nb_, flb,
                          &N, &wy, &wx, &H, &W, &has_sat, &fraction))
        return NULL;
    bs.n = 11;
    Py_ssize_t P = wy * wx;
    Py_ssize_t d8 = (Py_ssize_t)sizeof(double), i8 = (Py_ssize_t)sizeof(int64_t);
    int ok = N >= 0 && wy >= 1 && wx >= 1 && H >= 1 && W >= 1 && mb->len == N * P * d8 && vb->len == N * P * d8
             && bgb->len == N * d8 && kb->len == N * P && cb->len == N * i8 && rb->len == N * i8
             && fb->len == N * P && pkb->len == N * d8 && nb_->len == N * i8 && flb->len == 2 * N
             && (!has_sat || sb->len == H * W);
    if (!ok) {
        bufs_release(&bs);
        PyErr_SetString(PyExc_ValueError, "streak_footprint: bad sizes");
        return NULL;
    }
    const double *model = mb->buf, *bg = bgb->buf, *values = vb->buf;
    const uint8_t *valid = kb->buf, *sat = sb->buf;
    const int64_t *col = cb->buf, *row = rb->buf;
    uint8_t *foot = fb->buf, *flags = flb->buf;
    double *peak = pkb->buf;
    int64_t *npix = nb_->buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        const double *restrict m = model + s * P, *restrict v = values + s * P;
        const uint8_t *restrict k = valid + s * P;
        uint8_t *restrict f = foot + s * P;
        const double b = bg[s];
        /* the largest excess (NaN if one is); four running maxima, the same largest value */
        double t4[4] = {-INFINITY, -INFINITY, -INFINITY, -INFINITY};
        int nan = 0;
        Py_ssize_t q = 0;
        for (; q + 4 <= P; q += 4)
            for (int u = 0; u < 4; u++) {
                const double e = m[q + u] - b;
                nan |= e != e;
                t4[u] = e > t4[u] ? e : t4[u];
            }
        for (; q < P; q++) {
            const double e = m[q] - b;
            nan |= e != e;
            t4[0] = e > t4[0] ? e : t4[0];
        }
        const double top = fmax(fmax(t4[0], t4[1]), fmax(t4[2], t4[3]));
        const double level = nan ? NAN : fraction * top;
        int64_t count = 0;
        for (Py_ssize_t q = 0; q < P; q++) {           /* the footprint (false against NaN) */
            const uint8_t on = (m[q] - b) >= level;
            f[q] = on;
            count += on;
        }
        /* the window's rows and columns on the image: [i0, i1) x [j0, j1) */
        const Py_ssize_t r0 = row[s] - (wy - 1) / 2, c0 = col[s] - (wx - 1) / 2;
        const Py_ssize_t i0 = r0 < 0 ? (-r0 < wy ? -r0 : wy) : 0, i1 = r0 + wy > H ? (H - r0 > i0 ? H - r0 : i0) : wy;
        const Py_ssize_t j0 = c0 < 0 ? (-c0 < wx ? -c0 : wx) : 0, j1 = c0 + wx > W ? (W - c0 > j0 ? W - c0 : j0) : wx;
        int any_off = 0, any_sat = 0, best_nan = 0;
        double best = -INFINITY;
        for (Py_ssize_t i = 0; i < wy; i++) {
            const uint8_t *fr = f + i * wx;
            const double *vr = v + i * wx;
            const uint8_t *kr = k + i * wx;
            if (i < i0 || i >= i1) {                   /* a row off the image: every pixel off */
                for (Py_ssize_t j = 0; j < wx; j++) any_off |= fr[j];
                for (Py_ssize_t j = 0; j < wx; j++) {  /* (off the image: never saturated) */
                    const double x = (fr[j] & kr[j]) ? vr[j] : -INFINITY;
                    best_nan |= x != x;
                    best = x > best ? x : best;
                }
                continue;
            }
            for (Py_ssize_t j = 0; j < j0; j++) any_off |= fr[j];
            for (Py_ssize_t j = j1; j < wx; j++) any_off |= fr[j];
            const Py_ssize_t base = (r0 + i) * W + c0;  /* the image's pixel of (i, j): base + j */
            for (Py_ssize_t j = 0; j < wx; j++) {
                const uint8_t sp = (has_sat && j >= j0 && j < j1) ? sat[base + j] : 0;
                any_sat |= fr[j] & sp;
                const double x = (fr[j] & (kr[j] | sp)) ? vr[j] : -INFINITY;
                best_nan |= x != x;
                best = x > best ? x : best;
            }
        }
        peak[s] = best_nan ? NAN : best;
        npix[s] = count;
        flags[2 * s] = (uint8_t)any_sat;
        flags[2 * s + 1] = (uint8_t)any_off;
    }
    Py_END_ALLOW_THREADS
    bufs_release(&bs);
    Py_RETURN_NONE;
}

static PyObject *py_streak_start(PyObject *self, PyObject *args) {
    Bufs bs = {.n = 0};
    Py_buffer *vb = &bs.b[0], *kb = &bs.b[1], *bgb = &bs.b[2], *nb_ = &bs.b[3], *x0b = &bs.b[4], *y0b = &bs.b[5],
              *cb = &bs.b[6], *rb = &bs.b[7], *sb = &bs.b[8], *db = &bs.b[9], *pb = &bs.b[10];
    Py_ssize_t N, wy, wx;
    double reach, along_max, across_max;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*w*nnnddd", vb, kb, bgb, nb_, x0b, y0b, cb, rb, sb, db, pb,
                          &N, &wy, &wx, &reach, &along_max, &across_max))
        return NULL;
    bs.n = 11;
    Py_ssize_t P = wy * wx;
    int ok = N >= 0 && wy >= 1 && wx >= 1 && vb->len == (Py_ssize_t)(N * P * sizeof(double)) && kb->len == N * P
             && pb->len == (Py_ssize_t)(N * 7 * sizeof(double)) && db->len == (Py_ssize_t)(N * 2 * sizeof(double));
    double *work = ok ? malloc(sizeof(double) * (size_t)(4 * P + 1)) : NULL;
    if (!ok || work == NULL) {
        bufs_release(&bs);
        if (!ok) PyErr_SetString(PyExc_ValueError, "streak_start: bad sizes");
        else PyErr_NoMemory();
        return NULL;
    }
    const double *values = vb->buf, *bg = bgb->buf, *noise = nb_->buf, *x0 = x0b->buf, *y0 = y0b->buf,
                 *colf = cb->buf, *rowf = rb->buf, *sigma = sb->buf, *d = db->buf;
    const uint8_t *valid = kb->buf;
    double *p0 = pb->buf;
    double *excess = work, *w = work + P, *wa = work + 2 * P, *wc = work + 3 * P;
    double reach2 = reach * reach;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        const double *v = values + s * P;
        const uint8_t *k = valid + s * P;
        double dx = d[2 * s], dy = d[2 * s + 1];
        double length = hypot(dx, dy);
        double u0 = 1.0, u1 = 0.0;
        if (length > 1e-9) {
            double m = np_maximum(length, 1e-9);
            u0 = dx / m;
            u1 = dy / m;
        }
        double half = 0.5 * length, px = colf[s], py = rowf[s];
        for (Py_ssize_t i = 0; i < wy; i++) {
            double ddy = (y0[s] + (double)i) - py;
            for (Py_ssize_t j = 0; j < wx; j++) {
                Py_ssize_t q = i * wx + j;
                double ddx = (x0[s] + (double)j) - px;
                double along = ddx * u0 + ddy * u1;
                double across = ddx * u1 - ddy * u0;
                double e = k[q] ? v[q] - bg[s] : 0.0;
                double t = np_maximum(fabs(along) - half, 0.0);
                int near = t * t + across * across <= reach2;
                double wq = near ? np_maximum(e, 0.0) : 0.0;
                excess[q] = e;
                w[q] = wq;
                wa[q] = wq * along;
                wc[q] = wq * across;
            }
        }
        double total = np_maximum(pairwise_sum(w, P), 1e-300);
        double sa = np_clip(pairwise_sum(wa, P) / total, -along_max, along_max);
        double sc = np_clip(pairwise_sum(wc, P) / total, -across_max, across_max);
        double *o = p0 + 7 * s;
        o[0] = (px + sa * u0) + sc * u1;
        o[1] = (py + sa * u1) + sc * -u0;
        o[2] = np_maximum(pairwise_sum(excess, P), 10.0 * noise[s]);
        o[3] = bg[s];
        o[4] = sigma[s];
        o[5] = dx;
        o[6] = dy;
    }
    Py_END_ALLOW_THREADS
    free(work);
    bufs_release(&bs);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ window_peaks */

/* window_peaks(values (N, wy, wx) f8, valid u8, level (N,) f8, taps (T, 2) i8 [ox, oy], best_out (N,) i8,
 *              s_out (N,) f8, N, wy, wx, T, search, cx, cy): per window, the line filter's sums
 * S = sum over the taps (in their order, from 0) of the excess ``valid ? value - level : 0`` on the
 * (2 search + 1)^2 places around (cx, cy), and the first largest: its flat index among the places
 * and its sum (_windowed._peaks's arithmetic; the caller checks that every tap stays inside). */
static PyObject *py_window_peaks(PyObject *self, PyObject *args) {
    Py_buffer vb, kb, lb, tb, bb, sb;
    Py_ssize_t N, wy, wx, T, search, cx, cy;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*w*nnnnnnn", &vb, &kb, &lb, &tb, &bb, &sb, &N, &wy, &wx, &T, &search,
                          &cx, &cy))
        return NULL;
    Py_ssize_t P = wy * wx, side = 2 * search + 1, places = side * side;
    int ok = N >= 0 && T >= 1 && search >= 0 && vb.len == (Py_ssize_t)(N * P * sizeof(double)) && kb.len == N * P
             && lb.len == (Py_ssize_t)(N * sizeof(double)) && tb.len == (Py_ssize_t)(T * 2 * sizeof(int64_t))
             && bb.len == (Py_ssize_t)(N * sizeof(int64_t)) && sb.len == (Py_ssize_t)(N * sizeof(double));
    const int64_t *taps = tb.buf;
    for (Py_ssize_t t = 0; ok && t < T; t++) {
        Py_ssize_t y0 = cy + taps[2 * t + 1] - search, x0 = cx + taps[2 * t] - search;
        ok = y0 >= 0 && x0 >= 0 && y0 + side <= wy && x0 + side <= wx;
    }
    double *acc = ok ? malloc(sizeof(double) * (size_t)places) : NULL;
    if (acc == NULL) {
        PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&lb); PyBuffer_Release(&tb);
        PyBuffer_Release(&bb); PyBuffer_Release(&sb);
        if (!ok) PyErr_SetString(PyExc_ValueError, "window_peaks: bad sizes or a tap beyond the windows");
        else PyErr_NoMemory();
        return NULL;
    }
    const double *values = vb.buf, *level = lb.buf;
    const uint8_t *valid = kb.buf;
    int64_t *best_out = bb.buf;
    double *s_out = sb.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        const double *v = values + s * P;
        const uint8_t *k = valid + s * P;
        double b = level[s];
        for (Py_ssize_t q = 0; q < places; q++) acc[q] = 0.0;
        for (Py_ssize_t t = 0; t < T; t++) {
            Py_ssize_t y0 = cy + taps[2 * t + 1] - search, x0 = cx + taps[2 * t] - search;
            for (Py_ssize_t i = 0; i < side; i++) {
                const double *vr = v + (y0 + i) * wx + x0;
                const uint8_t *kr = k + (y0 + i) * wx + x0;
                double *ar = acc + i * side;
                for (Py_ssize_t j = 0; j < side; j++) ar[j] += kr[j] ? vr[j] - b : 0.0;
            }
        }
        Py_ssize_t best = 0;
        for (Py_ssize_t q = 1; q < places; q++)
            if (acc[q] > acc[best] || (isnan(acc[q]) && !isnan(acc[best]))) best = q;
        best_out[s] = best;
        s_out[s] = acc[best];
    }
    Py_END_ALLOW_THREADS
    free(acc);
    PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&lb); PyBuffer_Release(&tb);
    PyBuffer_Release(&bb); PyBuffer_Release(&sb);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ ring_levels */

/* [lo, i) of v[lo..hi] holds the values < p (or <= p), the rest after them; returns i.  Branch-free
 * (every element swapped, the boundary moved by the comparison): on fresh data a branch a value
 * guessed wrong half the time cost ~4x more (the box-noise factor's two medians of 4096 values,
 * ~90 us a frame in the chain against ~25 us for the same call repeated on one array). */
static Py_ssize_t partition_below(double *v, Py_ssize_t lo, Py_ssize_t hi, double p, int or_equal) {
    Py_ssize_t i = lo;
    if (or_equal) {
        for (Py_ssize_t j = lo; j <= hi; j++) { double x = v[j]; v[j] = v[i]; v[i] = x; i += x <= p; }
    } else {
        for (Py_ssize_t j = lo; j <= hi; j++) { double x = v[j]; v[j] = v[i]; v[i] = x; i += x < p; }
    }
    return i;
}

/* The k-th smallest of v[0..n) (NaN-free), v reordered so that every v[i < k] <= v[k] <= every
 * v[i > k]: quickselect on the median of three, split three ways (below, equal to, above the
 * pivot), small ranges by insertion. */
static double select_kth(double *v, Py_ssize_t n, Py_ssize_t k) {
    Py_ssize_t lo = 0, hi = n - 1;
    while (hi - lo > 16) {
        double a = v[lo], b = v[lo + (hi - lo) / 2], c = v[hi];
        double p = a < b ? (b < c ? b : (a < c ? c : a)) : (a < c ? a : (b < c ? c : b));
        Py_ssize_t i = partition_below(v, lo, hi, p, 0);     /* [lo, i) < p: the pivot itself is not */
        if (k < i) { hi = i - 1; continue; }
        Py_ssize_t e = partition_below(v, i, hi, p, 1);      /* [i, e) == p: at least the pivot */
        if (k < e) return v[k];
        lo = e;
    }
    for (Py_ssize_t i = lo + 1; i <= hi; i++) {
        double x = v[i];
        Py_ssize_t j = i;
        for (; j > lo && v[j - 1] > x; j--) v[j] = v[j - 1];
        v[j] = x;
    }
    return v[k];
}

/* _background.median of v (n > 0; v reordered): the middle value, or the mean of the two. */
static double median_of(double *v, Py_ssize_t n) {
    Py_ssize_t k = n / 2;
    double hi = select_kth(v, n, k);
    if (n % 2) return hi;
    double lo = v[0];                         /* the largest of v[:k], all <= v[k] after the selection */
    for (Py_ssize_t i = 1; i < k; i++) if (v[i] > lo) lo = v[i];
    return (lo + hi) / 2.0;
}

/* median_abs_deviation(x (n,) f8, n) -> the median of |x - median(x)| (_background.median's medians,
 * exactly; n > 0): the box-noise factor's robust spread. */
static PyObject *py_median_abs_deviation(PyObject *self, PyObject *args) {
    Py_buffer xb;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "y*n", &xb, &n)) return NULL;
    double *v = (n > 0 && xb.len == (Py_ssize_t)(n * sizeof(double))) ? malloc(sizeof(double) * (size_t)n) : NULL;
    if (v == NULL) {
        PyBuffer_Release(&xb);
        if (n > 0 && xb.len == (Py_ssize_t)(n * sizeof(double))) return PyErr_NoMemory();
        PyErr_SetString(PyExc_ValueError, "median_abs_deviation: bad sizes");
        return NULL;
    }
    const double *x = xb.buf;
    double mad;
    Py_BEGIN_ALLOW_THREADS
    memcpy(v, x, sizeof(double) * (size_t)n);
    double med = median_of(v, n);
    for (Py_ssize_t i = 0; i < n; i++) v[i] = fabs(x[i] - med);
    mad = median_of(v, n);
    Py_END_ALLOW_THREADS
    free(v);
    PyBuffer_Release(&xb);
    return PyFloat_FromDouble(mad);
}

/* ring_levels(values (N, wy, wx) f8, valid u8, bg, noise (N,) f8, own_out (N,) f8, N, wy, wx, r) -> level:
 * _windowed._ring_shift's arithmetic: each window's border ring of width r (its top r rows, bottom
 * r rows, then the left and right r columns between them) less the window's mesh background; the
 * median of the valid ones over all windows; per window the mean of its valid ring pixels within
 * 3 noise of that median (0 when none), and over all windows their pooled mean (NaN when none);
 * sums in NumPy's pairwise order. */
static PyObject *py_ring_levels(PyObject *self, PyObject *args) {
    Py_buffer vb, kb, bb, nb_, ob;
    Py_ssize_t N, wy, wx, r;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*nnnn", &vb, &kb, &bb, &nb_, &ob, &N, &wy, &wx, &r)) return NULL;
    Py_ssize_t P = wy * wx, m = 2 * r * wx + 2 * r * (wy - 2 * r);
    int ok = N >= 0 && r >= 1 && wy > 2 * r && wx > 2 * r && vb.len == (Py_ssize_t)(N * P * sizeof(double))
             && kb.len == N * P && bb.len == (Py_ssize_t)(N * sizeof(double)) && nb_.len == bb.len
             && ob.len == bb.len;
    double *ring = NULL, *pool = NULL, *row = NULL, *totals = NULL;
    uint8_t *use = NULL;
    if (ok) {
        ring = malloc(sizeof(double) * (size_t)(N * m + 1));
        pool = malloc(sizeof(double) * (size_t)(N * m + 1));
        row = malloc(sizeof(double) * (size_t)(m + 1));
        totals = malloc(sizeof(double) * (size_t)(N + 1));
        use = malloc((size_t)(N * m + 1));
    }
    if (!ok || !ring || !pool || !row || !totals || !use) {
        free(ring); free(pool); free(row); free(totals); free(use);
        PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_);
        PyBuffer_Release(&ob);
        if (!ok) PyErr_SetString(PyExc_ValueError, "ring_levels: bad sizes");
        else PyErr_NoMemory();
        return NULL;
    }
    const double *values = vb.buf, *bg = bb.buf, *noise = nb_.buf;
    const uint8_t *valid = kb.buf;
    double *own = ob.buf;
    double level = NAN;
    Py_BEGIN_ALLOW_THREADS
    Py_ssize_t n_pool = 0;
    for (Py_ssize_t s = 0; s < N; s++) {
        const double *v = values + s * P;
        const uint8_t *k = valid + s * P;
        double *out = ring + s * m;
        uint8_t *u = use + s * m;
        Py_ssize_t c = 0;
        /* top rows, bottom rows, then the left and the right columns of the rows between */
        Py_ssize_t row0[4] = {0, wy - r, r, r}, row1[4] = {r, wy, wy - r, wy - r};
        Py_ssize_t col0[4] = {0, 0, 0, wx - r}, col1[4] = {wx, wx, r, wx};
        for (int part = 0; part < 4; part++)
            for (Py_ssize_t i = row0[part]; i < row1[part]; i++)
                for (Py_ssize_t j = col0[part]; j < col1[part]; j++, c++) {
                    out[c] = v[i * wx + j] - bg[s];
                    u[c] = k[i * wx + j];
                    if (u[c]) pool[n_pool++] = out[c];
                }
    }
    if (n_pool > 0) {
        double centre = median_of(pool, n_pool);
        Py_ssize_t count_all = 0;
        for (Py_ssize_t s = 0; s < N; s++) {
            const double *x = ring + s * m;
            const uint8_t *u = use + s * m;
            double lim = 3.0 * noise[s];
            Py_ssize_t count = 0;
            for (Py_ssize_t c = 0; c < m; c++) {
                int in = u[c] && fabs(x[c] - centre) <= lim;
                row[c] = in ? x[c] : 0.0;
                count += in;
            }
            totals[s] = pairwise_sum(row, m);
            own[s] = count > 0 ? totals[s] / (double)count : 0.0;
            count_all += count;
        }
        if (count_all) level = pairwise_sum(totals, N) / (double)count_all;
    } else {
        for (Py_ssize_t s = 0; s < N; s++) own[s] = 0.0;
    }
    Py_END_ALLOW_THREADS
    free(ring); free(pool); free(row); free(totals); free(use);
    PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_);
    PyBuffer_Release(&ob);
    return PyFloat_FromDouble(level);
}

/* ------------------------------------------------------------------ crowded_count */

/* crowded_count(values (N, wy, wx) f8, valid u8, bg, noise (N,) f8, dx, dy (N,) i8, counts_out (N,) i8,
 *               N, wy, wx, u0, u1, along_max, across_max, k): per window, the valid pixels brighter
 * than bg + k noise outside the footprint centred (dx, dy) px from the window's centre: |along| <=
 * along_max and |across| <= across_max, along = gx u0 + gy u1, across = gx u1 - gy u0 for the
 * pixel's offset (gx, gy) from that centre (_windowed._crowded's arithmetic). */
static PyObject *py_crowded_count(PyObject *self, PyObject *args) {
    Py_buffer vb, kb, bb, nb_, xb, yb, ob;
    Py_ssize_t N, wy, wx;
    double u0, u1, along_max, across_max, kf;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*w*nnnddddd", &vb, &kb, &bb, &nb_, &xb, &yb, &ob, &N, &wy, &wx, &u0, &u1,
                          &along_max, &across_max, &kf))
        return NULL;
    Py_ssize_t P = wy * wx;
    int ok = N >= 0 && vb.len == (Py_ssize_t)(N * P * sizeof(double)) && kb.len == N * P
             && bb.len == (Py_ssize_t)(N * sizeof(double)) && nb_.len == bb.len
             && xb.len == (Py_ssize_t)(N * sizeof(int64_t)) && yb.len == xb.len && ob.len == xb.len;
    if (ok) {
        const double *values = vb.buf, *bg = bb.buf, *noise = nb_.buf;
        const uint8_t *valid = kb.buf;
        const int64_t *dx = xb.buf, *dy = yb.buf;
        int64_t *counts = ob.buf;
        Py_ssize_t cy = (wy - 1) / 2, cx = (wx - 1) / 2;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t s = 0; s < N; s++) {
            const double *v = values + s * P;
            const uint8_t *k = valid + s * P;
            double level = bg[s] + kf * noise[s];
            int64_t c = 0;
            for (Py_ssize_t i = 0; i < wy; i++) {
                double gy = (double)(i - cy - dy[s]);
                for (Py_ssize_t j = 0; j < wx; j++) {
                    Py_ssize_t q = i * wx + j;
                    if (!k[q] || !(v[q] > level)) continue;
                    double gx = (double)(j - cx - dx[s]);
                    double along = gx * u0 + gy * u1, across = gx * u1 - gy * u0;
                    if (!(fabs(along) <= along_max && fabs(across) <= across_max)) c++;
                }
            }
            counts[s] = c;
        }
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&bb); PyBuffer_Release(&nb_);
    PyBuffer_Release(&xb); PyBuffer_Release(&yb); PyBuffer_Release(&ob);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "crowded_count: bad sizes");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ point_start */

/* point_start(values (N, S, S) f8, valid u8, bg, x0, y0 (N,) f8, p_out (N, 5) f8, N, S, sigma): the
 * point fits' start values (_fit._start_values_python's arithmetic, its sums in NumPy's order):
 * the background-subtracted centre of gravity of the central 3 x 3 (its negative excess 0) and the
 * window's excess flux (at least the 3 x 3's), the background, sigma. */
static PyObject *py_point_start(PyObject *self, PyObject *args) {
    Py_buffer vb, kb, bb, xb, yb, pb;
    Py_ssize_t N, S;
    double sigma;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*nnd", &vb, &kb, &bb, &xb, &yb, &pb, &N, &S, &sigma)) return NULL;
    Py_ssize_t P = S * S;
    int ok = N >= 0 && S >= 3 && vb.len == (Py_ssize_t)(N * P * sizeof(double)) && kb.len == N * P
             && bb.len == (Py_ssize_t)(N * sizeof(double)) && xb.len == bb.len && yb.len == bb.len
             && pb.len == (Py_ssize_t)(N * 5 * sizeof(double));
    double *excess = ok ? malloc(sizeof(double) * (size_t)(P + 1)) : NULL;
    if (!ok || !excess) {
        PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&bb); PyBuffer_Release(&xb);
        PyBuffer_Release(&yb); PyBuffer_Release(&pb);
        if (!ok) PyErr_SetString(PyExc_ValueError, "point_start: bad sizes");
        else PyErr_NoMemory();
        return NULL;
    }
    const double *values = vb.buf, *bg = bb.buf, *x0 = xb.buf, *y0 = yb.buf;
    const uint8_t *valid = kb.buf;
    double *p = pb.buf;
    Py_ssize_t half = S / 2;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        const double *v = values + s * P;
        const uint8_t *k = valid + s * P;
        for (Py_ssize_t q = 0; q < P; q++) excess[q] = k[q] ? v[q] - bg[s] : 0.0;
        double core[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) core[3 * i + j] = np_maximum(excess[(half - 1 + i) * S + half - 1 + j], 0.0);
        double total = 0.0 + pairwise_sum(core, 9);
        double safe = total > 0 ? total : 1.0;
        double dx = 0.0, dy = 0.0;
        if (total > 0) {
            double col_sum[3], row_sum[3];
            for (int j = 0; j < 3; j++) col_sum[j] = ((0.0 + core[j]) + core[3 + j]) + core[6 + j];
            for (int i = 0; i < 3; i++) row_sum[i] = ((0.0 + core[3 * i]) + core[3 * i + 1]) + core[3 * i + 2];
            dx = ((0.0 + col_sum[0] * -1.0) + col_sum[1] * 0.0) + col_sum[2] * 1.0;
            dy = ((0.0 + row_sum[0] * -1.0) + row_sum[1] * 0.0) + row_sum[2] * 1.0;
            dx /= safe;
            dy /= safe;
        }
        double flux = np_maximum(0.0 + pairwise_sum(excess, P), total);
        double *o = p + 5 * s;
        o[0] = (x0[s] + (double)half) + dx;
        o[1] = (y0[s] + (double)half) + dy;
        o[2] = np_maximum(flux, 1e-9);
        o[3] = bg[s];
        o[4] = sigma;
    }
    Py_END_ALLOW_THREADS
    free(excess);
    PyBuffer_Release(&vb); PyBuffer_Release(&kb); PyBuffer_Release(&bb); PyBuffer_Release(&xb);
    PyBuffer_Release(&yb); PyBuffer_Release(&pb);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ cho_solve */

/* cho_solve(low (N, k, k) f8, y (N, k, m) f8 in place, N, k, m): solve (L L^T) x = y for each
 * of the N systems, x written over y.  The operations of _fit._cho_solve_python in its
 * order, element by element: y_i /= L_ii, then y_r -= L_ri y_i for r > i (forward); y_i /= L_ii,
 * then y_r -= L_ir y_i for r < i (back); each product rounded before its subtraction (no
 * fused multiply-add: the C99 mode and the baseline x86-64 target contract none), so the
 * results are NumPy's to the bit (tests/test_extract_kernels.py). */
static PyObject *py_cho_solve(PyObject *self, PyObject *args) {
    Py_buffer lb, yb;
    Py_ssize_t N;
    int k, m;
    if (!PyArg_ParseTuple(args, "y*w*nii", &lb, &yb, &N, &k, &m)) return NULL;
    const double *low = lb.buf;
    double *y = yb.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t s = 0; s < N; s++) {
        const double *L = low + s * (Py_ssize_t)k * k;
        double *Y = y + s * (Py_ssize_t)k * m;
        for (int i = 0; i < k; i++) {
            double d = L[i * k + i];
            double *yi = Y + (Py_ssize_t)i * m;
            for (int c = 0; c < m; c++) yi[c] /= d;
            for (int r = i + 1; r < k; r++) {
                double l = L[r * k + i];
                double *yr = Y + (Py_ssize_t)r * m;
                for (int c = 0; c < m; c++) yr[c] -= l * yi[c];
            }
        }
        for (int i = k - 1; i >= 0; i--) {
            double d = L[i * k + i];
            double *yi = Y + (Py_ssize_t)i * m;
            for (int c = 0; c < m; c++) yi[c] /= d;
            for (int r = 0; r < i; r++) {
                double l = L[i * k + r];
                double *yr = Y + (Py_ssize_t)r * m;
                for (int c = 0; c < m; c++) yr[c] -= l * yi[c];
            }
        }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&lb);
    PyBuffer_Release(&yb);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ persistent pixels (_artifacts) */

/* First index of the sorted keys[0..T) not below q. */
static Py_ssize_t lower_bound_i8(const int64_t *keys, Py_ssize_t T, int64_t q) {
    Py_ssize_t lo = 0, hi = T;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (keys[mid] < q) lo = mid + 1; else hi = mid;
    }
    return lo;
}

/* persistent_pairs(table_keys (T,) i8 sorted, table_frames (T,) i8, T, keys (N,) i8, N, near (9,) i8,
 * oldest, window, min_count, stamp (window,) i8 work, out_star (N window,) i8, out_frame (N window,)
 * i8) -> P, or -1 when a remembered frame lies outside (oldest, oldest + window]:
 * PersistentPixels._pairs_python's result: each detection n with each remembered frame after ``oldest``
 * that had a detection at one of keys[n] + near[0..9), for the detections with at least
 * min_count such frames; star-major, frames increasing (the order of np.unique on
 * star * span + frame).  A frame is marked in ``stamp`` with the detection's number + 1, so
 * the work array is never cleared. */
static PyObject *py_persistent_pairs(PyObject *self, PyObject *args) {
    Py_buffer tk_b, tf_b, k_b, near_b, st_b, os_b, of_b;
    Py_ssize_t T, N;
    long long oldest, window, min_count;
    if (!PyArg_ParseTuple(args, "y*y*ny*ny*LLLw*w*w*", &tk_b, &tf_b, &T, &k_b, &N, &near_b, &oldest, &window,
                          &min_count, &st_b, &os_b, &of_b)) return NULL;
    Py_ssize_t P = 0;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    const int64_t *tk = tk_b.buf, *tf = tf_b.buf, *keys = k_b.buf, *near = near_b.buf;
    int64_t *stamp = st_b.buf, *out_star = os_b.buf, *out_frame = of_b.buf;
    for (long long w = 0; w < window; w++) stamp[w] = 0;
    for (Py_ssize_t n = 0; n < N && !bad; n++) {
        long long count = 0;
        for (int d = 0; d < 9; d++) {
            int64_t q = keys[n] + near[d];
            for (Py_ssize_t j = lower_bound_i8(tk, T, q); j < T && tk[j] == q; j++) {
                long long f = tf[j] - oldest - 1;
                if (f < 0) continue;                        /* older than the window */
                if (f >= window) { bad = 1; break; }
                if (stamp[f] != n + 1) { stamp[f] = n + 1; count++; }
            }
        }
        if (count < min_count || bad) continue;
        for (long long w = 0; w < window; w++)
            if (stamp[w] == n + 1) { out_star[P] = n; out_frame[P] = oldest + 1 + w; P++; }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&tk_b); PyBuffer_Release(&tf_b); PyBuffer_Release(&k_b); PyBuffer_Release(&near_b);
    PyBuffer_Release(&st_b); PyBuffer_Release(&os_b); PyBuffer_Release(&of_b);
    return PyLong_FromSsize_t(bad ? -1 : P);
}

/* persistent_merge(table_keys (T,) i8 sorted, table_frames (T,) i8, T, new_keys (U,) i8 sorted, U,
 * oldest, frame, out_keys (T + U,) i8, out_frames (T + U,) i8) -> the new table's length: the
 * entries after ``oldest`` and the new keys (each with ``frame``) merged in key order, an old
 * entry before a new one of the same key (a stable sort of the old live entries followed by
 * the new ones gives this order). */
static PyObject *py_persistent_merge(PyObject *self, PyObject *args) {
    Py_buffer tk_b, tf_b, nk_b, ok_b, of_b;
    Py_ssize_t T, U;
    long long oldest, frame;
    if (!PyArg_ParseTuple(args, "y*y*ny*nLLw*w*", &tk_b, &tf_b, &T, &nk_b, &U, &oldest, &frame, &ok_b, &of_b))
        return NULL;
    Py_ssize_t m = 0;
    Py_BEGIN_ALLOW_THREADS
    const int64_t *tk = tk_b.buf, *tf = tf_b.buf, *nk = nk_b.buf;
    int64_t *ok = ok_b.buf, *of = of_b.buf;
    Py_ssize_t i = 0, u = 0;
    while (i < T || u < U) {
        if (i < T && tf[i] <= oldest) { i++; continue; }   /* no longer in the window */
        if (i < T && (u >= U || tk[i] <= nk[u])) { ok[m] = tk[i]; of[m] = tf[i]; i++; }
        else { ok[m] = nk[u]; of[m] = frame; u++; }
        m++;
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&tk_b); PyBuffer_Release(&tf_b); PyBuffer_Release(&nk_b);
    PyBuffer_Release(&ok_b); PyBuffer_Release(&of_b);
    return PyLong_FromSsize_t(m);
}

static PyMethodDef methods[] = {
    {"streak_equations", py_streak_equations, METH_VARARGS, "Normal equations of the smeared-PSF model."},
    {"streak_fit", py_streak_fit, METH_VARARGS, "Levenberg-Marquardt fits of the smeared-PSF model."},
    {"gauss_fit", py_gauss_fit, METH_VARARGS, "Gauss-Newton fits of the pixel-integrated Gaussian."},
    {"gauss_normal", py_gauss_normal, METH_VARARGS, "Normal equations of the pixel-integrated Gaussian."},
    {"block_stats", py_block_stats, METH_VARARGS, "Median, MAD and clipped RMS of block samples."},
    {"streak_footprint", py_streak_footprint, METH_VARARGS, "The streak fits' footprints, peaks and their flags."},
    {"grid_box_sums", py_grid_box_sums, METH_VARARGS, "3 x 3 sums around a regular grid of pixels."},
    {"value_step", py_value_step, METH_VARARGS, "Smallest positive step between sorted samples."},
    {"median3", py_median3, METH_VARARGS, "3 x 3 median of a grid, edges extended."},
    {"mesh_at", py_mesh_at, METH_VARARGS, "Bilinear background and noise between block centres."},
    {"candidates", py_candidates, METH_VARARGS, "Flat indices of the pixels above their block's level."},
    {"local_max", py_local_max, METH_VARARGS, "Candidates that are the maximum of their 3 x 3 neighbourhood."},
    {"neighbours", py_neighbours, METH_VARARGS, "The 8 neighbours of pixels and whether they are inside."},
    {"box_sums", py_box_sums, METH_VARARGS, "3 x 3 box sums and counts around pixels."},
    {"tap_sum", py_tap_sum, METH_VARARGS, "The line filter's shifted sums, tile by tile."},
    {"line_filter", py_line_filter, METH_VARARGS, "The whole line filter, row by row."},
    {"box3", py_box3, METH_VARARGS, "3 x 3 mean of a float32 image, edges extended."},
    {"region_shape", py_region_shape, METH_VARARGS, "The trail test's region: its extent along and across."},
    {"label_runs", py_label_runs, METH_VARARGS, "8-connected components of sorted candidate pixels."},
    {"suppress", py_suppress, METH_VARARGS, "Greedy suppression of peaks in a stronger one's footprint."},
    {"streak_peaks", py_streak_peaks, METH_VARARGS, "The line filter's peaks, their components and extents."},
    {"point_objects", py_point_objects, METH_VARARGS, "Point sources from candidates: peaks, box test, one a component."},
    {"erf_array", py_erf_array, METH_VARARGS, "erf of a float64 array."},
    {"cho_solve", py_cho_solve, METH_VARARGS, "Cholesky substitutions of stacked systems, in place."},
    {"grid_box_z", py_grid_box_z, METH_VARARGS, "Whitened 3 x 3 sums on a regular grid of the mesh."},
    {"median_abs_deviation", py_median_abs_deviation, METH_VARARGS, "Median of |x - median(x)|."},
    {"streak_start", py_streak_start, METH_VARARGS, "Start parameters of the streak fits."},
    {"window_peaks", py_window_peaks, METH_VARARGS, "The line filter's maximum near each window's centre."},
    {"ring_levels", py_ring_levels, METH_VARARGS, "Background levels of the windows' border rings."},
    {"gather", py_gather, METH_VARARGS, "Rectangular pixel windows as float64 and their validity."},
    {"crowded_count", py_crowded_count, METH_VARARGS, "Bright pixels outside each window's footprint."},
    {"point_start", py_point_start, METH_VARARGS, "Start values of the point fits."},
    {"too_sharp", py_too_sharp, METH_VARARGS, "Peaks sharper than the PSF allows."},
    {"component_stats", py_component_stats, METH_VARARGS, "Per-star sums over the stars' pixels."},
    {"persistent_pairs", py_persistent_pairs, METH_VARARGS, "Detections with the remembered frames near their pixel."},
    {"persistent_merge", py_persistent_merge, METH_VARARGS, "The remembered detections with a frame's added."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_ckernels", "shipstar's extraction kernels", -1, methods};

PyMODINIT_FUNC PyInit__ckernels(void) { return module_with_source_digest(PyModule_Create(&module)); }
