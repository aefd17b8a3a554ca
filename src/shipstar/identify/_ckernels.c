/* Compiled hot loops of star identification (shipstar.identify._ckernels).
 *
 * Plain C99 on Python's buffer protocol (no NumPy headers); the argument checks (dtype,
 * C order, sizes) are in shipstar/identify/_kernels.py, the only caller.
 *
 * lis_solve:  lost-in-space from the pattern search to the accepted match: 4-star
 *             patterns of the brightest stars in batches, edge ratios, probe keys, the
 *             two-level key index, the exact re-check and star pairing, then per
 *             candidate QUEST, prediction, association, focal-scale / radial refit and
 *             the false-match probability (_lost_in_space.py's docstring and
 *             docs/identification.md give the rules; this is the same computation).
 * track_solve: tracking from a prior attitude (_tracking.py's docstring: prediction,
 *             common shift, shifted pairs, fit and fine gate, vote).
 * lis_pinhole / track_pinhole: the same from pixel centroids of a camera without
 *             distortion, unprojection and result arrays included (one call per frame).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "../_csource.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define RAD2ASEC 206264.80624709636
#define N_GATES 4
static const double GATE_FRACTIONS[N_GATES] = {1.0, 0.5, 0.25, 0.125};

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

#include "../_cquest.h"    /* QUEST (quest_b, wahba): shared with shipstar.attitude */

/* ---------------------------------------------------------------------------------
 * Binomial tail P(X >= k), X ~ Binomial(n, p) (scipy.special.bdtrc(k - 1, n, p))
 * ------------------------------------------------------------------------------- */

static double binom_tail(long n, long k, double p)
{
    if (k <= 0) return 1.0;
    if (k > n) return 0.0;
    if (p <= 0.0) return 0.0;
    if (p >= 1.0) return 1.0;
    /* sum of the terms i = k..n, relative to the first (recurrence), then scaled */
    double r = p / (1.0 - p), rel = 1.0, sum = 1.0;
    for (long i = k; i < n; i++) {
        rel *= r * (double)(n - i) / (double)(i + 1);
        sum += rel;
        if (rel < 1e-17 * sum) break;
    }
    double log_first = lgamma((double)n + 1.0) - lgamma((double)k + 1.0) - lgamma((double)(n - k) + 1.0)
                       + (double)k * log(p) + (double)(n - k) * log1p(-p);
    double v = exp(log_first + log(sum));
    return v < 1.0 ? v : 1.0;
}

/* min_j factors_j P(Bin(n_j, p1_j) >= k_j) over the gates, lazily (_verify.min_chance) */
static double min_chance(const double *factors, const long *n, const long *k, const double *p1,
                         double stop)
{
    double first = factors[0] * binom_tail(n[0], k[0], p1[0]);
    if (first <= stop) return first;
    double best = first;
    for (int g = 1; g < N_GATES; g++) {
        double v = factors[g] * binom_tail(n[g], k[g], p1[g]);
        if (v < best) best = v;
    }
    return best;
}

/* ---------------------------------------------------------------------------------
 * Scatter screen: a pair far outside the frame's own centroid scatter is not matched
 * ------------------------------------------------------------------------------- */

/* The fine gate is set by the centroid-error *bound*; a frame's real scatter is often
 * several times smaller.  A detection that is not the catalog star (a false star where
 * the star itself was not detected) can then fall inside the fine gate but far outside
 * the scatter of the other pairs.  With r2_q the upper-quartile squared residual of the
 * k pairs, a pair with d2 > SCREEN_FACTOR r2_q is not matched.  For Gaussian centroid
 * errors (r^2 / 2 sigma^2 ~ Exp(1), r2_q = 2 sigma^2 ln 4) that is r > 7.4 sigma, a
 * chance of 1e-12 for a true pair; real frames have heavier tails (faint stars, blends:
 * the rendered sessions of tests/golden reach 10.2 r2_q), hence 20, which still drops
 * a false star 1.2 px from a missing star's place among pairs of 0.2 px scatter
 * (bench_identify's seed004 stream, 34 r2_q).  The upper quartile, not the median, so
 * that the noisier (fainter) stars of a frame set the scale.  Only with
 * SCREEN_MIN_PAIRS pairs or more, never below (gate / 8)^2 (the smallest gate of the
 * chance model), so never more than a quarter of the pairs. */
#define SCREEN_MIN_PAIRS 8
#define SCREEN_FACTOR 20.0

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : (x > y);
}

/* pairs (img, cat, d2) kept in place; returns their number (k when none is dropped).
 * scratch: k doubles. */
static long scatter_screen(long *img, long *cat, double *d2, long k, double gate, double *scratch)
{
    if (k < SCREEN_MIN_PAIRS) return k;
    memcpy(scratch, d2, k * sizeof(double));
    qsort(scratch, k, sizeof(double), cmp_d);
    double lim = SCREEN_FACTOR * scratch[(3 * (k - 1)) / 4];
    double floor2 = 0.015625 * gate * gate;
    if (lim < floor2) lim = floor2;
    if (!(scratch[k - 1] > lim)) return k;
    long out = 0;
    for (long i = 0; i < k; i++)
        if (d2[i] <= lim) { img[out] = img[i]; cat[out] = cat[i]; d2[out] = d2[i]; out++; }
    return out;
}

/* Pairs (img, j, d2) kept in place whose detection (row img of t) is the nearest to the
 * prediction by C of the catalog star (row j of u (., 3)) also among the detections
 * beyond the used ones (t_more: the fainter rows the fit does not see); returns their
 * number.  The true tangent plane of t and t_more is t s (1 + k1 |t|^2) (tracking: s 1,
 * k1 0, t already at its focal scale).  The used detection of a pair that loses is not
 * the star: the star's own detection ranked beyond the used ones and a false one among
 * them fell inside its fine gate (bench_identify's seed004 stream, frame 1325: a false
 * star ranked 2nd, 1.24 px from the place of a catalog star detected 63rd; 5 sigma of
 * the frame's 0.24 px scatter per axis, 11.7 times the pairs' upper-quartile squared
 * residual, inside the fine gate and the scatter screen: it was named).
 * Nearer, not merely inside the gate: a faint neighbour of a true star (an uncatalogued
 * star, noise) must not cost the star its name. */
static long unused_nearer(const double *t, const double *t_more, long n_more, double s, double k1,
                          const double *u, long *img, long *j, double *d2, long k, const double *C)
{
    if (n_more <= 0) return k;
    long out = 0;
    for (long i = 0; i < k; i++) {
        const double *v = u + 3 * j[i];
        double w0 = v[0] * C[0] + v[1] * C[3] + v[2] * C[6];
        double ty = (v[0] * C[1] + v[1] * C[4] + v[2] * C[7]) / w0;
        double tz = (v[0] * C[2] + v[1] * C[5] + v[2] * C[8]) / w0;
        double a = t[2 * img[i]], b = t[2 * img[i] + 1], f = s;
        if (k1 != 0.0) f = s * (1.0 + k1 * (a * a + b * b));
        double ey = a * f - ty, ez = b * f - tz, own = ey * ey + ez * ez;
        int nearer = 0;
        for (long r = 0; r < n_more && !nearer; r++) {
            a = t_more[2 * r]; b = t_more[2 * r + 1]; f = s;
            if (k1 != 0.0) f = s * (1.0 + k1 * (a * a + b * b));
            double dy = a * f - ty, dz = b * f - tz;
            nearer = dy * dy + dz * dz < own;
        }
        if (!nearer) { img[out] = img[i]; j[out] = j[i]; d2[out] = d2[i]; out++; }
    }
    return out;
}

/* ---------------------------------------------------------------------------------
 * Sky grid and prediction
 * ------------------------------------------------------------------------------- */

static long cell_of_one(const double *v, long n)
{
    double x = v[0], y = v[1], z = v[2], ax = fabs(x), ay = fabs(y), az = fabs(z), m, a, b;
    int major, positive;
    if (ax >= ay && ax >= az) { major = 0; m = ax; a = y; b = z; positive = x >= 0; }
    else if (ay >= az) { major = 1; m = ay; a = x; b = z; positive = y >= 0; }
    else { major = 2; m = az; a = x; b = y; positive = z >= 0; }
    long face = 2 * major + (positive ? 0 : 1);
    const double qp = M_PI / 4;
    double fi = (atan(a / m) / qp + 1.0) * 0.5 * (double)n;
    double fj = (atan(b / m) / qp + 1.0) * 0.5 * (double)n;
    long i = (long)fi, j = (long)fj;      /* truncation as Python's int() */
    if (i < 0) i = 0;
    if (i > n - 1) i = n - 1;
    if (j < 0) j = 0;
    if (j > n - 1) j = n - 1;
    return (face * n + i) * n + j;
}

/* row q of a cell list stored as uint16 (ci16) or uint32 */
static inline long cell_row(const void *ci, int ci16, long q)
{
    return ci16 ? (long)((const uint16_t *)ci)[q] : (long)((const uint32_t *)ci)[q];
}

/* whether a cell list of cell_start's last offset M rows is uint16 (1), uint32 (0) or
 * neither (-1), from its length in bytes */
static int cell_list_u16(const Py_buffer *cs, const Py_buffer *ci)
{
    Py_ssize_t n = cs->len / (Py_ssize_t)sizeof(int32_t);
    if (n < 1) return -1;
    Py_ssize_t M = ((const int32_t *)cs->buf)[n - 1];
    if (M < 0) return -1;
    if (ci->len == 2 * M) return 1;
    return ci->len == 4 * M ? 0 : -1;
}

typedef struct {
    const double *u64;          /* (S, 3) */
    const float *u32;           /* (S, 3) */
    const void *pstars;         /* (P, 4), uint16 (pstars16) or uint32 */
    int pstars16;
    const uint16_t *key_lo;     /* (P,) */
    const int32_t *key_hi_start;
    const int32_t *cell_start;
    const void *cell_index;     /* (M,): uint16 (ci16, as stored for up to 65536 stars) or uint32 */
    int ci16;
    const double *cell_u;       /* (M, 3): u64[cell_index], read in cell order */
    const uint16_t *size_q;     /* (P,): each pattern's largest edge in size_quantum steps */
    double size_quantum;        /* rad */
    long grid_n, key_bits, lo_bits, bins, n_patterns_db;
    long n_stars;               /* S: a pattern's star rows are checked against it as read */
} Db;

/* the largest edge (rad) of the pattern of star rows ps: the smallest of its six dot
 * products of float32 vectors, as the look-up computes it (PAIR_A / PAIR_B order) */
static const int PAIR_A[6] = {0, 0, 0, 1, 1, 2};
static const int PAIR_B[6] = {1, 2, 3, 2, 3, 3};
static double clip1(double x) { return x < -1.0 ? -1.0 : (x > 1.0 ? 1.0 : x); }

static double largest_edge(const float *u32, const uint32_t ps[4], double *dots, int *emin)
{
    double dmin = INFINITY;
    *emin = 0;
    for (int e = 0; e < 6; e++) {
        const float *a = u32 + 3 * ps[PAIR_A[e]], *b = u32 + 3 * ps[PAIR_B[e]];
        dots[e] = (double)a[0] * (double)b[0] + (double)a[1] * (double)b[1] + (double)a[2] * (double)b[2];
        if (clip1(dots[e]) < dmin) { dmin = clip1(dots[e]); *emin = e; }
    }
    return acos(dmin);
}

/* the stored size step of a pattern whose largest edge is `largest` (rad) */
static uint16_t size_step(double largest, double quantum)
{
    double q = floor(largest / quantum);
    return q >= 65535.0 ? 65535 : (q <= 0.0 ? 0 : (uint16_t)q);
}

/* the 4 star rows of pattern `row` */
static inline void pattern_row(const Db *db, long row, uint32_t ps[4])
{
    if (db->pstars16) {
        const uint16_t *p = (const uint16_t *)db->pstars + 4 * row;
        ps[0] = p[0]; ps[1] = p[1]; ps[2] = p[2]; ps[3] = p[3];
    } else {
        memcpy(ps, (const uint32_t *)db->pstars + 4 * row, 4 * sizeof(uint32_t));
    }
}

/* pattern_row, and 1 if its four star rows are inside the star arrays (a database mapped
 * from its cache file has its star rows checked on a sample when it is opened, not every
 * row: a row out of range is skipped here, as a corrupt one could never match) */
static inline int pattern_row_in(const Db *db, long row, uint32_t ps[4])
{
    pattern_row(db, row, ps);
    uint32_t mx = ps[0] > ps[1] ? ps[0] : ps[1], my = ps[2] > ps[3] ? ps[2] : ps[3];
    return (long)(mx > my ? mx : my) < db->n_stars;
}

typedef struct {
    long m, cap, n_in;
    long *rows;                 /* database rows */
    long *qpos;                 /* positions in the cell arrays */
    double *ty, *tz;
    long *ord, *best;           /* scratch of associate() */
    double *sty;
} Pred;

static int pred_reserve(Pred *p, long m)
{
    if (m <= p->cap) return 0;
    long cap = m + 64;
    long *r = realloc(p->rows, cap * sizeof(long));
    if (!r) return -1;
    p->rows = r;
    double *a = realloc(p->ty, cap * sizeof(double));
    if (!a) return -1;
    p->ty = a;
    a = realloc(p->tz, cap * sizeof(double));
    if (!a) return -1;
    p->tz = a;
    a = realloc(p->sty, cap * sizeof(double));
    if (!a) return -1;
    p->sty = a;
    r = realloc(p->ord, cap * sizeof(long));
    if (!r) return -1;
    p->ord = r;
    r = realloc(p->qpos, cap * sizeof(long));
    if (!r) return -1;
    p->qpos = r;
    r = realloc(p->best, cap * sizeof(long));
    if (!r) return -1;
    p->best = r;
    p->cap = cap;
    return 0;
}

static void pred_free(Pred *p)
{
    free(p->rows); free(p->ty); free(p->tz); free(p->ord); free(p->best); free(p->sty); free(p->qpos);
    p->rows = NULL; p->ty = p->tz = p->sty = NULL; p->ord = p->best = p->qpos = NULL;
    p->cap = p->m = 0;
}

/* box: centre y, centre z, half y, half z */
static int predict(const Db *db, const double *C, const double *box, double margin, Pred *out)
{
    double bore[3] = {C[0], C[3], C[6]};
    long c = cell_of_one(bore, db->grid_n);
    long a = db->cell_start[c], e = db->cell_start[c + 1];
    if (pred_reserve(out, e - a) < 0) return -1;
    long m = 0, n_in = 0;
    for (long q = a; q < e; q++) {
        long r = cell_row(db->cell_index, db->ci16, q);
        const double *u = db->cell_u + 3 * q;
        double w0 = u[0] * C[0] + u[1] * C[3] + u[2] * C[6];
        double w1 = u[0] * C[1] + u[1] * C[4] + u[2] * C[7];
        double w2 = u[0] * C[2] + u[1] * C[5] + u[2] * C[8];
        double ty = w1 / w0, tz = w2 / w0;
        double oy = fabs(ty - box[0]), oz = fabs(tz - box[1]);
        if (oy <= box[2] + margin && oz <= box[3] + margin) {
            out->rows[m] = r; out->qpos[m] = q; out->ty[m] = ty; out->tz[m] = tz; m++;
            if (oy <= box[2] && oz <= box[3]) n_in++;
        }
    }
    out->m = m;
    out->n_in = n_in;
    return 0;
}

static void reproject(const Db *db, const double *C, const double *box, Pred *p)
{
    long n_in = 0;
    for (long q = 0; q < p->m; q++) {
        const double *u = db->cell_u + 3 * p->qpos[q];
        double w0 = u[0] * C[0] + u[1] * C[3] + u[2] * C[6];
        double w1 = u[0] * C[1] + u[1] * C[4] + u[2] * C[7];
        double w2 = u[0] * C[2] + u[1] * C[5] + u[2] * C[8];
        p->ty[q] = w1 / w0;
        p->tz[q] = w2 / w0;
        if (fabs(p->ty[q] - box[0]) <= box[2] && fabs(p->tz[q] - box[1]) <= box[3]) n_in++;
    }
    p->n_in = n_in;
}

static int cmp_by_key(const void *a, const void *b);
static const double *SORT_KEY;          /* qsort has no context argument in C99 */

/* ord: the predictions sorted by ty (ties by index), sty their ty */
static void sort_by_ty(const Pred *p, long *ord, double *sty)
{
    long m = p->m;
    for (long q = 0; q < m; q++) ord[q] = q;
    if (m > 48) {
        SORT_KEY = p->ty;
        qsort(ord, m, sizeof(long), cmp_by_key);
    } else {
        for (long i = 1; i < m; i++) {
            long x = ord[i];
            double kx = p->ty[x];
            long j = i - 1;
            while (j >= 0 && p->ty[ord[j]] > kx) { ord[j + 1] = ord[j]; j--; }
            ord[j + 1] = x;
        }
    }
    for (long q = 0; q < m; q++) sty[q] = p->ty[ord[q]];
}

static int cmp_by_key(const void *a, const void *b)
{
    long x = *(const long *)a, y = *(const long *)b;
    double kx = SORT_KEY[x], ky = SORT_KEY[y];
    if (kx != ky) return kx < ky ? -1 : 1;
    return x < y ? -1 : (x > y);
}

/* Nearest prediction of each measured star (ty, tz (n,)) within gate, one to one: the
 * closer star keeps a contested prediction (ties: the earlier row).  Writes the rows
 * (ascending), prediction indices and squared distances; returns their number.
 * The nearest prediction overall is within the gate exactly when one is, so only the
 * predictions whose ty is within the gate are looked at (sorted by ty: a band); ties
 * go to the lower prediction index, as argmin.
 * best_k, ord: p->m longs scratch, sty: p->m doubles scratch.
 * lost (may be NULL): (row, j) of the stars that lost a contested prediction. */
static long associate(const double *ty, const double *tz, long n, const Pred *p, double gate,
                      long *img, long *jj, double *d2, long *best_k, long *ord, double *sty,
                      long *lost_row, long *lost_j, long *n_lost)
{
    long cnt = 0;
    double g2 = gate * gate;
    if (n_lost) *n_lost = 0;
    if (p->m == 0) return 0;
    int dup = 0;
    long m = p->m;
    sort_by_ty(p, ord, sty);
    for (long q = 0; q < m; q++) best_k[q] = -1;
    for (long i = 0; i < n; i++) {
        double y = ty[i], lo_y = y - gate, hi_y = y + gate;
        if (!(lo_y <= hi_y)) continue;                      /* NaN */
        long a = 0, b = m;                                  /* first sty >= lo_y */
        while (a < b) {
            long c = (a + b) >> 1;
            if (sty[c] < lo_y) a = c + 1; else b = c;
        }
        double best = INFINITY;
        long bj = -1;
        for (long s = a; s < m && sty[s] <= hi_y; s++) {
            long q = ord[s];
            double dy = y - p->ty[q], dz = tz[i] - p->tz[q];
            double d = dy * dy + dz * dz;
            if (d < best || (d == best && q < bj)) { best = d; bj = q; }
        }
        if (bj >= 0 && best <= g2) {
            img[cnt] = i; jj[cnt] = bj; d2[cnt] = best;
            long prev = best_k[bj];
            if (prev < 0) best_k[bj] = cnt;
            else {
                dup = 1;
                if (best < d2[prev]) best_k[bj] = cnt;
            }
            cnt++;
        }
    }
    if (!dup) return cnt;
    long out = 0;
    for (long c = 0; c < cnt; c++) {
        if (best_k[jj[c]] == c) {
            img[out] = img[c]; jj[out] = jj[c]; d2[out] = d2[c]; out++;
        } else if (n_lost) {
            lost_row[*n_lost] = img[c]; lost_j[*n_lost] = jj[c]; (*n_lost)++;
        }
    }
    return out;
}

/* ---------------------------------------------------------------------------------
 * Lost-in-space
 * ------------------------------------------------------------------------------- */

/* the 24 permutations of four stars (itertools order) and their edge maps */
static int PERM[24][4];
static int PERM_EDGES[24][6];
static void init_perms(void)
{
    int k = 0;
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++)
            for (int c = 0; c < 4; c++)
                for (int d = 0; d < 4; d++) {
                    if (a == b || a == c || a == d || b == c || b == d || c == d) continue;
                    PERM[k][0] = a; PERM[k][1] = b; PERM[k][2] = c; PERM[k][3] = d; k++;
                }
    for (int p = 0; p < 24; p++)
        for (int e = 0; e < 6; e++) {
            int i = PERM[p][PAIR_A[e]], j = PERM[p][PAIR_B[e]];
            if (i > j) { int t = i; i = j; j = t; }
            for (int f = 0; f < 6; f++)
                if (PAIR_A[f] == i && PAIR_B[f] == j) PERM_EDGES[p][e] = f;
        }
}

static void sort6(double *e)
{
    for (int i = 1; i < 6; i++) {
        double x = e[i];
        int j = i - 1;
        while (j >= 0 && e[j] > x) { e[j + 1] = e[j]; j--; }
        e[j + 1] = x;
    }
}

typedef struct {
    long owner;                 /* pattern row in the batch */
    long order;                 /* discovery order (stable sort) */
    double err;
    double scale;
    long cat[4];
} Cand;

static int cand_cmp(const void *a, const void *b)
{
    const Cand *x = a, *y = b;
    if (x->owner != y->owner) return x->owner < y->owner ? -1 : 1;
    if (x->err != y->err) return x->err < y->err ? -1 : 1;
    return x->order < y->order ? -1 : (x->order > y->order);
}

typedef struct {
    /* field: usable stars (brightest first) */
    long n;
    const double *t;            /* (n, 2) nominal tangent plane */
    const double *u0;           /* (n, 3) unit vectors at scale 1 */
    const double *t_more;       /* (n_more, 2): the detections beyond the n usable ones */
    long n_more;
    /* parameters */
    double e_edge, max_edge, min_edge, model_tol, ftol, error_rad, half_diag, gate_fine,
        area0, p_false_max, max_time_s, t_start;
    double bounds[4];
    int fit, fit_radial;
    long min_matches, max_candidates;
    long db_n_patterns;
    /* counters */
    long n_verified, n_patterns;
    /* scratch */
    double *ty, *tz, *w, *v;    /* (n,), (n,), (n, 3), (n, 3) */
    long *img, *jj, *img2, *jj2, *cat, *cat2, *lost_r, *lost_j;
    double *d2, *d2b;
    Pred pred;
    /* result */
    double C[9], s, k1, p_false, rms;
    long n_match;
} Lis;

static void lis_box(const Lis *L, double s, double *box)
{
    const double *b = L->bounds;
    box[0] = 0.5 * (b[0] + b[1]) * s; box[1] = 0.5 * (b[2] + b[3]) * s;
    box[2] = 0.5 * (b[1] - b[0]) * s; box[3] = 0.5 * (b[3] - b[2]) * s;
}

/* unit vector of usable star i at focal scale s and radial k1 (field.unit) */
static void unit_of(const Lis *L, long i, double s, double k1, double *out)
{
    if (s == 1.0 && k1 == 0.0) {
        out[0] = L->u0[3 * i]; out[1] = L->u0[3 * i + 1]; out[2] = L->u0[3 * i + 2];
        return;
    }
    double ty = L->t[2 * i], tz = L->t[2 * i + 1], f = s;
    if (k1 != 0.0) f = s * (1.0 + k1 * (ty * ty + tz * tz));
    ty *= f; tz *= f;
    double nn = sqrt(1.0 + ty * ty + tz * tz);
    out[0] = 1.0 / nn; out[1] = ty / nn; out[2] = tz / nn;
}

static void t_true_all(const Lis *L, double s, double k1, double *ty, double *tz)
{
    for (long i = 0; i < L->n; i++) {
        double a = L->t[2 * i], b = L->t[2 * i + 1], f = s;
        if (k1 != 0.0) f = s * (1.0 + k1 * (a * a + b * b));
        ty[i] = a * f; tz[i] = b * f;
    }
}

/* _verify.refine: attitude and (fit) focal scale / radial term from k matched stars */
static void refine(Lis *L, const Db *db, const long *img, const long *cat, long k, double *s_io,
                   double *k1_io, int fit_scale, int fit_k1, double *C)
{
    double s = *s_io, k1 = *k1_io;
    for (long i = 0; i < k; i++) {
        unit_of(L, img[i], s, k1, L->w + 3 * i);
        memcpy(L->v + 3 * i, db->u64 + 3 * cat[i], 3 * sizeof(double));
    }
    wahba(L->w, L->v, (int)k, NULL, C);
    if (!fit_scale || k < 3) return;
    double h2 = L->half_diag * L->half_diag;
    for (int round = 0; round < 2; round++) {
        /* tc: catalog stars projected with C; x = t, y = t |t|^2 (interleaved y, z) */
        double sxx = 0, sxy = 0, syy = 0, sxc = 0, syc = 0, sgg = 0, sgc = 0;
        for (long i = 0; i < k; i++) {
            const double *v = L->v + 3 * i;
            double w0 = v[0] * C[0] + v[1] * C[3] + v[2] * C[6];
            double w1 = v[0] * C[1] + v[1] * C[4] + v[2] * C[7];
            double w2 = v[0] * C[2] + v[1] * C[5] + v[2] * C[8];
            double tc[2] = {w1 / w0, w2 / w0};
            double ty = L->t[2 * img[i]], tz = L->t[2 * img[i] + 1];
            double r2 = ty * ty + tz * tz, tt[2] = {ty, tz};
            for (int a = 0; a < 2; a++) {
                double x = tt[a], y = tt[a] * r2, g = tt[a] * (1.0 + k1 * r2);
                sxx += x * x; sxy += x * y; syy += y * y; sxc += x * tc[a]; syc += y * tc[a];
                sgg += g * g; sgc += g * tc[a];
            }
        }
        int done = 0;
        if (fit_k1 && k >= 6) {
            double det = sxx * syy - sxy * sxy;
            if (det != 0.0) {
                double s_new = (syy * sxc - sxy * syc) / det;
                double b = (sxx * syc - sxy * sxc) / det;
                double k_new = b / s_new;
                if (fabs(k_new) * h2 < 0.05) { s = s_new; k1 = k_new; done = 1; }
            }
        }
        if (!done) s = sgc / sgg;
        for (long i = 0; i < k; i++) unit_of(L, img[i], s, k1, L->w + 3 * i);
        wahba(L->w, L->v, (int)k, NULL, C);
    }
    *s_io = s;
    *k1_io = k1;
}

/* p_false of the final match (_Search.p_false) */
static double lis_p_false(const Lis *L, const long *img, const double *d2, long k, const long *img4,
                          long n_in, double s)
{
    long k_all[N_GATES] = {0}, k_other[N_GATES] = {0};
    for (long i = 0; i < k; i++) {
        int in_pat = img[i] == img4[0] || img[i] == img4[1] || img[i] == img4[2] || img[i] == img4[3];
        for (int g = 0; g < N_GATES; g++) {
            double gg = L->gate_fine * GATE_FRACTIONS[g];
            if (d2[i] <= gg * gg) { k_all[g]++; if (!in_pat) k_other[g]++; }
        }
    }
    long n = L->n;
    double p1[N_GATES], fb[N_GATES], fa[N_GATES];
    long nb[N_GATES], na[N_GATES], ka[N_GATES];
    double looked = (double)(L->n_patterns > 1 ? L->n_patterns : 1) * (double)L->db_n_patterns;
    for (int g = 0; g < N_GATES; g++) {
        double gg = L->gate_fine * GATE_FRACTIONS[g];
        p1[g] = (double)n_in * M_PI * gg * gg / (L->area0 * s * s);
        fb[g] = (double)L->n_verified; nb[g] = n - 4;
        fa[g] = looked; na[g] = n - 2; ka[g] = k_all[g] - 2;
    }
    double stop = 1e-3 * L->p_false_max / (2 * N_GATES);
    double p_b = min_chance(fb, nb, k_other, p1, stop);
    if (p_b <= stop) return 2.0 * N_GATES * p_b;
    double p_a = min_chance(fa, na, ka, p1, stop);
    double p = 2.0 * N_GATES * (p_a < p_b ? p_a : p_b);
    return p < 1.0 ? p : 1.0;
}

/* _Search.verify: 1 accepted (result in L), 0 rejected, -1 out of memory */
/* L->d2b [0, m): the squared residuals of the pairs (L->img, L->cat) by C, s, k1 */
static void lis_residuals2(Lis *L, const Db *db, const double *C, double s, double k1, long m)
{
    for (long i = 0; i < m; i++) {
        const double *v = db->u64 + 3 * L->cat[i];
        double w0 = v[0] * C[0] + v[1] * C[3] + v[2] * C[6];
        double w1 = v[0] * C[1] + v[1] * C[4] + v[2] * C[7];
        double w2 = v[0] * C[2] + v[1] * C[5] + v[2] * C[8];
        double a = L->t[2 * L->img[i]], b = L->t[2 * L->img[i] + 1], f = s;
        if (k1 != 0.0) f = s * (1.0 + k1 * (a * a + b * b));
        double dy = a * f - w1 / w0, dz = b * f - w2 / w0;
        L->d2b[i] = dy * dy + dz * dz;
    }
}

static int lis_verify(Lis *L, const Db *db, const long *img4, const long *cat4, double scale)
{
    double s = L->fit ? scale : 1.0, k1 = 0.0, C[9], box[4];
    double w4[12], v4[12];
    for (int a = 0; a < 4; a++) {
        unit_of(L, img4[a], s, 0.0, w4 + 3 * a);
        memcpy(v4 + 3 * a, db->u64 + 3 * cat4[a], 3 * sizeof(double));
    }
    wahba(w4, v4, 4, NULL, C);
    double lim = (2.0 * L->e_edge) * (2.0 * L->e_edge), dmax = 0.0;
    for (int a = 0; a < 4; a++) {
        double d = 0.0;
        for (int r = 0; r < 3; r++) {
            double x = C[3 * r] * w4[3 * a] + C[3 * r + 1] * w4[3 * a + 1] + C[3 * r + 2] * w4[3 * a + 2]
                       - v4[3 * a + r];
            d += x * x;
        }
        if (d > dmax) dmax = d;
    }
    if (dmax > lim) return 0;                              /* mirror image or wrong pairing */
    double largest2 = 0.0;
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++) {
            double dy = L->t[2 * img4[a]] - L->t[2 * img4[b]];
            double dz = L->t[2 * img4[a] + 1] - L->t[2 * img4[b] + 1];
            double d = dy * dy + dz * dz;
            if (d > largest2) largest2 = d;
        }
    double largest = sqrt(largest2);
    double gate = 2.0 * L->error_rad * (1.0 + 2.0 * L->half_diag / (largest > 1e-12 ? largest : 1e-12));
    if (L->fit_radial) {
        double g2 = 0.01 * (L->bounds[3] - L->bounds[2]);
        if (g2 > gate) gate = g2;
    }
    lis_box(L, s, box);
    if (predict(db, C, box, gate, &L->pred) < 0) return -1;
    for (long i = 0; i < L->n; i++) { L->ty[i] = L->t[2 * i] * s; L->tz[i] = L->t[2 * i + 1] * s; }
    long m = associate(L->ty, L->tz, L->n, &L->pred, gate, L->img, L->jj, L->d2, L->pred.best,
                       L->pred.ord, L->pred.sty, NULL, NULL, NULL);
    if (m < 4) return 0;
    for (long i = 0; i < m; i++) L->cat[i] = L->pred.rows[L->jj[i]];
    int radial = L->fit && L->fit_radial;
    refine(L, db, L->img, L->cat, m, &s, &k1, L->fit, radial, C);
    long m2 = 0;
    for (int attempt = 0; attempt < 4; attempt++) {
        lis_box(L, s, box);
        reproject(db, C, box, &L->pred);
        t_true_all(L, s, k1, L->ty, L->tz);
        long n_lost = 0;
        m2 = associate(L->ty, L->tz, L->n, &L->pred, L->gate_fine, L->img2, L->jj2, L->d2b,
                       L->pred.best, L->pred.ord, L->pred.sty, L->lost_r, L->lost_j, &n_lost);
        if (n_lost) {
            /* two stars within the fine gate of one catalog star: neither is matched (as
             * in tracking; a blend or a false star on a true one) */
            long o = 0;
            for (long i = 0; i < m2; i++) {
                int drop = 0;
                for (long q = 0; q < n_lost && !drop; q++) drop = L->jj2[i] == L->lost_j[q];
                if (!drop) { L->img2[o] = L->img2[i]; L->jj2[o] = L->jj2[i]; L->d2b[o] = L->d2b[i]; o++; }
            }
            m2 = o;
        }
        if (m2 < L->min_matches) return 0;
        for (long i = 0; i < m2; i++) L->cat2[i] = L->pred.rows[L->jj2[i]];
        int settled = m2 == m;
        for (long i = 0; settled && i < m2; i++)
            settled = L->img2[i] == L->img[i] && L->cat2[i] == L->cat[i];
        m = m2;
        memcpy(L->img, L->img2, m * sizeof(long));
        memcpy(L->cat, L->cat2, m * sizeof(long));
        if (settled || attempt == 3) break;
        refine(L, db, L->img, L->cat, m, &s, &k1, L->fit, radial, C);
    }
    long m3 = scatter_screen(L->img, L->cat, L->d2b, m, L->gate_fine, L->d2);
    if (m3 < m) {                                           /* refit without the outliers */
        m = m3;
        refine(L, db, L->img, L->cat, m, &s, &k1, L->fit, radial, C);
        lis_residuals2(L, db, C, s, k1, m);
    }
    m3 = unused_nearer(L->t, L->t_more, L->n_more, s, k1, db->u64, L->img, L->cat, L->d2b, m, C);
    if (m3 < m) {                                           /* refit without them */
        if (m3 < L->min_matches) return 0;
        m = m3;
        refine(L, db, L->img, L->cat, m, &s, &k1, L->fit, radial, C);
        lis_residuals2(L, db, C, s, k1, m);
    }
    double p = lis_p_false(L, L->img, L->d2b, m, img4, L->pred.n_in, s);
    if (p > L->p_false_max) return 0;
    memcpy(L->C, C, sizeof C);
    L->s = s; L->k1 = k1; L->p_false = p; L->n_match = m;
    double ss = 0.0;
    for (long i = 0; i < m; i++) {
        double w[3];
        unit_of(L, L->img[i], s, k1, w);
        const double *v = db->u64 + 3 * L->cat[i];
        for (int r = 0; r < 3; r++) {
            double x = C[3 * r] * w[0] + C[3 * r + 1] * w[1] + C[3 * r + 2] * w[2] - v[r];
            ss += x * x;
        }
    }
    L->rms = sqrt(ss / m) * RAD2ASEC;
    return 1;
}

static int cand_push(Cand **c, long *n, long *cap, const Cand *x)
{
    if (*n >= *cap) {
        long nc = *cap ? 2 * *cap : 256;
        Cand *p = realloc(*c, nc * sizeof(Cand));
        if (!p) return -1;
        *c = p;
        *cap = nc;
    }
    (*c)[(*n)++] = *x;
    return 0;
}

/* candidates of one image pattern (edges e6 in canonical order) appended to *cands */
static int pattern_candidates(Lis *L, const Db *db, long owner, const double *e6, Cand **cands,
                              long *n_cand, long *cap, long *order)
{
    double srt[6];
    memcpy(srt, e6, sizeof srt);
    sort6(srt);
    double largest = srt[5];
    double ratio[5], tol[5];
    long lo[5], span[5];
    long bins = db->bins;
    for (int q = 0; q < 5; q++) {
        ratio[q] = srt[q] / largest;
        tol[q] = L->e_edge * (1.0 + ratio[q]) / largest + L->model_tol;
        long a = (long)((ratio[q] - tol[q]) * bins), b = (long)((ratio[q] + tol[q]) * bins);
        if (a < 0) a = 0;
        if (a > bins - 1) a = bins - 1;
        if (b < 0) b = 0;
        if (b > bins - 1) b = bins - 1;
        lo[q] = a;
        span[q] = b - a + 1;
        if (span[q] > 3) {
            long c = (long)(ratio[q] * bins) - 1;
            if (c < 0) c = 0;
            if (c > bins - 3) c = bins - 3;
            lo[q] = c;
            span[q] = 3;
        }
    }
    uint64_t mask = (db->key_bits >= 64) ? ~(uint64_t)0 : (((uint64_t)1 << db->key_bits) - 1);
    uint64_t lo_mask = ((uint64_t)1 << db->lo_bits) - 1;
    /* The look-up is memory bound (random reads in the key index and the star table):
     * the addresses are computed first and prefetched together, then used in the same
     * order as the plain loop would (the candidates and their order do not change). */
    uint64_t his[243];
    uint16_t los[243];
    int n_probe = 0;
    long o[5];
    for (o[0] = 0; o[0] < span[0]; o[0]++)
    for (o[1] = 0; o[1] < span[1]; o[1]++)
    for (o[2] = 0; o[2] < span[2]; o[2]++)
    for (o[3] = 0; o[3] < span[3]; o[3]++)
    for (o[4] = 0; o[4] < span[4]; o[4]++) {
        int64_t key = 0, wgt = 1;
        for (int q = 0; q < 5; q++) { key += (lo[q] + o[q]) * wgt; wgt *= bins; }
        uint64_t h = ((uint64_t)key * (uint64_t)331804481) & mask;
        his[n_probe] = h >> db->lo_bits;
        los[n_probe] = (uint16_t)(h & lo_mask);
        __builtin_prefetch(db->key_hi_start + his[n_probe]);
        n_probe++;
    }
    for (int i = 0; i < n_probe; i++) {
        long a = db->key_hi_start[his[i]];
        __builtin_prefetch(db->key_lo + a);
        __builtin_prefetch(db->size_q + a);
    }
    /* a row whose stored largest edge (in size_quantum steps: its edge is within
     * [q, q + 1) steps) cannot pass the size test below is not read further: most chance
     * hits fail it, and each would cost the random reads of its star rows and vectors.
     * The bounds are widened by 1e-9 so that rounding cannot drop a row the test keeps. */
    double s_tol = L->ftol * 1.001 + 2.0 * L->e_edge / largest;
    double q_lo = largest * (1.0 - s_tol) * (1.0 - 1e-9) / db->size_quantum - 1.0;
    double q_hi = largest * (1.0 + s_tol) * (1.0 + 1e-9) / db->size_quantum;
    long hits[512];
    int n_hit = 0, more = 0;
    for (int i = 0; i < n_probe && !more; i++) {
        /* a bucket's rows are sorted by key_lo (the database is sorted by the whole key,
         * checked in _kernels.py): the rows below los[i] are counted without a branch,
         * then the equal ones are read in order (the same rows as a scan for equality) */
        long a = db->key_hi_start[his[i]], e = db->key_hi_start[his[i] + 1], row = a;
        uint16_t lo = los[i];
        for (long r = a; r < e; r++) row += db->key_lo[r] < lo;
        for (; row < e && db->key_lo[row] == lo; row++) {
            double q = (double)db->size_q[row];
            if (q < q_lo || (q > q_hi && q < 65535.0)) continue;
            if (n_hit == 512) { more = 1; break; }
            hits[n_hit++] = row;
            __builtin_prefetch((const char *)db->pstars + (db->pstars16 ? 8 : 16) * row);
        }
    }
    if (more) n_hit = 0;                /* (never seen) too many: the plain loop below */
    for (int i = 0; i < n_hit; i++) {
        uint32_t ps[4];
        if (pattern_row_in(db, hits[i], ps))
            for (int a = 0; a < 4; a++) __builtin_prefetch(db->u32 + 3 * ps[a]);
    }
    for (int i = 0; i < (more ? n_probe : n_hit); i++) {
      long row_a = more ? db->key_hi_start[his[i]] : hits[i];
      long row_b = more ? db->key_hi_start[his[i] + 1] : hits[i] + 1;
      for (long row = row_a; row < row_b; row++) {
            if (more && db->key_lo[row] != los[i]) continue;
            uint32_t ps[4];
            if (!pattern_row_in(db, row, ps)) continue;
            /* the largest edge first (one acos): most chance hits fail the size test */
            double dots[6];
            int emin;
            double clargest = largest_edge(db->u32, ps, dots, &emin);
            double scale = clargest / largest;
            if (!(fabs(scale - 1.0) <= s_tol)) continue;
            double ce[6];
            for (int e = 0; e < 6; e++) ce[e] = e == emin ? clargest : acos(clip1(dots[e]));
            double cs[6];
            memcpy(cs, ce, sizeof cs);
            sort6(cs);
            int good = 1;
            for (int q = 0; q < 5 && good; q++)
                good = fabs(cs[q] / clargest - ratio[q]) <= tol[q];
            if (!good) continue;
            double best = INFINITY;
            int bp = 0;
            for (int p = 0; p < 24; p++) {
                double err = 0.0;
                for (int e = 0; e < 6; e++) {
                    double d = ce[PERM_EDGES[p][e]] - e6[e] * scale;
                    err += d * d;
                }
                if (err < best) { best = err; bp = p; }
            }
            Cand c;
            c.owner = owner; c.order = (*order)++; c.err = best; c.scale = scale;
            for (int a = 0; a < 4; a++) c.cat[a] = ps[PERM[bp][a]];
            if (cand_push(cands, n_cand, cap, &c) < 0) return -1;
      }
    }
    return 0;
}

/* the search; returns 1 solved, 0 exhausted, 2 stopped (time / candidates), -1 no memory */
static int lis_run(Lis *L, const Db *db, long k, const int64_t *combos, const int64_t *ends, long n_ends)
{
    double ang[32 * 32];
    long have = 0;                      /* angles among the first `have` stars are known */
    Cand *cands = NULL;
    long cap = 0, start = 0;
    int status = 0;
    for (long bi = 0; bi < n_ends && status == 0; bi++) {
        long end = ends[bi];
        if (end <= start) continue;
        long n_cand = 0, order = 0;
        long need = combos[4 * (end - 1) + 3] + 1;     /* rows are sorted: the last star */
        for (long b = have; b < need; b++)
            for (long a = 0; a < b; a++) {
                const double *x = L->u0 + 3 * a, *y = L->u0 + 3 * b;
                ang[a * k + b] = acos(clip1(x[0] * y[0] + x[1] * y[1] + x[2] * y[2]));
            }
        if (need > have) have = need;
        for (long p = start; p < end; p++) {
            const int64_t *cb = combos + 4 * p;
            double e6[6], lg = 0.0;
            for (int e = 0; e < 6; e++) {
                e6[e] = ang[cb[PAIR_A[e]] * k + cb[PAIR_B[e]]];
                if (e6[e] > lg) lg = e6[e];
            }
            if (!(lg <= L->max_edge && lg >= L->min_edge)) continue;
            L->n_patterns++;
            if (pattern_candidates(L, db, p - start, e6, &cands, &n_cand, &cap, &order) < 0) {
                status = -1;
                break;
            }
        }
        if (status) break;
        if (n_cand > 1) qsort(cands, n_cand, sizeof(Cand), cand_cmp);
        for (long i = 0; i < n_cand; i++) {
            L->n_verified++;
            const int64_t *cb = combos + 4 * (start + cands[i].owner);
            long img4[4] = {cb[0], cb[1], cb[2], cb[3]};
            int r = lis_verify(L, db, img4, cands[i].cat, cands[i].scale);
            if (r != 0) { status = r; break; }
            if (now_s() - L->t_start > L->max_time_s || L->n_verified >= L->max_candidates) {
                status = 2;
                break;
            }
        }
        if (status) break;
        if (now_s() - L->t_start > L->max_time_s || L->n_verified >= L->max_candidates) {
            status = 2;
            break;
        }
        start = end;
    }
    free(cands);
    return status;
}

/* ---------------------------------------------------------------------------------
 * Python entry points
 * ------------------------------------------------------------------------------- */

/* star_index / hip outputs: -1, then out_star[usable[img]] = cat, out_hip[..] = hip[cat]
 * (usable empty: img itself); 0 when an index is out of range */
static int scatter_rows(const int64_t *img, const int64_t *cat, long k, const Py_buffer *usable,
                        const Py_buffer *hip, Py_buffer *out_star, Py_buffer *out_hip)
{
    const int64_t *u = usable->buf;
    const int32_t *h = hip->buf;
    int64_t *star = out_star->buf, *oh = out_hip->buf;
    long n = (long)(out_star->len / sizeof(int64_t)), n_use = (long)(usable->len / sizeof(int64_t));
    long n_hip = (long)(hip->len / sizeof(int32_t));
    if ((long)(out_hip->len / sizeof(int64_t)) != n) return 0;
    for (long i = 0; i < n; i++) { star[i] = -1; oh[i] = -1; }
    for (long i = 0; i < k; i++) {
        long r = n_use ? (img[i] >= 0 && img[i] < n_use ? (long)u[img[i]] : -1) : (long)img[i];
        if (r < 0 || r >= n || cat[i] < 0 || cat[i] >= n_hip) return 0;
        star[r] = cat[i];
        oh[r] = h[cat[i]];
    }
    return 1;
}

#define NBUF 9                  /* the database arrays of a search */

static void release_all(Py_buffer *b, int n)
{
    for (int i = 0; i < n; i++)
        if (b[i].obj) PyBuffer_Release(&b[i]);
}

/* The search over the usable stars t (n, 2), u0 (n, 3) (t_more (n_more, 2) the fainter
 * ones beyond them) with the parameters of lis_solve; 1 solved (L->C, L->img / L->cat
 * [0, L->n_match), ...), 0 / 2 not, -1 no memory.  L is zeroed here and must be released with lis_free. */
static int lis_core(Lis *L, const Db *db, const double *t, const double *u0, long n,
                    const double *t_more, long n_more, const int64_t *I, const double *D,
                    const int64_t *combos, const int64_t *ends, long n_ends)
{
    memset(L, 0, sizeof *L);
    L->t = t;
    L->u0 = u0;
    L->n = n;
    L->t_more = t_more;
    L->n_more = n_more;
    long k = (long)I[0];
    L->db_n_patterns = db->n_patterns_db;
    L->min_matches = (long)I[6]; L->max_candidates = (long)I[7]; L->fit = (int)I[8];
    L->fit_radial = (int)I[9];
    L->e_edge = D[0]; L->max_edge = D[1]; L->min_edge = D[2]; L->model_tol = D[3]; L->ftol = D[4];
    L->error_rad = D[5]; L->half_diag = D[6]; L->gate_fine = D[7]; L->area0 = D[8];
    L->p_false_max = D[9]; L->max_time_s = D[10];
    for (int q = 0; q < 4; q++) L->bounds[q] = D[11 + q];
    long m = n > 0 ? n : 1;
    L->ty = malloc(m * sizeof(double)); L->tz = malloc(m * sizeof(double));
    L->w = malloc(3 * m * sizeof(double)); L->v = malloc(3 * m * sizeof(double));
    L->d2 = malloc(m * sizeof(double)); L->d2b = malloc(m * sizeof(double));
    L->img = malloc(m * sizeof(long)); L->jj = malloc(m * sizeof(long));
    L->img2 = malloc(m * sizeof(long)); L->jj2 = malloc(m * sizeof(long));
    L->cat = malloc(m * sizeof(long)); L->cat2 = malloc(m * sizeof(long));
    L->lost_r = malloc(m * sizeof(long)); L->lost_j = malloc(m * sizeof(long));
    if (!(L->ty && L->tz && L->w && L->v && L->d2 && L->d2b && L->img && L->jj && L->img2 && L->jj2
          && L->cat && L->cat2 && L->lost_r && L->lost_j) || k > 32)
        return -1;
    L->t_start = now_s();
    return lis_run(L, db, k, combos, ends, n_ends);
}

static void lis_free(Lis *L)
{
    free(L->ty); free(L->tz); free(L->w); free(L->v); free(L->d2); free(L->d2b); free(L->img);
    free(L->jj); free(L->img2); free(L->jj2); free(L->cat); free(L->cat2); free(L->lost_r);
    free(L->lost_j);
    pred_free(&L->pred);
}

static void db_from(Db *db, Py_buffer *b, const int64_t *I, const double *D)
{
    db->size_q = b[8].buf; db->size_quantum = D[15];
    db->u64 = b[0].buf; db->u32 = b[1].buf; db->pstars = b[2].buf; db->key_lo = b[3].buf;
    db->pstars16 = b[2].len == (Py_ssize_t)(8 * I[5]);     /* else uint32 (db_prepare checked) */
    db->key_hi_start = b[4].buf; db->cell_start = b[5].buf; db->cell_index = b[6].buf;
    db->ci16 = cell_list_u16(&b[5], &b[6]) == 1;         /* else uint32 (db_prepare checked) */
    db->cell_u = b[7].buf;
    db->grid_n = (long)I[1]; db->key_bits = (long)I[2]; db->lo_bits = (long)I[3]; db->bins = (long)I[4];
    db->n_patterns_db = (long)I[5];
    db->n_stars = (long)(b[0].len / (Py_ssize_t)(3 * sizeof(double)));
}

/* the result of a search: (status, n_match, n_verified, n_patterns, s, k1, p_false, rms);
 * solved: out_C and the star_index / hip outputs filled */
static PyObject *lis_result(int status, Lis *L, Py_buffer *oc, const Py_buffer *bus,
                            const Py_buffer *bh, Py_buffer *ostar, Py_buffer *ohip)
{
    int scattered = 1;
    if (status == 1) {
        memcpy(oc->buf, L->C, 9 * sizeof(double));
        int64_t *ii = malloc((L->n_match + 1) * sizeof(int64_t)), *cc = malloc((L->n_match + 1) * sizeof(int64_t));
        if (!ii || !cc) { free(ii); free(cc); status = -1; }
        else {
            for (long i = 0; i < L->n_match; i++) { ii[i] = L->img[i]; cc[i] = L->cat[i]; }
            scattered = scatter_rows(ii, cc, L->n_match, bus, bh, ostar, ohip);
            free(ii); free(cc);
        }
    }
    if (status < 0) return PyErr_NoMemory();
    if (!scattered) {
        PyErr_SetString(PyExc_IndexError, "lis_solve: matched row out of range");
        return NULL;
    }
    return Py_BuildValue("illldddd", status, L->n_match, L->n_verified, L->n_patterns, L->s, L->k1,
                         L->p_false, L->rms);
}

/* lis_solve(t, u0, t_more, combos, ends, u64, u32, pstars, key_lo, key_hi_start, cell_start,
 *           cell_index, cell_u, size_q, iparams, dparams, out_C, usable, hip_db, out_star,
 *           out_hip)
 * t_more (n_more, 2): the usable detections beyond the n searched (fainter; only a nearer
 * one of them unnames a pair, unused_nearer)
 * iparams (int64): k, grid_n, key_bits, lo_bits, bins, db_n_patterns, min_matches,
 *                  max_candidates, fit, fit_radial
 * dparams (float64): e_edge, max_edge, min_edge, model_tol, ftol, error_rad, half_diag,
 *                    gate_fine, area0, p_false_max, max_time_s, bounds[4], size_quantum
 * returns (status, n_match, n_verified, n_patterns, s, k1, p_false, rms_arcsec) */
static PyObject *py_lis_solve(PyObject *self, PyObject *args)
{
    Py_buffer bt, bu0, bmore, bco, ben, b[NBUF], ip, dp, oc, bus, bh, ostar, ohip;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*w*y*y*w*w*", &bt, &bu0, &bmore, &bco,
                          &ben, &b[0], &b[1], &b[2], &b[3], &b[4], &b[5], &b[6], &b[7], &b[8], &ip, &dp,
                          &oc, &bus, &bh, &ostar, &ohip))
        return NULL;
    const int64_t *I = ip.buf;
    Db db;
    db_from(&db, b, I, dp.buf);
    Lis L;
    int status;
    Py_BEGIN_ALLOW_THREADS
    status = lis_core(&L, &db, bt.buf, bu0.buf, (long)(bt.len / (2 * sizeof(double))), bmore.buf,
                      (long)(bmore.len / (2 * sizeof(double))), I, dp.buf, bco.buf, ben.buf,
                      (long)(ben.len / sizeof(int64_t)));
    Py_END_ALLOW_THREADS
    PyObject *res = lis_result(status, &L, &oc, &bus, &bh, &ostar, &ohip);
    lis_free(&L);
    release_all(b, NBUF);
    PyBuffer_Release(&bt); PyBuffer_Release(&bu0); PyBuffer_Release(&bmore); PyBuffer_Release(&bco);
    PyBuffer_Release(&ben); PyBuffer_Release(&ip); PyBuffer_Release(&dp); PyBuffer_Release(&oc);
    PyBuffer_Release(&bus); PyBuffer_Release(&bh); PyBuffer_Release(&ostar); PyBuffer_Release(&ohip);
    return res;
}

/* pinhole unprojection of xy (n, 2) with cam = (x0, y0, pixel_mm, f_mm) into u (n, 3) and
 * t (n, 2) (Camera.unproject without distortion, then t = u[1:] / u[0]); 1 if all finite */
static int unproject_rows(const double *xy, long n, const double *P, double *u, double *t)
{
    int finite = 1;
    for (long i = 0; i < n; i++) {
        double um = (xy[2 * i] - P[0]) * P[2], wm = (xy[2 * i + 1] - P[1]) * P[2];
        double a = P[3], b = -wm, c = um;
        double nn = sqrt(a * a + b * b + c * c);
        a /= nn; b /= nn; c /= nn;
        u[3 * i] = a; u[3 * i + 1] = b; u[3 * i + 2] = c;
        t[2 * i] = b / a; t[2 * i + 1] = c / a;
        if (!isfinite(t[2 * i]) || !isfinite(t[2 * i + 1])) finite = 0;
    }
    return finite;
}

/* unit vectors (n, 3) of t (n, 2) at focal scale s and radial k1 (StarField.unit) */
static void unit_rows_of(const double *t, long n, double s, double k1, double *u)
{
    for (long i = 0; i < n; i++) {
        double ty = t[2 * i], tz = t[2 * i + 1], f = s;
        if (k1 != 0.0) f = s * (1.0 + k1 * (ty * ty + tz * tz));
        ty *= f; tz *= f;
        double nn = sqrt(1.0 + ty * ty + tz * tz);
        u[3 * i] = 1.0 / nn; u[3 * i + 1] = ty / nn; u[3 * i + 2] = tz / nn;
    }
}

/* lis_pinhole(xy, cam, combos, ends, <the 9 database arrays>, iparams, dparams, out_C,
 *             out_u, hip_db, out_star, out_hip): lis_solve from pixel centroids of a
 * camera without distortion, cam = (x0_px, y0_px, pixel_mm, f_mm) (float64), in one call:
 * out_u (N, 3) gets the stars' unit vectors (at the solved focal scale and radial term
 * when solved); the brightest iparams[10] rows are searched.  None when a centroid is
 * not finite (the caller takes the general path); else lis_solve's tuple. */
static PyObject *py_lis_pinhole(PyObject *self, PyObject *args)
{
    Py_buffer bx, bcam, bco, ben, b[NBUF], ip, dp, oc, ou, bh, ostar, ohip;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*w*w*y*w*w*", &bx, &bcam, &bco, &ben,
                          &b[0], &b[1], &b[2], &b[3], &b[4], &b[5], &b[6], &b[7], &b[8], &ip, &dp,
                          &oc, &ou, &bh, &ostar, &ohip))
        return NULL;
    const int64_t *I = ip.buf;
    long n = (long)(bx.len / (2 * sizeof(double))), m = (long)I[10];
    Db db;
    db_from(&db, b, I, dp.buf);
    Lis L;
    memset(&L, 0, sizeof L);
    int status = -1, finite = 0;
    double *t = malloc((n > 0 ? n : 1) * 2 * sizeof(double));
    if (t && m <= n && (long)(ou.len / (3 * sizeof(double))) == n) {
        Py_BEGIN_ALLOW_THREADS
        finite = unproject_rows(bx.buf, n, bcam.buf, ou.buf, t);
        if (finite) {
            status = lis_core(&L, &db, t, ou.buf, m, t + 2 * m, n - m, I, dp.buf, bco.buf, ben.buf,
                              (long)(ben.len / sizeof(int64_t)));
            if (status == 1 && !(L.s == 1.0 && L.k1 == 0.0)) unit_rows_of(t, n, L.s, L.k1, ou.buf);
        }
        Py_END_ALLOW_THREADS
    }
    PyObject *res;
    if (t && !finite) { Py_INCREF(Py_None); res = Py_None; }
    else {
        Py_buffer none_used;
        memset(&none_used, 0, sizeof none_used);
        none_used.len = 0;
        none_used.buf = NULL;
        res = lis_result(status, &L, &oc, &none_used, &bh, &ostar, &ohip);
    }
    free(t);
    lis_free(&L);
    release_all(b, NBUF);
    PyBuffer_Release(&bx); PyBuffer_Release(&bcam); PyBuffer_Release(&bco); PyBuffer_Release(&ben);
    PyBuffer_Release(&ip); PyBuffer_Release(&dp); PyBuffer_Release(&oc); PyBuffer_Release(&ou);
    PyBuffer_Release(&bh); PyBuffer_Release(&ostar); PyBuffer_Release(&ohip);
    return res;
}

/* ---------------------------------------------------------------------------------
 * Tracking (_tracking.py)
 * ------------------------------------------------------------------------------- */

#define WIDE_STARS 20
#define MAX_FITS 6
#define MAX_TRIMS 2
#define TRIM_FRACTION 0.2

typedef struct {
    long n;                     /* measured stars */
    const double *t;            /* (n, 2) at the focal scale */
    const double *w;            /* (n, 3) unit vectors */
    const double *my, *mz;      /* (n,) split t */
    const double *t_more;       /* (n_more, 2): the detections beyond the n used ones */
    long n_more;
    long m;                     /* predicted stars */
    const long *rows;
    const double *u;            /* (m, 3) packed catalog vectors */
    const double *py, *pz;      /* prior projections */
    double gate, gate_prior, gate_shift, area, limit;
    long min_matches, n_trials;
    /* scratch */
    double *sy, *sz, *qy, *qz;  /* (m,) shifted / fitted projections */
    double *wb, *vb;            /* (n, 3) */
    long *best_k, *lost_r, *lost_j, *tmp_i, *tmp_j, *ord;
    double *tmp_d, *sty;
    Pred pr;                    /* views for associate() */
} Scene;

static void residuals2(const Scene *S, const long *img, const long *j, long k, const double *C, double *d2)
{
    for (long i = 0; i < k; i++) {
        const double *v = S->u + 3 * j[i];
        double w0 = v[0] * C[0] + v[1] * C[3] + v[2] * C[6];
        double w1 = v[0] * C[1] + v[1] * C[4] + v[2] * C[7];
        double w2 = v[0] * C[2] + v[1] * C[5] + v[2] * C[8];
        double dy = S->t[2 * img[i]] - w1 / w0, dz = S->t[2 * img[i] + 1] - w2 / w0;
        d2[i] = dy * dy + dz * dz;
    }
}

static void fit(Scene *S, const long *img, const long *j, long k, const double *C_near, double *C)
{
    for (long i = 0; i < k; i++) {
        memcpy(S->wb + 3 * i, S->w + 3 * img[i], 3 * sizeof(double));
        memcpy(S->vb + 3 * i, S->u + 3 * j[i], 3 * sizeof(double));
    }
    wahba(S->wb, S->vb, (int)k, C_near, C);
}

static long pair(Scene *S, const double *py, const double *pz, double gate, long *img, long *j,
                 double *d2, long *n_lost)
{
    S->pr.m = S->m;
    S->pr.ty = (double *)py;
    S->pr.tz = (double *)pz;
    return associate(S->my, S->mz, S->n, &S->pr, gate, img, j, d2, S->best_k, S->ord, S->sty,
                     S->lost_r, S->lost_j, n_lost);
}

static double dmax(const double *d, long k)
{
    double m = -INFINITY;
    for (long i = 0; i < k; i++) if (d[i] > m) m = d[i];
    return m;
}

static long without(long *img, long *j, double *d2, long k, const long *bad, long n_bad)
{
    long out = 0;
    for (long i = 0; i < k; i++) {
        int drop = 0;
        for (long b = 0; b < n_bad && !drop; b++) drop = j[i] == bad[b];
        if (!drop) { img[out] = img[i]; j[out] = j[i]; d2[out] = d2[i]; out++; }
    }
    return out;
}

/* _Scene.settle; img/j/d2 in-out, returns the number of pairs, C out */
static long settle(Scene *S, long *img, long *j, double *d2, long k, long n_lost, const double *C_near,
                   double *C)
{
    double g2 = S->gate * S->gate;
    fit(S, img, j, k, C_near, C);
    residuals2(S, img, j, k, C, d2);
    double g = S->gate_shift;
    if (dmax(d2, k) > g2) {                                 /* _trim */
        for (int it = 0; it < MAX_TRIMS; it++) {
            long keep = 0;
            for (long i = 0; i < k; i++) keep += d2[i] <= g2;
            if (keep == k || (double)(k - keep) > TRIM_FRACTION * (double)k) break;
            long o = 0;
            for (long i = 0; i < k; i++)
                if (d2[i] <= g2) { img[o] = img[i]; j[o] = j[i]; d2[o] = d2[i]; o++; }
            k = o;
            if (k < S->min_matches) return k;
            double Cn[9];
            memcpy(Cn, C, sizeof Cn);
            fit(S, img, j, k, Cn, C);
            residuals2(S, img, j, k, C, d2);
        }
        if (k < S->min_matches) return k;
    }
    if (dmax(d2, k) <= g2) {
        /* _ambiguous: predictions a losing star is also within the fine gate of */
        long bad[64], n_bad = 0;
        for (long L = 0; L < n_lost && n_bad < 64; L++) {
            long jp = S->lost_j[L];
            int taken = 0;
            for (long i = 0; i < k && !taken; i++) taken = j[i] == jp;
            if (!taken) continue;
            long r = S->lost_r[L];
            double dd;
            residuals2(S, &r, &jp, 1, C, &dd);
            if (dd <= g2) bad[n_bad++] = jp;
        }
        if (n_bad == 0) return k;
        k = without(img, j, d2, k, bad, n_bad);
        if (k < S->min_matches) return k;
        double Cn[9];
        memcpy(Cn, C, sizeof Cn);
        fit(S, img, j, k, Cn, C);
        g = S->gate;
    }
    for (int it = 0; it < MAX_FITS; it++) {
        g = 0.25 * g > S->gate ? 0.25 * g : S->gate;
        for (long q = 0; q < S->m; q++) {
            const double *u = S->u + 3 * q;
            double w0 = u[0] * C[0] + u[1] * C[3] + u[2] * C[6];
            double w1 = u[0] * C[1] + u[1] * C[4] + u[2] * C[7];
            double w2 = u[0] * C[2] + u[1] * C[5] + u[2] * C[8];
            S->qy[q] = w1 / w0;
            S->qz[q] = w2 / w0;
        }
        long nl = 0;
        long k2 = pair(S, S->qy, S->qz, g, S->tmp_i, S->tmp_j, S->tmp_d, &nl);
        if (g == S->gate && nl) {
            long bad[64], n_bad = 0;
            for (long L = 0; L < nl && n_bad < 64; L++) bad[n_bad++] = S->lost_j[L];
            k2 = without(S->tmp_i, S->tmp_j, S->tmp_d, k2, bad, n_bad);
        }
        int settled = g == S->gate && k2 == k;
        for (long i = 0; settled && i < k2; i++) settled = S->tmp_i[i] == img[i] && S->tmp_j[i] == j[i];
        memcpy(img, S->tmp_i, k2 * sizeof(long));
        memcpy(j, S->tmp_j, k2 * sizeof(long));
        memcpy(d2, S->tmp_d, k2 * sizeof(double));
        k = k2;
        if (settled || k < S->min_matches) break;
        double Cn[9];
        memcpy(Cn, C, sizeof Cn);
        fit(S, img, j, k, Cn, C);
    }
    return k;
}

/* _Scene.match: 0 ok (k, n_in set), else a reason code with *k the count */
static int scene_match(Scene *S, const double *C_prior, double shy, double shz, const double *box,
                       long *img, long *j, double *d2, long *k_out, long *n_in, double *C)
{
    for (long q = 0; q < S->m; q++) { S->sy[q] = S->py[q] + shy; S->sz[q] = S->pz[q] + shz; }
    long n_lost = 0;
    long k = pair(S, S->sy, S->sz, S->gate_shift, img, j, d2, &n_lost);
    *k_out = k;
    if (k < S->min_matches) return 3;
    k = settle(S, img, j, d2, k, n_lost, C_prior, C);
    *k_out = k;
    if (k < S->min_matches) return 4;
    long k2 = scatter_screen(img, j, d2, k, S->gate, S->tmp_d);
    if (k2 < k) {                                           /* refit without the outliers */
        k = k2;
        *k_out = k;
        double Cn[9];
        memcpy(Cn, C, sizeof Cn);
        fit(S, img, j, k, Cn, C);
        residuals2(S, img, j, k, C, d2);
    }
    k2 = unused_nearer(S->t, S->t_more, S->n_more, 1.0, 0.0, S->u, img, j, d2, k, C);
    if (k2 < k) {                                           /* refit without them */
        k = k2;
        *k_out = k;
        if (k < S->min_matches) return 4;
        double Cn[9];
        memcpy(Cn, C, sizeof Cn);
        fit(S, img, j, k, Cn, C);
        residuals2(S, img, j, k, C, d2);
    }
    long c = 0;
    for (long q = 0; q < S->m; q++)
        c += fabs(S->sy[q] - box[0]) <= box[2] && fabs(S->sz[q] - box[1]) <= box[3];
    *n_in = c;
    return 0;
}

static double tail_bound(long n, long k, double p)
{
    if (k <= 0) return 1.0;
    if (k > n || p <= 0.0) return 0.0;
    double log_c = lgamma(n + 1.0) - lgamma(k + 1.0) - lgamma(n - k + 1.0);
    double x = log_c + k * log(p < 1.0 ? p : 1.0);
    return exp(x < 0.0 ? x : 0.0);
}

/* _tracking._p_false */
static double track_p_false(const Scene *S, const double *d2, long k, long n_in)
{
    double stop = 1e-3 * S->limit / N_GATES;
    double r = S->gate_prior / S->gate;
    double look = r * r * r > 1.0 ? r * r * r : 1.0;
    double p1 = n_in * M_PI * S->gate * S->gate / S->area;
    double first = look * tail_bound(S->n_trials, k - 2, p1);
    if (first > stop) first = look * binom_tail(S->n_trials, k - 2, p1);
    if (first <= stop) { double p = N_GATES * first; return p < 1.0 ? p : 1.0; }
    double f[N_GATES], p1s[N_GATES];
    long nt[N_GATES], kk[N_GATES];
    for (int g = 0; g < N_GATES; g++) {
        double gg = S->gate * GATE_FRACTIONS[g], rr = S->gate_prior / gg;
        p1s[g] = n_in * M_PI * gg * gg / S->area;
        f[g] = rr * rr * rr > 1.0 ? rr * rr * rr : 1.0;
        nt[g] = S->n_trials;
        long c = 0;
        for (long i = 0; i < k; i++) c += d2[i] <= gg * gg;
        kk[g] = c - 2;
    }
    double p = N_GATES * min_chance(f, nt, kk, p1s, stop);
    return p < 1.0 ? p : 1.0;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : (x > y);
}

static double median_of(double *v, long n)
{
    qsort(v, n, sizeof(double), cmp_double);
    long k = n / 2;
    return n % 2 ? v[k] : 0.5 * (v[k - 1] + v[k]);
}

typedef struct {
    int code;                   /* 0 solved, else a reason (see _tracking.py) */
    long count;
    double p;
    int voted;
    double C[9];
    long k;
    double p_false;
} TrackOut;

static int track_run(Scene *S, const double *C_prior, const double *box, long *img, long *j,
                     double *d2, TrackOut *out)
{
    long nw = S->n < WIDE_STARS ? S->n : WIDE_STARS;
    int shift_ok = 0;
    double shy = 0, shz = 0;
    int code = 0;
    long count = 0;
    double pval = 0.0;
    /* median shift */
    if (S->m == 0) code = 1;
    else {
        double *oy = S->tmp_d, *oz = S->qy;      /* scratch: n >= nw, m >= 1 */
        long c = 0;
        double g2 = S->gate_prior * S->gate_prior;
        double *dz_buf = malloc((nw + 1) * sizeof(double));
        if (!dz_buf) return -1;
        for (long i = 0; i < nw; i++) {
            double best = INFINITY;
            long bj = -1;
            for (long q = 0; q < S->m; q++) {
                double dy = S->my[i] - S->py[q], dz = S->mz[i] - S->pz[q];
                double d = dy * dy + dz * dz;
                if (d < best) { best = d; bj = q; }
            }
            if (bj >= 0 && best <= g2) {
                oy[c] = S->my[i] - S->py[bj];
                dz_buf[c] = S->mz[i] - S->pz[bj];
                c++;
            }
        }
        if (c < S->min_matches) { code = 2; count = c; }
        else {
            shy = median_of(oy, c);
            shz = median_of(dz_buf, c);
            shift_ok = 1;
        }
        (void)oz;
        free(dz_buf);
    }
    long n_in = 0, k = 0;
    if (shift_ok) {
        code = scene_match(S, C_prior, shy, shz, box, img, j, d2, &k, &n_in, out->C);
        count = k;
        if (code == 0) {
            double p = track_p_false(S, d2, k, n_in);
            if (p <= S->limit) { out->code = 0; out->k = k; out->p_false = p; return 0; }
            code = 5; count = k; pval = p;
        }
    }
    /* vote */
    long nmax = nw * S->m;
    double *cy = malloc((nmax + 1) * sizeof(double)), *cz = malloc((nmax + 1) * sizeof(double));
    if (!cy || !cz) { free(cy); free(cz); return -1; }
    long K = 0;
    double gp2 = S->gate_prior * S->gate_prior;
    for (long i = 0; i < nw; i++)
        for (long q = 0; q < S->m; q++) {
            double dy = S->my[i] - S->py[q], dz = S->mz[i] - S->pz[q];
            if (dy * dy + dz * dz <= gp2) { cy[K] = dy; cz[K] = dz; K++; }
        }
    int have_vote = 0;
    double vy = 0, vz = 0;
    if (K > 0) {
        double r = 0.5 * S->gate_shift, r2 = r * r;
        long best = -1, best_c = -1;
        for (long a = 0; a < K; a++) {
            long c = 0;
            for (long b = 0; b < K; b++) {
                double ddy = cy[a] - cy[b], ddz = cz[a] - cz[b];
                c += ddy * ddy + ddz * ddz <= r2;
            }
            if (c > best_c) { best_c = c; best = a; }
        }
        double *sy = malloc((best_c + 1) * sizeof(double)), *sz = malloc((best_c + 1) * sizeof(double));
        if (!sy || !sz) { free(sy); free(sz); free(cy); free(cz); return -1; }
        long c = 0;
        for (long b = 0; b < K; b++) {
            double ddy = cy[best] - cy[b], ddz = cz[best] - cz[b];
            if (ddy * ddy + ddz * ddz <= r2) { sy[c] = cy[b]; sz[c] = cz[b]; c++; }
        }
        vy = median_of(sy, c);
        vz = median_of(sz, c);
        free(sy); free(sz);
        have_vote = 1;
    }
    free(cy); free(cz);
    if (!have_vote || (shift_ok && hypot(vy - shy, vz - shz) <= 0.5 * S->gate_shift)) {
        out->code = code; out->count = count; out->p = pval;
        return 0;
    }
    out->voted = 1;
    long k2 = 0, n_in2 = 0;
    double C2[9];
    int code2 = scene_match(S, C_prior, vy, vz, box, img, j, d2, &k2, &n_in2, C2);
    if (code2) { out->code = code; out->count = count; out->p = pval; return 0; }
    double p = 2.0 * track_p_false(S, d2, k2, n_in2);
    if (p > S->limit) { out->code = 5; out->count = k2; out->p = p; return 0; }
    memcpy(out->C, C2, sizeof C2);
    out->code = 0; out->k = k2; out->p_false = p;
    return 0;
}

/* Tracking of the stars t (n, 2), w (n, 3) from C_prior with iparams (grid_n,
 * min_matches, n_trials) and dparams (box[4], gate, gate_prior, gate_shift, area, limit):
 * 0 (out filled; solved when out->code == 0, then img / cat [0, out->k) and *rms), -1 no
 * memory.  img, cat: n longs. */
static int track_core(const double *t, const double *w, long n_stars, const double *t_more,
                      long n_more, const double *C_prior,
                      const double *cell_u, const int32_t *cell_start, const void *cell_index,
                      int ci16, const int64_t *I, const double *D, TrackOut *out, long *img, long *cat,
                      double *rms_out)
{
    long grid_n = (long)I[0];
    Scene S;
    memset(&S, 0, sizeof S);
    S.n = n_stars;
    S.t = t;
    S.w = w;
    S.t_more = t_more;
    S.n_more = n_more;
    S.min_matches = (long)I[1];
    S.n_trials = (long)I[2];
    double box[4] = {D[0], D[1], D[2], D[3]};
    S.gate = D[4]; S.gate_prior = D[5]; S.gate_shift = D[6]; S.area = D[7]; S.limit = D[8];
    memset(out, 0, sizeof *out);
    int rc = -1;
    double rms = NAN;
    double bore[3] = {C_prior[0], C_prior[3], C_prior[6]};
    long c = cell_of_one(bore, grid_n);
    long m_cell = cell_start[c + 1] - cell_start[c];
    long n = S.n > 0 ? S.n : 1, mc = m_cell > 0 ? m_cell : 1;
    double *my = malloc(n * sizeof(double)), *mz = malloc(n * sizeof(double));
    long *rows = malloc(mc * sizeof(long));
    double *u = malloc(3 * mc * sizeof(double)), *py = malloc(mc * sizeof(double)),
           *pz = malloc(mc * sizeof(double));
    S.sy = malloc(mc * sizeof(double)); S.sz = malloc(mc * sizeof(double));
    S.qy = malloc(mc * sizeof(double)); S.qz = malloc(mc * sizeof(double));
    S.wb = malloc(3 * n * sizeof(double)); S.vb = malloc(3 * n * sizeof(double));
    S.best_k = malloc(mc * sizeof(long)); S.lost_r = malloc(n * sizeof(long));
    S.ord = malloc(mc * sizeof(long)); S.sty = malloc(mc * sizeof(double));
    S.lost_j = malloc(n * sizeof(long)); S.tmp_i = malloc(n * sizeof(long));
    S.tmp_j = malloc(n * sizeof(long)); S.tmp_d = malloc(n * sizeof(double));
    long *j = malloc(n * sizeof(long));
    double *d2 = malloc(n * sizeof(double));
    if (my && mz && rows && u && py && pz && S.sy && S.sz && S.qy && S.qz && S.wb && S.vb && S.best_k
        && S.ord && S.sty && S.lost_r && S.lost_j && S.tmp_i && S.tmp_j && S.tmp_d && j && d2) {
        for (long i = 0; i < S.n; i++) { my[i] = S.t[2 * i]; mz[i] = S.t[2 * i + 1]; }
        S.my = my; S.mz = mz;
        long m = 0;
        double margin = S.gate_prior;
        for (long q = cell_start[c]; q < cell_start[c + 1]; q++) {
            long r = cell_row(cell_index, ci16, q);
            const double *uu = cell_u + 3 * q;
            double w0 = uu[0] * C_prior[0] + uu[1] * C_prior[3] + uu[2] * C_prior[6];
            double w1 = uu[0] * C_prior[1] + uu[1] * C_prior[4] + uu[2] * C_prior[7];
            double w2 = uu[0] * C_prior[2] + uu[1] * C_prior[5] + uu[2] * C_prior[8];
            double ty = w1 / w0, tz = w2 / w0;
            if (fabs(ty - box[0]) <= box[2] + margin && fabs(tz - box[1]) <= box[3] + margin) {
                rows[m] = r; memcpy(u + 3 * m, uu, 3 * sizeof(double)); py[m] = ty; pz[m] = tz; m++;
            }
        }
        S.m = m; S.rows = rows; S.u = u; S.py = py; S.pz = pz;
        rc = track_run(&S, C_prior, box, img, j, d2, out);
        if (rc == 0 && out->code == 0) {
            double ss = 0.0;
            for (long i = 0; i < out->k; i++) {
                const double *ww = S.w + 3 * img[i], *v = u + 3 * j[i];
                for (int r = 0; r < 3; r++) {
                    double x = out->C[3 * r] * ww[0] + out->C[3 * r + 1] * ww[1] + out->C[3 * r + 2] * ww[2] - v[r];
                    ss += x * x;
                }
            }
            rms = sqrt(ss / out->k) * RAD2ASEC;
            for (long i = 0; i < out->k; i++) cat[i] = rows[j[i]];
        }
    }
    free(my); free(mz); free(rows); free(u); free(py); free(pz); free(S.sy); free(S.sz); free(S.qy);
    free(S.qz); free(S.wb); free(S.vb); free(S.best_k); free(S.lost_r); free(S.lost_j); free(S.tmp_i);
    free(S.tmp_j); free(S.tmp_d); free(j); free(d2); free(S.ord); free(S.sty);
    *rms_out = rms;
    return rc;
}

/* (code, count, p, voted, n_match, p_false, rms_arcsec, 0.0); solved: out_C and the
 * star_index / hip outputs filled */
static PyObject *track_result(int rc, const TrackOut *out, const long *img, const long *cat, double rms,
                              Py_buffer *oc, const Py_buffer *bus, const Py_buffer *bh,
                              Py_buffer *ostar, Py_buffer *ohip)
{
    int scattered = 1;
    if (rc == 0 && out->code == 0) {
        memcpy(oc->buf, out->C, 9 * sizeof(double));
        int64_t *ii = malloc((out->k + 1) * sizeof(int64_t)), *cc = malloc((out->k + 1) * sizeof(int64_t));
        if (!ii || !cc) rc = -1;
        else {
            for (long i = 0; i < out->k; i++) { ii[i] = img[i]; cc[i] = cat[i]; }
            scattered = scatter_rows(ii, cc, out->k, bus, bh, ostar, ohip);
        }
        free(ii); free(cc);
    }
    if (rc < 0) return PyErr_NoMemory();
    if (!scattered) {
        PyErr_SetString(PyExc_IndexError, "track_solve: matched row out of range");
        return NULL;
    }
    return Py_BuildValue("ildilddd", out->code, out->count, out->p, out->voted, out->k, out->p_false,
                         rms, 0.0);
}

/* NULL with ValueError: a cell list that is neither uint16 nor uint32 rows of cell_start's count */
static PyObject *bad_cell_list(const char *entry)
{
    PyErr_Format(PyExc_ValueError, "%s: cell_index is neither uint16 nor uint32 of cell_start's rows", entry);
    return NULL;
}

/* track_solve(t, w, t_more, C_prior, cell_u, cell_start, cell_index, iparams, dparams,
 *             out_C, usable, hip_db, out_star, out_hip): t_more (n_more, 2) the usable
 *             detections beyond the n used (fainter; only a nearer one of them unnames
 *             a pair, unused_nearer)
 * iparams (int64): grid_n, min_matches, n_trials
 * dparams (float64): box[4] (cy, cz, hy, hz), gate, gate_prior, gate_shift, area, limit
 * returns (code, count, p, voted, n_match, p_false, rms_arcsec, 0.0) */
static PyObject *py_track_solve(PyObject *self, PyObject *args)
{
    Py_buffer bt, bw, bmore, bc, bu, bcs, bci, ip, dp, oc, bus, bh, ostar, ohip;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*w*y*y*w*w*", &bt, &bw, &bmore, &bc, &bu, &bcs, &bci,
                          &ip, &dp, &oc, &bus, &bh, &ostar, &ohip))
        return NULL;
    long n = (long)(bt.len / (2 * sizeof(double)));
    long n_more = (long)(bmore.len / (2 * sizeof(double)));
    long *img = malloc((n > 0 ? n : 1) * sizeof(long)), *cat = malloc((n > 0 ? n : 1) * sizeof(long));
    TrackOut out;
    memset(&out, 0, sizeof out);
    int rc = -1, ci16 = cell_list_u16(&bcs, &bci);
    double rms = NAN;
    if (img && cat && ci16 >= 0) {
        Py_BEGIN_ALLOW_THREADS
        rc = track_core(bt.buf, bw.buf, n, bmore.buf, n_more, bc.buf, bu.buf, bcs.buf, bci.buf, ci16, ip.buf,
                        dp.buf, &out, img, cat, &rms);
        Py_END_ALLOW_THREADS
    }
    PyObject *res = ci16 < 0 ? bad_cell_list("track_solve")
                             : track_result(rc, &out, img, cat, rms, &oc, &bus, &bh, &ostar, &ohip);
    free(img); free(cat);
    PyBuffer_Release(&bt); PyBuffer_Release(&bw); PyBuffer_Release(&bmore); PyBuffer_Release(&bc);
    PyBuffer_Release(&bu); PyBuffer_Release(&bcs); PyBuffer_Release(&bci); PyBuffer_Release(&ip);
    PyBuffer_Release(&dp); PyBuffer_Release(&oc); PyBuffer_Release(&bus); PyBuffer_Release(&bh);
    PyBuffer_Release(&ostar); PyBuffer_Release(&ohip);
    return res;
}

/* track_pinhole(xy, cam, C_prior, cell_u, cell_start, cell_index, iparams, dparams, out_C,
 *               out_u, hip_db, out_star, out_hip): track_solve from pixel centroids of a
 * camera without distortion, cam = (x0_px, y0_px, pixel_mm, f_mm), at focal scale 1, in
 * one call: out_u (N, 3) gets the stars' unit vectors; the brightest iparams[3] rows are
 * used (the others as t_more).  None when a centroid is not finite (the caller takes the
 * general path). */
static PyObject *py_track_pinhole(PyObject *self, PyObject *args)
{
    Py_buffer bx, bcam, bc, bu, bcs, bci, ip, dp, oc, ou, bh, ostar, ohip;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*w*w*y*w*w*", &bx, &bcam, &bc, &bu, &bcs, &bci, &ip,
                          &dp, &oc, &ou, &bh, &ostar, &ohip))
        return NULL;
    const int64_t *I = ip.buf;
    long n = (long)(bx.len / (2 * sizeof(double))), m = (long)I[3];
    long nn = n > 0 ? n : 1;
    long *img = malloc(nn * sizeof(long)), *cat = malloc(nn * sizeof(long));
    double *t = malloc(2 * nn * sizeof(double));
    TrackOut out;
    memset(&out, 0, sizeof out);
    int rc = -1, finite = 0, ci16 = cell_list_u16(&bcs, &bci);
    double rms = NAN;
    if (img && cat && t && ci16 >= 0 && m <= n && (long)(ou.len / (3 * sizeof(double))) == n) {
        Py_BEGIN_ALLOW_THREADS
        finite = unproject_rows(bx.buf, n, bcam.buf, ou.buf, t);
        if (finite)
            rc = track_core(t, ou.buf, m, t + 2 * m, n - m, bc.buf, bu.buf, bcs.buf, bci.buf, ci16, I, dp.buf,
                            &out, img, cat, &rms);
        Py_END_ALLOW_THREADS
    }
    PyObject *res;
    if (ci16 < 0) res = bad_cell_list("track_pinhole");
    else if (img && cat && t && !finite && rc == -1 && m <= n) { Py_INCREF(Py_None); res = Py_None; }
    else {
        Py_buffer none_used;
        memset(&none_used, 0, sizeof none_used);
        res = track_result(rc, &out, img, cat, rms, &oc, &none_used, &bh, &ostar, &ohip);
    }
    free(img); free(cat); free(t);
    PyBuffer_Release(&bx); PyBuffer_Release(&bcam); PyBuffer_Release(&bc); PyBuffer_Release(&bu);
    PyBuffer_Release(&bcs); PyBuffer_Release(&bci); PyBuffer_Release(&ip); PyBuffer_Release(&dp);
    PyBuffer_Release(&oc); PyBuffer_Release(&ou); PyBuffer_Release(&bh); PyBuffer_Release(&ostar);
    PyBuffer_Release(&ohip);
    return res;
}

/* wahba(w, v) -> C bytes (for tests: the compiled QUEST against the Python one) */
static PyObject *py_wahba(PyObject *self, PyObject *args)
{
    Py_buffer bw, bv, oc;
    if (!PyArg_ParseTuple(args, "y*y*w*", &bw, &bv, &oc)) return NULL;
    long n = (long)(bw.len / (3 * sizeof(double)));
    if (n >= 1) wahba(bw.buf, bv.buf, (int)n, NULL, oc.buf);
    PyBuffer_Release(&bw); PyBuffer_Release(&bv); PyBuffer_Release(&oc);
    Py_RETURN_NONE;
}

/* pinhole_unproject(xy, params[x0, y0, pixel_mm, f_mm], out_u, out_t) -> all finite
 * (Camera.unproject without distortion, then t = u[1:] / u[0]: the same arithmetic) */
static PyObject *py_pinhole_unproject(PyObject *self, PyObject *args)
{
    Py_buffer bx, bp, ou, ot;
    if (!PyArg_ParseTuple(args, "y*y*w*w*", &bx, &bp, &ou, &ot)) return NULL;
    int finite = unproject_rows(bx.buf, (long)(bx.len / (2 * sizeof(double))), bp.buf, ou.buf, ot.buf);
    PyBuffer_Release(&bx); PyBuffer_Release(&bp); PyBuffer_Release(&ou); PyBuffer_Release(&ot);
    return PyBool_FromLong(finite);
}

/* unit_rows(t, s, k1, out): StarField.unit(s, k1=k1) for every row */
static PyObject *py_unit_rows(PyObject *self, PyObject *args)
{
    Py_buffer bt, ou;
    double s, k1;
    if (!PyArg_ParseTuple(args, "y*ddw*", &bt, &s, &k1, &ou)) return NULL;
    unit_rows_of(bt.buf, (long)(bt.len / (2 * sizeof(double))), s, k1, ou.buf);
    PyBuffer_Release(&bt); PyBuffer_Release(&ou);
    Py_RETURN_NONE;
}

/* scatter(img, cat, usable, hip_db, out_star, out_hip): out_star[usable[img]] = cat,
 * out_hip[...] = hip_db[cat], -1 elsewhere (usable empty: the identity) */
static PyObject *py_scatter(PyObject *self, PyObject *args)
{
    Py_buffer bi, bc, bu, bh, os, oh;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*w*", &bi, &bc, &bu, &bh, &os, &oh)) return NULL;
    const int64_t *img = bi.buf, *cat = bc.buf, *usable = bu.buf;
    const int32_t *hip = bh.buf;
    int64_t *star = os.buf, *ohip = oh.buf;
    long k = (long)(bi.len / sizeof(int64_t)), n = (long)(os.len / sizeof(int64_t));
    long n_use = (long)(bu.len / sizeof(int64_t)), n_hip = (long)(bh.len / sizeof(int32_t));
    int ok = 1;
    for (long i = 0; i < n; i++) { star[i] = -1; ohip[i] = -1; }
    for (long i = 0; i < k && ok; i++) {
        long r = n_use ? (img[i] >= 0 && img[i] < n_use ? (long)usable[img[i]] : -1) : (long)img[i];
        if (r < 0 || r >= n || cat[i] < 0 || cat[i] >= n_hip) { ok = 0; break; }
        star[r] = cat[i];
        ohip[r] = hip[cat[i]];
    }
    PyBuffer_Release(&bi); PyBuffer_Release(&bc); PyBuffer_Release(&bu); PyBuffer_Release(&bh);
    PyBuffer_Release(&os); PyBuffer_Release(&oh);
    if (!ok) {
        PyErr_SetString(PyExc_IndexError, "scatter: index out of range");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* The i-th of a stored array's sampled rows, i in [0, SAMPLE_RUNS * SAMPLE_RUN]: runs of
 * SAMPLE_RUN consecutive rows at SAMPLE_RUNS evenly spaced starts over [0, n), and
 * (i == SAMPLE_RUNS * SAMPLE_RUN) the last row.  Runs, not single rows spread evenly:
 * the same number of rows from ~1/16 of the pages (each first touch of a page of the
 * mapped cache file is a fault, which maps its 16-page neighbourhood). */
#define SAMPLE_RUNS 32
#define SAMPLE_RUN 16
static long sampled_row(long i, long n)
{
    if (i >= SAMPLE_RUNS * SAMPLE_RUN) return n - 1;
    long r = (i / SAMPLE_RUN) * (n / SAMPLE_RUNS) + i % SAMPLE_RUN;
    return r < n ? r : n - 1;
}

/* The consistency of a database's arrays (every index the kernels follow stays inside
 * its array) and its cell vectors, in one pass over each array: 0 consistent (cell_u
 * filled when `gather`), 1 offsets / star rows out of range, 2 a key bucket not sorted
 * by key_lo, 3 stored vectors (not `gather`) that are not those of the star rows. */
static int db_check_gather(const void *pstars, int p16, long P, const uint16_t *key_lo,
                           const int32_t *khs, long n_seg, const int32_t *cs, long n_cells,
                           const void *ci, int ci16, long M, const double *u64, const float *u32,
                           long S, double *cell_u, uint16_t *size_q, double quantum, int gather)
{
    if (!(quantum > 0.0)) return 1;
    if (khs[0] != 0 || khs[n_seg] != P || cs[0] != 0 || cs[n_cells] != M) return 1;
    int bad = 0;
    for (long h = 0; h < n_seg; h++) bad |= khs[h + 1] < khs[h];
    for (long c = 0; c < n_cells; c++) bad |= cs[c + 1] < cs[c];
    if (bad) return 1;
    long mx_cell = 0;
    for (long q = 0; q < M; q++) {
        long r = cell_row(ci, ci16, q);
        mx_cell = r > mx_cell ? r : mx_cell;
    }
    if (M > 0 && mx_cell >= S) return 1;
    uint32_t mx = 0;
    Db db;
    memset(&db, 0, sizeof db);
    db.pstars = pstars;
    db.pstars16 = p16;
    db.n_stars = S;
    double dots[6];
    int emin;
    uint32_t ps[4];
    if (gather) {
        /* made here (a database just built, or one whose stored arrays are missing):
         * every star row, and every bucket sorted by key_lo (the look-up reads it so):
         * each descent of key_lo (one linear pass) must be at the first row of a bucket */
        mx = 0;
        if (p16) {
            const uint16_t *p = pstars;
            uint16_t m16 = 0;
            for (long i = 0; i < 4 * P; i++) m16 = p[i] > m16 ? p[i] : m16;
            mx = m16;
        } else {
            const uint32_t *p = pstars;
            for (long i = 0; i < 4 * P; i++) mx = p[i] > mx ? p[i] : mx;
        }
        if (P > 0 && (long)mx >= S) return 1;
        long descents = 0, at_starts = 0;
        for (long r = 1; r < P; r++) descents += key_lo[r] < key_lo[r - 1];
        for (long h = 0; h < n_seg; h++) {
            long r = khs[h];
            at_starts += r > 0 && r < khs[h + 1] && key_lo[r] < key_lo[r - 1];
        }
        if (descents != at_starts) return 2;
        for (long q = 0; q < M; q++) {
            const double *u = u64 + 3 * cell_row(ci, ci16, q);
            double *o = cell_u + 3 * q;
            o[0] = u[0]; o[1] = u[1]; o[2] = u[2];
        }
        for (long r = 0; r < P; r++) {
            pattern_row(&db, r, ps);
            size_q[r] = size_step(largest_edge(u32, ps, dots, &emin), quantum);
        }
        return 0;
    }
    /* Stored (mapped from the cache file, which was checked in full when it was built):
     * a sample, as reading every row would cost more than a one-shot solve's search
     * (~20-50 ms for a 2.3 million-pattern database).  A misplaced or foreign array is
     * refused all the same; elsewhere, a star row out of range is skipped by the look-up
     * (pattern_row_in), and a changed size step or key order can only drop a match, never
     * make a wrong one.  Each array is checked on the same 513 rows of it (sampled_row:
     * runs, so that few of its pages are touched: each first touch of a mapped page is a
     * fault; 513 single rows spread evenly cost 16-19 ms for the 2.3 million-pattern
     * database here, every 61st row of the vectors more).  Key buckets sorted by key_lo: */
    const long n_samples = SAMPLE_RUNS * SAMPLE_RUN + 1;
    for (long i = 0; i < n_samples && n_seg > 0; i++) {
        long h = sampled_row(i, n_seg);
        for (long r = (long)khs[h] + 1; r < khs[h + 1]; r++)
            if (key_lo[r] < key_lo[r - 1]) return 2;
    }
    /* star rows in range, size steps as made here (each costs random reads of its stars) */
    for (long i = 0; i < n_samples && P > 0; i++) {
        long r = sampled_row(i, P);
        if (!pattern_row_in(&db, r, ps)) return 1;
        if (size_q[r] != size_step(largest_edge(u32, ps, dots, &emin), quantum)) return 3;
    }
    /* stored (memory-mapped) vectors as made here (a misplaced or foreign array is
     * refused; they index nothing, so a changed value elsewhere can only spoil a match, as
     * a changed u_icrs would) */
    for (long i = 0; i < n_samples && M > 0; i++) {
        long q = sampled_row(i, M);
        const double *u = u64 + 3 * cell_row(ci, ci16, q), *o = cell_u + 3 * q;
        if (o[0] != u[0] || o[1] != u[1] || o[2] != u[2]) return 3;
    }
    for (long k = 0; k < n_samples && S > 0; k++) {
        long i = sampled_row(k, S);
        const double *u = u64 + 3 * i;
        const float *f = u32 + 3 * i;
        double n2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
        if (!(fabs(n2 - 1.0) < 1e-12 && fabs(u[0] - f[0]) < 1e-6 && fabs(u[1] - f[1]) < 1e-6
              && fabs(u[2] - f[2]) < 1e-6))
            return 3;
    }
    return 0;
}

/* db_prepare(pstars (P, 4) uint16 or uint32, key_lo (P,) uint16, key_hi_start (H + 1,)
 * int32, cell_start (C + 1,) int32, cell_index (M,) uint16 or uint32 (told apart by
 * length, M = cell_start[C]), u64 (S, 3) float64,
 * cell_u (M, 3) float64, u32 (S, 3) float32, size_q (P,) uint16, size_quantum, gather)
 * -> 0 consistent (gather: cell_u = u64[cell_index] and each pattern's size step
 * written; else the stored cell_u, size_q and u64 checked on a sample), 1
 * offsets or star rows out of range, 2 a key bucket not sorted by key_lo, 3 stored
 * vectors not those of the stars (see db_check_gather); the sizes are checked here, the
 * dtypes by the caller (_kernels.py) */
static PyObject *py_db_prepare(PyObject *self, PyObject *args)
{
    Py_buffer bp, bk, bh, bs, bi, bu, bo, bf, bz;
    double quantum;
    int gather;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*dp", &bp, &bk, &bh, &bs, &bi, &bu, &bo, &bf, &bz,
                          &quantum, &gather))
        return NULL;
    if (gather && (bo.readonly || bz.readonly)) {
        PyBuffer_Release(&bp); PyBuffer_Release(&bk); PyBuffer_Release(&bh); PyBuffer_Release(&bs);
        PyBuffer_Release(&bi); PyBuffer_Release(&bu); PyBuffer_Release(&bo); PyBuffer_Release(&bf);
        PyBuffer_Release(&bz);
        PyErr_SetString(PyExc_ValueError, "db_prepare: cell_u and size_q must be writable to be made");
        return NULL;
    }
    long P = (long)(bk.len / sizeof(uint16_t)), n_seg = (long)(bh.len / sizeof(int32_t)) - 1;
    long n_cells = (long)(bs.len / sizeof(int32_t)) - 1;
    int ci16 = cell_list_u16(&bs, &bi);
    long M = (long)(bi.len / (ci16 == 1 ? sizeof(uint16_t) : sizeof(uint32_t)));
    long S = (long)(bu.len / (3 * sizeof(double)));
    int p16 = bp.len == (Py_ssize_t)(8 * P), rc = 1;
    if (n_seg >= 0 && n_cells >= 0 && ci16 >= 0 && (p16 || bp.len == (Py_ssize_t)(16 * P))
            && bo.len == (Py_ssize_t)(3 * sizeof(double) * M)
            && bf.len == (Py_ssize_t)(3 * sizeof(float) * S)
            && bz.len == (Py_ssize_t)(sizeof(uint16_t) * P)) {
        Py_BEGIN_ALLOW_THREADS
        rc = db_check_gather(bp.buf, p16, P, bk.buf, bh.buf, n_seg, bs.buf, n_cells, bi.buf, ci16, M,
                             bu.buf, bf.buf, S, (double *)bo.buf, (uint16_t *)bz.buf, quantum, gather);
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&bp); PyBuffer_Release(&bk); PyBuffer_Release(&bh); PyBuffer_Release(&bs);
    PyBuffer_Release(&bi); PyBuffer_Release(&bu); PyBuffer_Release(&bo); PyBuffer_Release(&bf);
    PyBuffer_Release(&bz);
    return PyLong_FromLong(rc);
}

static PyObject *py_binom_tail(PyObject *self, PyObject *args)
{
    long n, k;
    double p;
    if (!PyArg_ParseTuple(args, "lld", &n, &k, &p)) return NULL;
    return PyFloat_FromDouble(binom_tail(n, k, p));
}

static PyObject *py_tail_bound(PyObject *self, PyObject *args)
{
    long n, k;
    double p;
    if (!PyArg_ParseTuple(args, "lld", &n, &k, &p)) return NULL;
    return PyFloat_FromDouble(tail_bound(n, k, p));
}

static PyMethodDef methods[] = {
    {"lis_solve", py_lis_solve, METH_VARARGS, "lost-in-space search (see _kernels.py)"},
    {"track_solve", py_track_solve, METH_VARARGS, "tracking (see _kernels.py)"},
    {"lis_pinhole", py_lis_pinhole, METH_VARARGS, "lis_solve from pixel centroids (see _kernels.py)"},
    {"track_pinhole", py_track_pinhole, METH_VARARGS, "track_solve from pixel centroids (see _kernels.py)"},
    {"wahba", py_wahba, METH_VARARGS, "QUEST of unit vectors (see _kernels.py)"},
    {"pinhole_unproject", py_pinhole_unproject, METH_VARARGS, "see _kernels.py"},
    {"unit_rows", py_unit_rows, METH_VARARGS, "see _kernels.py"},
    {"scatter", py_scatter, METH_VARARGS, "see _kernels.py"},
    {"db_prepare", py_db_prepare, METH_VARARGS, "database consistency and cell vectors (see _kernels.py)"},
    {"binom_tail", py_binom_tail, METH_VARARGS, "P(Bin(n, p) >= k)"},
    {"tail_bound", py_tail_bound, METH_VARARGS, "C(n, k) p^k, a bound on P(Bin(n, p) >= k)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_ckernels",
                                    "Compiled star-identification loops (see _kernels.py).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__ckernels(void)
{
    init_perms();
    return module_with_source_digest(PyModule_Create(&moddef));
}
