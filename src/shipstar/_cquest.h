/* QUEST in plain C99, shared by the compiled kernels of shipstar.identify and
 * shipstar.attitude (included by both; every function static inline).
 *
 * The same steps and constants as shipstar.attitude._quest.quest_single: Newton's
 * iteration for lambda_max, the method of sequential rotations when |q4| < 0.3, one
 * re-solve with the Rayleigh quotient.  Includes <math.h>. */
#ifndef SHIPSTAR_CQUEST_H
#define SHIPSTAR_CQUEST_H

#include <math.h>


static const double FRAME_SIGNS[4][3] = {{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}};

static inline void k_parts(const double *b, double *s, double *sigma, double *z)
{
    s[0] = 2.0 * b[0]; s[1] = b[1] + b[3]; s[2] = b[2] + b[6];
    s[3] = 2.0 * b[4]; s[4] = b[5] + b[7]; s[5] = 2.0 * b[8];
    *sigma = b[0] + b[4] + b[8];
    z[0] = b[5] - b[7]; z[1] = b[6] - b[2]; z[2] = b[1] - b[3];
}

static inline void sym_mul(const double *s, const double *x, double *out)
{
    out[0] = s[0] * x[0] + s[1] * x[1] + s[2] * x[2];
    out[1] = s[1] * x[0] + s[3] * x[1] + s[4] * x[2];
    out[2] = s[2] * x[0] + s[4] * x[1] + s[5] * x[2];
}

static inline void kappa_delta(const double *s, double *kappa, double *delta)
{
    double m00 = s[3] * s[5] - s[4] * s[4];
    *kappa = m00 + s[0] * s[5] - s[2] * s[2] + s[0] * s[3] - s[1] * s[1];
    *delta = s[0] * m00 - s[1] * (s[1] * s[5] - s[4] * s[2]) + s[2] * (s[1] * s[4] - s[3] * s[2]);
}

static inline void lambda_max(const double *b, double *lam_out, double *dp_out)
{
    double s[6], sigma, z[3], kappa, delta, sz[3];
    k_parts(b, s, &sigma, z);
    kappa_delta(s, &kappa, &delta);
    sym_mul(s, z, sz);
    double zz = z[0] * z[0] + z[1] * z[1] + z[2] * z[2];
    double zsz = z[0] * sz[0] + z[1] * sz[1] + z[2] * sz[2];
    double zs2z = sz[0] * sz[0] + sz[1] * sz[1] + sz[2] * sz[2];
    double ca = sigma * sigma - kappa, cb = sigma * sigma + zz, cc = delta + zsz;
    double p2 = -(ca + cb), p1 = -cc, p0 = ca * cb + cc * sigma - zs2z;
    double lam = 1.0;
    for (int it = 0; it < 60; it++) {
        double lam2 = lam * lam;
        double f = (lam2 + p2) * lam2 + p1 * lam + p0;
        double fp = (4.0 * lam2 + 2.0 * p2) * lam + p1;
        double step = fp != 0.0 ? f / fp : 0.0;
        lam = lam - step;
        if (fabs(step) <= 1e-15) break;
    }
    *lam_out = lam;
    *dp_out = (4.0 * lam * lam + 2.0 * p2) * lam + p1;
}

static inline void flip_b(const double *b, int frame, double *out)
{
    const double *g = FRAME_SIGNS[frame];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) out[3 * i + j] = g[j] * b[3 * i + j];
}

static inline void frame_solution(const double *b, double lam, double *x, double *gamma)
{
    double s[6], sigma, z[3], kappa, delta, sz[3], ssz[3];
    k_parts(b, s, &sigma, z);
    kappa_delta(s, &kappa, &delta);
    double alpha = lam * lam - sigma * sigma + kappa;
    double beta = lam - sigma;
    *gamma = (lam + sigma) * alpha - delta;
    sym_mul(s, z, sz);
    sym_mul(s, sz, ssz);
    for (int k = 0; k < 3; k++) x[k] = alpha * z[k] + beta * sz[k] + ssz[k];
}

static inline double rayleigh(const double *b, const double *qv, double q4)
{
    double s[6], sigma, z[3], sq[3];
    k_parts(b, s, &sigma, z);
    sym_mul(s, qv, sq);
    double qq = qv[0] * qv[0] + qv[1] * qv[1] + qv[2] * qv[2];
    double num = (qv[0] * sq[0] + qv[1] * sq[1] + qv[2] * sq[2] - sigma * qq
                  + 2.0 * q4 * (z[0] * qv[0] + z[1] * qv[1] + z[2] * qv[2]) + sigma * q4 * q4);
    return num / (qq + q4 * q4);
}

/* C (row-major 3x3) from the profile matrix b (row-major B = sum v w^T / n) */
static inline void quest_b(const double *b, double *C)
{
    double lam, dp, x[3], gamma, bk[9];
    lambda_max(b, &lam, &dp);
    frame_solution(b, lam, x, &gamma);
    int k = 0;
    if (gamma < 0.3 * 0.3 * dp) {
        double best = -INFINITY;
        for (int i = 0; i < 4; i++) {
            double xi[3], gi;
            flip_b(b, i, bk);
            frame_solution(bk, lam, xi, &gi);
            if (gi > best) { best = gi; k = i; x[0] = xi[0]; x[1] = xi[1]; x[2] = xi[2]; gamma = gi; }
        }
    }
    flip_b(b, k, bk);
    double lr = rayleigh(bk, x, gamma);
    frame_solution(bk, lr, x, &gamma);
    double n = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + gamma * gamma);
    if (!(n > 0.0)) n = NAN;
    double q0 = x[0] / n, q1 = x[1] / n, q2 = x[2] / n, q4 = gamma / n;
    double d = q4 * q4 - (q0 * q0 + q1 * q1 + q2 * q2);
    double A[9] = {d + 2 * q0 * q0, 2 * q0 * q1 + 2 * q4 * q2, 2 * q0 * q2 - 2 * q4 * q1,
                   2 * q1 * q0 - 2 * q4 * q2, d + 2 * q1 * q1, 2 * q1 * q2 + 2 * q4 * q0,
                   2 * q2 * q0 + 2 * q4 * q1, 2 * q2 * q1 - 2 * q4 * q0, d + 2 * q2 * q2};
    const double *g = FRAME_SIGNS[k];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) C[3 * i + j] = A[3 * i + j] * g[j];
}

/* C_ref_from_body for n matched unit vectors w (body) and v (ref), rows of 3;
 * with C_near (not NULL): C_near @ quest(w, v @ C_near) (_verify.wahba). */
static inline void wahba(const double *w, const double *v, int n, const double *C_near, double *C)
{
    double b[9] = {0};
    for (int i = 0; i < n; i++) {
        double vi[3];
        if (C_near) {
            for (int c = 0; c < 3; c++)
                vi[c] = v[3 * i] * C_near[c] + v[3 * i + 1] * C_near[3 + c] + v[3 * i + 2] * C_near[6 + c];
        } else {
            vi[0] = v[3 * i]; vi[1] = v[3 * i + 1]; vi[2] = v[3 * i + 2];
        }
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) b[3 * r + c] += vi[r] * w[3 * i + c];
    }
    double inv = 1.0 / n;
    for (int k = 0; k < 9; k++) b[k] *= inv;
    if (!C_near) {
        quest_b(b, C);
        return;
    }
    double Cs[9];
    quest_b(b, Cs);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            C[3 * r + c] = C_near[3 * r] * Cs[c] + C_near[3 * r + 1] * Cs[3 + c] + C_near[3 * r + 2] * Cs[6 + c];
}

#endif /* SHIPSTAR_CQUEST_H */
