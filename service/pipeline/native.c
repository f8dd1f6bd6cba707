/* Compiled kernels of the pipeline's innermost loops: per-row serial-chain kinematics,
 * the rotation error and the damped-least-squares step (see native.py for the
 * typed wrappers and why they are compiled).
 *
 * Plain C99 and the CPython API only (no numpy headers: arrays arrive through the buffer
 * protocol, already checked by the wrappers for dtype, shape and contiguity), so the
 * extension builds with the C compiler every CPython build has and needs nothing at run
 * time. Each kernel loops over the batch's rows with the GIL released; a row's result
 * depends on that row alone.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "row_helper.h"

/* ---------------------------------------------------------------- chain kinematics */

/* fixed (n, 4, 4): joint i's fixed transform from the previous joint's frame, its axis
 * turned onto z; tip (4, 4); q (B, n) -> position (B, 3), rotation (B, 3, 3), jacobian
 * (B, 6, n): linear rows z_i x (p_ee - p_i), then angular rows z_i. */
static void chain_rows(const double *fixed, const double *tip, Py_ssize_t n,
                       const double *q, Py_ssize_t batch, double *position,
                       double *rotation, double *jacobian) {
    double z[64][3], p[64][3];
    for (Py_ssize_t b = 0; b < batch; ++b) {
        double R[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, t[3] = {0, 0, 0};
        const double *qb = q + b * n;
        for (Py_ssize_t i = 0; i < n; ++i) {
            const double *F = fixed + 16 * i;
            double next[3][3];
            for (int r = 0; r < 3; ++r) {
                double moved = t[r];
                for (int k = 0; k < 3; ++k) moved += R[r][k] * F[4 * k + 3];
                for (int c = 0; c < 3; ++c)
                    next[r][c] = R[r][0] * F[c] + R[r][1] * F[4 + c] + R[r][2] * F[8 + c];
                p[i][r] = moved;
            }
            /* R Rz(q): x <- c x + s y, y <- c y - s x on the frame's columns. */
            double c = cos(qb[i]), s = sin(qb[i]);
            for (int r = 0; r < 3; ++r) {
                double x = next[r][0], y = next[r][1];
                R[r][0] = c * x + s * y;
                R[r][1] = c * y - s * x;
                R[r][2] = next[r][2];
                t[r] = p[i][r];
                z[i][r] = R[r][2];
            }
        }
        double *pos = position + 3 * b, *rot = rotation + 9 * b, *jac = jacobian + 6 * n * b;
        for (int r = 0; r < 3; ++r) {
            double moved = t[r];
            for (int k = 0; k < 3; ++k) moved += R[r][k] * tip[4 * k + 3];
            pos[r] = moved;
            for (int c = 0; c < 3; ++c)
                rot[3 * r + c] = R[r][0] * tip[c] + R[r][1] * tip[4 + c] + R[r][2] * tip[8 + c];
        }
        for (Py_ssize_t i = 0; i < n; ++i) {
            double lx = pos[0] - p[i][0], ly = pos[1] - p[i][1], lz = pos[2] - p[i][2];
            jac[0 * n + i] = z[i][1] * lz - z[i][2] * ly;
            jac[1 * n + i] = z[i][2] * lx - z[i][0] * lz;
            jac[2 * n + i] = z[i][0] * ly - z[i][1] * lx;
            jac[3 * n + i] = z[i][0];
            jac[4 * n + i] = z[i][1];
            jac[5 * n + i] = z[i][2];
        }
    }
}

/* ---------------------------------------------------------------- rotation error */

#define COS_150_DEG (-0.86602540378443860)

/* Rotation vector of M (row-major 3 x 3), NaN unless M is finite with det M > 0. Below
 * 150 degrees from the skew part, (theta / sin theta) vee((M - M^T) / 2); beyond, from the
 * quaternion of the largest of the trace and the diagonal (Markley's choice, as scipy's
 * Rotation.from_matrix makes it), scalar part made non-negative, 2 atan2(|v|, w) v / |v|. */
static void rotation_log_row(const double *M, double *out) {
    int finite = 1;
    for (int k = 0; k < 9; ++k) finite &= isfinite(M[k]) != 0;
    double det = M[0] * (M[4] * M[8] - M[5] * M[7]) - M[1] * (M[3] * M[8] - M[5] * M[6]) +
                 M[2] * (M[3] * M[7] - M[4] * M[6]);
    if (!finite || !(det > 0.0)) {
        out[0] = out[1] = out[2] = NAN;
        return;
    }
    double sx = 0.5 * (M[7] - M[5]), sy = 0.5 * (M[2] - M[6]), sz = 0.5 * (M[3] - M[1]);
    double trace = M[0] + M[4] + M[8];
    double cosine = 0.5 * (trace - 1.0);
    if (cosine >= COS_150_DEG) {
        double sine = sqrt(sx * sx + sy * sy + sz * sz);
        double scale = sine > 1e-8 ? atan2(sine, cosine) / sine : 1.0;
        out[0] = sx * scale;
        out[1] = sy * scale;
        out[2] = sz * scale;
        return;
    }
    double quat[4]; /* x, y, z, w */
    int choice = 3;
    double best = trace;
    for (int i = 0; i < 3; ++i)
        if (M[4 * i] > best) best = M[4 * i], choice = i;
    if (choice == 3) {
        quat[0] = M[7] - M[5];
        quat[1] = M[2] - M[6];
        quat[2] = M[3] - M[1];
        quat[3] = 1.0 + trace;
    } else {
        int i = choice, j = (i + 1) % 3, k = (j + 1) % 3;
        quat[i] = 1.0 - trace + 2.0 * M[4 * i];
        quat[j] = M[3 * j + i] + M[3 * i + j];
        quat[k] = M[3 * k + i] + M[3 * i + k];
        quat[3] = M[3 * k + j] - M[3 * j + k];
    }
    double norm = sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3]);
    double sign = quat[3] < 0.0 ? -1.0 : 1.0;
    for (int k = 0; k < 4; ++k) quat[k] *= sign / norm;
    double vector_norm = sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2]);
    double angle = 2.0 * atan2(vector_norm, quat[3]);
    double scale = angle / sin(0.5 * angle);
    for (int k = 0; k < 3; ++k) out[k] = quat[k] * scale;
}

/* target (3, 3), rotation (B, 3, 3) -> error (B, 3) = log(R* R^T). */
static void rotation_error_rows(const double *target, const double *rotation, Py_ssize_t batch,
                                double *error) {
    for (Py_ssize_t b = 0; b < batch; ++b) {
        const double *R = rotation + 9 * b;
        double M[9];
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                M[3 * r + c] = target[3 * r] * R[3 * c] + target[3 * r + 1] * R[3 * c + 1] +
                               target[3 * r + 2] * R[3 * c + 2];
        rotation_log_row(M, error + 3 * b);
    }
}

/* ---------------------------------------------------------------- task residual */

/* The axis task's two rows (rotations.axis_error): F holds rows b1, b2 (orthonormal, b1 x
 * b2 = the target axis a*) and u, the tool axis in the end-effector frame; with a = R u
 * and s_k = b_k . a, e = -(theta / sin theta) s (|e| = theta, the angle from a to a*; pi
 * where a is opposite a*) and J's row k is (a x b_k) . z_i from the angular rows. */
static void axis_rows(const double *F, const double *R, const double *full, Py_ssize_t n,
                      double *e, double *J) {
    double a[3], target[3], s[2], normal[2][3];
    for (int r = 0; r < 3; ++r) a[r] = R[3 * r] * F[6] + R[3 * r + 1] * F[7] + R[3 * r + 2] * F[8];
    target[0] = F[1] * F[5] - F[2] * F[4];
    target[1] = F[2] * F[3] - F[0] * F[5];
    target[2] = F[0] * F[4] - F[1] * F[3];
    for (int k = 0; k < 2; ++k) {
        const double *b = F + 3 * k;
        s[k] = b[0] * a[0] + b[1] * a[1] + b[2] * a[2];
        normal[k][0] = a[1] * b[2] - a[2] * b[1];
        normal[k][1] = a[2] * b[0] - a[0] * b[2];
        normal[k][2] = a[0] * b[1] - a[1] * b[0];
    }
    double sine = sqrt(s[0] * s[0] + s[1] * s[1]);
    double cosine = a[0] * target[0] + a[1] * target[1] + a[2] * target[2];
    if (sine > 1e-8) {
        double scale = atan2(sine, cosine) / sine;
        e[0] = -scale * s[0];
        e[1] = -scale * s[1];
    } else if (cosine < 0.0) {
        e[0] = 3.14159265358979323846;
        e[1] = 0.0;
    } else {
        e[0] = -s[0];
        e[1] = -s[1];
    }
    for (int k = 0; k < 2; ++k)
        for (Py_ssize_t i = 0; i < n; ++i)
            J[k * n + i] = normal[k][0] * full[3 * n + i] + normal[k][1] * full[4 * n + i] +
                           normal[k][2] * full[5 * n + i];
}

/* The chain kinematics (chain_rows) and the task error in one pass per row: error (B, m) =
 * the constrained position axes of target - p, then the orientation rows: (pose task, 3)
 * log(R* R^T) with the geometric Jacobian's rows `rows`, or (axis task, 2) axis_rows with
 * target_rotation holding its frame; jacobian (B, m, n), the position axes' rows first. */
static void residual_rows(const double *fixed, const double *tip, Py_ssize_t n, const double *q,
                          Py_ssize_t batch, const long long *rows, Py_ssize_t m,
                          Py_ssize_t m_position, const double *target_position,
                          const double *target_rotation, double *error, double *jacobian) {
    double position[3], rotation[9], full[6 * 64];
    for (Py_ssize_t b = 0; b < batch; ++b) {
        chain_rows(fixed, tip, n, q + b * n, 1, position, rotation, full);
        double *e = error + b * m, *J = jacobian + b * m * n;
        for (Py_ssize_t i = 0; i < m_position; ++i)
            e[i] = target_position[i] - position[rows[i]];
        if (target_rotation != NULL && m - m_position == 2) {
            axis_rows(target_rotation, rotation, full, n, e + m_position, J + m_position * n);
            for (Py_ssize_t r = 0; r < m_position; ++r)
                memcpy(J + r * n, full + rows[r] * n, n * sizeof(double));
            continue;
        }
        if (target_rotation != NULL) rotation_error_rows(target_rotation, rotation, 1, e + m_position);
        for (Py_ssize_t r = 0; r < m; ++r) memcpy(J + r * n, full + rows[r] * n, n * sizeof(double));
    }
}

/* ---------------------------------------------------------------- DLS step */

/* jacobian (B, m, n), error (B, m), damping -> step (B, n) = J^T (J J^T + damping^2 I)^-1 e
 * by Gaussian elimination with partial pivoting (LAPACK gesv's choice of pivots). A row
 * with a non-finite entry gets NaN; a row whose system is exactly singular gets NaN and
 * is flagged in `singular` (1) for the caller's pseudo-inverse. */
static void dls_rows(const double *jacobian, const double *error, Py_ssize_t batch, Py_ssize_t m,
                     Py_ssize_t n, double damping, double *step, unsigned char *singular) {
    double A[6][6], y[6];
    for (Py_ssize_t b = 0; b < batch; ++b) {
        const double *J = jacobian + b * m * n, *e = error + b * m;
        double *dq = step + b * n;
        singular[b] = 0;
        int finite = 1;
        for (Py_ssize_t k = 0; k < m * n; ++k) finite &= isfinite(J[k]) != 0;
        for (Py_ssize_t k = 0; k < m; ++k) finite &= isfinite(e[k]) != 0;
        if (!finite) {
            for (Py_ssize_t k = 0; k < n; ++k) dq[k] = NAN;
            continue;
        }
        for (Py_ssize_t r = 0; r < m; ++r) {
            for (Py_ssize_t c = r; c < m; ++c) {
                double sum = 0.0;
                for (Py_ssize_t k = 0; k < n; ++k) sum += J[r * n + k] * J[c * n + k];
                A[r][c] = A[c][r] = sum;
            }
            A[r][r] += damping * damping;
            y[r] = e[r];
        }
        int failed = 0;
        for (Py_ssize_t col = 0; col < m && !failed; ++col) {
            Py_ssize_t pivot = col;
            for (Py_ssize_t r = col + 1; r < m; ++r)
                if (fabs(A[r][col]) > fabs(A[pivot][col])) pivot = r;
            if (A[pivot][col] == 0.0) {
                failed = 1;
                break;
            }
            if (pivot != col) {
                for (Py_ssize_t c = 0; c < m; ++c) {
                    double swap = A[col][c];
                    A[col][c] = A[pivot][c];
                    A[pivot][c] = swap;
                }
                double swap = y[col];
                y[col] = y[pivot];
                y[pivot] = swap;
            }
            for (Py_ssize_t r = col + 1; r < m; ++r) {
                double factor = A[r][col] / A[col][col];
                for (Py_ssize_t c = col; c < m; ++c) A[r][c] -= factor * A[col][c];
                y[r] -= factor * y[col];
            }
        }
        if (failed) {
            singular[b] = 1;
            for (Py_ssize_t k = 0; k < n; ++k) dq[k] = NAN;
            continue;
        }
        for (Py_ssize_t r = m - 1; r >= 0; --r) {
            double sum = y[r];
            for (Py_ssize_t c = r + 1; c < m; ++c) sum -= A[r][c] * y[c];
            y[r] = sum / A[r][r];
        }
        for (Py_ssize_t k = 0; k < n; ++k) {
            double sum = 0.0;
            for (Py_ssize_t r = 0; r < m; ++r) sum += J[r * n + k] * y[r];
            dq[k] = sum;
        }
    }
}

/* ---------------------------------------------------------------- bordered solve */

/* A (n, n) x = y by Gaussian elimination with partial pivoting, A and y overwritten (y
 * becomes x); 0 where A is exactly singular. */
static int gauss_solve(double *A, double *y, Py_ssize_t n) {
    for (Py_ssize_t col = 0; col < n; ++col) {
        Py_ssize_t pivot = col;
        for (Py_ssize_t r = col + 1; r < n; ++r)
            if (fabs(A[r * n + col]) > fabs(A[pivot * n + col])) pivot = r;
        if (A[pivot * n + col] == 0.0) return 0;
        if (pivot != col) {
            for (Py_ssize_t c = 0; c < n; ++c) {
                double swap = A[col * n + c];
                A[col * n + c] = A[pivot * n + c];
                A[pivot * n + c] = swap;
            }
            double swap = y[col];
            y[col] = y[pivot];
            y[pivot] = swap;
        }
        for (Py_ssize_t r = col + 1; r < n; ++r) {
            double factor = A[r * n + col] / A[col * n + col];
            for (Py_ssize_t c = col; c < n; ++c) A[r * n + c] -= factor * A[col * n + c];
            y[r] -= factor * y[col];
        }
    }
    for (Py_ssize_t r = n - 1; r >= 0; --r) {
        double sum = y[r];
        for (Py_ssize_t c = r + 1; c < n; ++c) sum -= A[r * n + c] * y[c];
        y[r] = sum / A[r * n + r];
    }
    return 1;
}

/* jacobian (B, n - 1, n), border (B, n), rhs (B, n) -> x (B, n) with [J; border^T] x = rhs,
 * by Gaussian elimination with partial pivoting; NaN rows where the system is not finite
 * or exactly singular. `scratch` holds one n x n system. */
static void bordered_rows(const double *jacobian, const double *border, const double *rhs,
                          Py_ssize_t batch, Py_ssize_t n, double *x, double *scratch) {
    Py_ssize_t m = n - 1;
    for (Py_ssize_t b = 0; b < batch; ++b) {
        double *A = scratch, *y = x + b * n;
        const double *J = jacobian + b * m * n, *t = border + b * n, *e = rhs + b * n;
        int finite = 1;
        for (Py_ssize_t k = 0; k < m * n; ++k) finite &= isfinite(A[k] = J[k]) != 0;
        for (Py_ssize_t k = 0; k < n; ++k) {
            finite &= isfinite(A[m * n + k] = t[k]) != 0;
            finite &= isfinite(y[k] = e[k]) != 0;
        }
        if (!finite || !gauss_solve(A, y, n))
            for (Py_ssize_t k = 0; k < n; ++k) y[k] = NAN;
    }
}

/* ---------------------------------------------------------------- Newton onto the fibre */

/* Up to `iterations` Newton steps per row from q (B, n) with its measured error (B, m) and
 * task Jacobian (B, m, n), all updated in place: a DLS step (damping > 0; the joints a row
 * locks have their Jacobian columns zeroed for the step), or with `tangent` (B, n, r = 1)
 * the bordered step [J; t^T] dq = [e; 0]. Each step is evaluated (residual_rows), so the
 * returned error and Jacobian are measured at the returned q. With until >= 0 a row stops
 * once |e| <= until (a NaN |e| never stops). A step entry that is not finite makes that
 * joint NaN, as numpy's iterate does. `scratch` holds (m + 1) * n + 2 n doubles. */
static void newton_rows(const double *fixed, const double *tip, Py_ssize_t n, const long long *rows,
                        Py_ssize_t m, Py_ssize_t m_position, const double *target_position,
                        const double *target_rotation, double *q, double *error, double *jacobian,
                        Py_ssize_t batch, Py_ssize_t iterations, double until, double damping,
                        const unsigned char *locked, const double *tangent,
                        const unsigned char *fresh, double *scratch) {
    double *system = scratch, *dq = scratch + (m + 1) * n, *rhs = dq + n;
    unsigned char singular;
    for (Py_ssize_t b = 0; b < batch; ++b) {
        double *qb = q + b * n, *e = error + b * m, *J = jacobian + b * m * n;
        if (fresh != NULL && fresh[b]) /* not yet evaluated: measure it first */
            residual_rows(fixed, tip, n, qb, 1, rows, m, m_position, target_position,
                          target_rotation, e, J);
        for (Py_ssize_t it = 0; it < iterations; ++it) {
            if (until >= 0.0) {
                double norm2 = 0.0;
                for (Py_ssize_t k = 0; k < m; ++k) norm2 += e[k] * e[k];
                if (sqrt(norm2) <= until) break;
            }
            if (tangent != NULL) {
                for (Py_ssize_t k = 0; k < n; ++k) rhs[k] = k < m ? e[k] : 0.0;
                bordered_rows(J, tangent + b * n, rhs, 1, n, dq, system);
            } else {
                const double *step_J = J;
                if (locked != NULL) {
                    for (Py_ssize_t r = 0; r < m; ++r)
                        for (Py_ssize_t k = 0; k < n; ++k)
                            system[r * n + k] = locked[b * n + k] ? 0.0 : J[r * n + k];
                    step_J = system;
                }
                dls_rows(step_J, e, 1, m, n, damping, dq, &singular);
            }
            for (Py_ssize_t k = 0; k < n; ++k) qb[k] = isfinite(dq[k]) ? qb[k] + dq[k] : NAN;
            residual_rows(fixed, tip, n, qb, 1, rows, m, m_position, target_position,
                          target_rotation, e, J);
        }
    }
}

/* ---------------------------------------------------------------- URDF joint frames */

/* origin (n, 4, 4) joint k's fixed transform, axis (n, 3) unit; q (B, n) -> frames
 * (B, n + 1, 4, 4): T_0 = I, T_k = T_{k-1} origin_k Rot(axis_k, q_k), Rot by Rodrigues'
 * formula cos I + sin [a]x + (1 - cos) a a^T. */
static void frame_rows(const double *origin, const double *axis, Py_ssize_t n, const double *q,
                       Py_ssize_t batch, double *frames) {
    for (Py_ssize_t b = 0; b < batch; ++b) {
        double *T = frames + b * (n + 1) * 16;
        memset(T, 0, 16 * sizeof(double));
        T[0] = T[5] = T[10] = T[15] = 1.0;
        for (Py_ssize_t k = 0; k < n; ++k) {
            const double *P = T + 16 * k, *O = origin + 16 * k, *a = axis + 3 * k;
            double *N = T + 16 * (k + 1), fixed[12];
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 4; ++c)
                    fixed[4 * r + c] = P[4 * r] * O[c] + P[4 * r + 1] * O[4 + c] +
                                       P[4 * r + 2] * O[8 + c] + P[4 * r + 3] * O[12 + c];
            double cq = cos(q[b * n + k]), sq = sin(q[b * n + k]), vq = 1.0 - cq;
            double rot[9] = {
                cq + vq * a[0] * a[0],        vq * a[0] * a[1] - sq * a[2], vq * a[0] * a[2] + sq * a[1],
                vq * a[1] * a[0] + sq * a[2], cq + vq * a[1] * a[1],        vq * a[1] * a[2] - sq * a[0],
                vq * a[2] * a[0] - sq * a[1], vq * a[2] * a[1] + sq * a[0], cq + vq * a[2] * a[2],
            };
            for (int r = 0; r < 3; ++r) {
                for (int c = 0; c < 3; ++c)
                    N[4 * r + c] = fixed[4 * r] * rot[c] + fixed[4 * r + 1] * rot[3 + c] +
                                   fixed[4 * r + 2] * rot[6 + c];
                N[4 * r + 3] = fixed[4 * r + 3];
            }
            N[12] = N[13] = N[14] = 0.0;
            N[15] = 1.0;
        }
    }
}

/* ---------------------------------------------------------------- self-clearance */

/* rotation (B, K, 3, 3), origin (B, K, 3): each body's frame; centre (K, S, 3), radius
 * (K, S) its spheres (the first own[k] are its own), bound (K, 3), bound_radius (K,) its
 * bounding sphere; pair_a, pair_b (P,) the checked body pairs -> clearance (B,): the
 * least |c_a - c_b| - r_a - r_b over the checked pairs' spheres, +inf with no pair. A
 * body pair whose bounding spheres are already no nearer than the least found so far
 * cannot lower it and is skipped: the first spheres' pairs start it. `placed` is scratch
 * (K * S * 3 + K * 3). */
static void place_spheres(const double *Rk, const double *tk, const double *centre, Py_ssize_t count,
                          double *out) {
    for (Py_ssize_t s = 0; s < count; ++s) {
        const double *c = centre + s * 3;
        for (int r = 0; r < 3; ++r)
            out[3 * s + r] = Rk[3 * r] * c[0] + Rk[3 * r + 1] * c[1] + Rk[3 * r + 2] * c[2] + tk[r];
    }
}

static void self_clearance_rows(const double *rotation, const double *origin, Py_ssize_t batch,
                                Py_ssize_t K, Py_ssize_t S, const double *centre,
                                const double *radius, const long long *own, const double *bound,
                                const double *bound_radius, const long long *pair_a,
                                const long long *pair_b, Py_ssize_t P, double *clearance,
                                double *placed) {
    /* Spheres are placed when a pair first needs them: a body's first sphere for the first
     * pass, all its own for the second (`placed_count[k]` of body k placed so far). */
    double *bounds = placed + K * S * 3;
    Py_ssize_t placed_count[64];
    for (Py_ssize_t b = 0; b < batch; ++b) {
        const double *R = rotation + b * K * 9, *t = origin + b * K * 3;
        for (Py_ssize_t k = 0; k < K; ++k) {
            const double *Rk = R + 9 * k, *tk = t + 3 * k;
            const double *c = bound + 3 * k;
            for (int r = 0; r < 3; ++r)
                bounds[3 * k + r] = Rk[3 * r] * c[0] + Rk[3 * r + 1] * c[1] + Rk[3 * r + 2] * c[2] + tk[r];
            placed_count[k] = 0;
        }
        double best = INFINITY;
        for (Py_ssize_t p = 0; p < P; ++p) {
            Py_ssize_t ka = pair_a[p], kb = pair_b[p];
            for (int side = 0; side < 2; ++side) {
                Py_ssize_t k = side ? kb : ka;
                if (placed_count[k] < 1) {
                    place_spheres(R + 9 * k, t + 3 * k, centre + k * S * 3, 1, placed + k * S * 3);
                    placed_count[k] = 1;
                }
            }
            const double *ca = placed + ka * S * 3, *cb = placed + kb * S * 3;
            double dx = ca[0] - cb[0], dy = ca[1] - cb[1], dz = ca[2] - cb[2];
            double gap = sqrt(dx * dx + dy * dy + dz * dz) - (radius[ka * S] + radius[kb * S]);
            if (gap < best || isnan(gap)) best = gap;
        }
        for (Py_ssize_t p = 0; p < P && !isnan(best); ++p) {
            Py_ssize_t ka = pair_a[p], kb = pair_b[p];
            const double *ba = bounds + 3 * ka, *bb = bounds + 3 * kb;
            double dx = ba[0] - bb[0], dy = ba[1] - bb[1], dz = ba[2] - bb[2];
            double lower = sqrt(dx * dx + dy * dy + dz * dz) - (bound_radius[ka] + bound_radius[kb]);
            if (!(lower < best)) continue;
            for (int side = 0; side < 2; ++side) {
                Py_ssize_t k = side ? kb : ka;
                if (placed_count[k] < own[k]) {
                    place_spheres(R + 9 * k, t + 3 * k, centre + k * S * 3, own[k], placed + k * S * 3);
                    placed_count[k] = own[k];
                }
            }
            for (Py_ssize_t i = 0; i < (Py_ssize_t)own[ka]; ++i) {
                const double *ci = placed + (ka * S + i) * 3;
                double ri = radius[ka * S + i];
                for (Py_ssize_t j = 0; j < (Py_ssize_t)own[kb]; ++j) {
                    const double *cj = placed + (kb * S + j) * 3;
                    double ex = ci[0] - cj[0], ey = ci[1] - cj[1], ez = ci[2] - cj[2];
                    double gap = sqrt(ex * ex + ey * ey + ez * ez) - (ri + radius[kb * S + j]);
                    if (gap < best) best = gap;
                }
            }
        }
        clearance[b] = best;
    }
}

/* Each body's rotation (K, 3, 3) and origin (K, 3) from the chain's frames T (n + 1, 4, 4):
 * body k moves with frame[k]. */
static void body_frames(const double *T, const long long *frame, Py_ssize_t K, double *rotation,
                        double *origin) {
    for (Py_ssize_t k = 0; k < K; ++k) {
        const double *F = T + 16 * frame[k];
        for (int r = 0; r < 3; ++r) {
            for (int c = 0; c < 3; ++c) rotation[9 * k + 3 * r + c] = F[4 * r + c];
            origin[3 * k + r] = F[4 * r + 3];
        }
    }
}

/* self_clearance_rows at configurations q (B, n) instead of placed frames: per row the
 * chain's frames (frame_rows), each body's taken from frame[k], then the same clearance,
 * so the (B, n + 1, 4, 4) frames are never stored. `scratch` holds (n + 1) 16 + K 12 +
 * K S 3 + K 3 doubles. */
static void self_clearance_at_rows(const double *origin, const double *axis, Py_ssize_t n,
                                   const double *q, Py_ssize_t batch, const long long *frame,
                                   Py_ssize_t K, Py_ssize_t S, const double *centre,
                                   const double *radius, const long long *own, const double *bound,
                                   const double *bound_radius, const long long *pair_a,
                                   const long long *pair_b, Py_ssize_t P, double *clearance,
                                   double *scratch) {
    double *T = scratch, *rotation = T + (n + 1) * 16, *origin_k = rotation + K * 9;
    double *placed = origin_k + K * 3;
    for (Py_ssize_t b = 0; b < batch; ++b) {
        frame_rows(origin, axis, n, q + b * n, 1, T);
        body_frames(T, frame, K, rotation, origin_k);
        self_clearance_rows(rotation, origin_k, 1, K, S, centre, radius, own, bound, bound_radius,
                            pair_a, pair_b, P, clearance + b, placed);
    }
}

/* ---------------------------------------------------------------- hull separation (GJK) */

/* The constants of convex.py: its GJK, step for step, one row at a time. */
enum { GJK_ITERATIONS = 32 };
static const double GJK_RESOLUTION_M = 1e-4, GJK_DEGENERATE = 1e-10, GJK_STALLED = 1e-12;

/* The vertex of a placed hull farthest along u (base frame): R^T u in the hull's frame, the
 * first vertex of greatest reach (as numpy's argmax), placed back by R and t. */
static void hull_support_row(const double *vertices, long long count, const double *R,
                             const double *t, const double *u, double *out) {
    double local[3];
    for (int i = 0; i < 3; ++i) local[i] = R[i] * u[0] + R[3 + i] * u[1] + R[6 + i] * u[2];
    long long best = 0;
    double reach = -INFINITY;
    for (long long v = 0; v < count; ++v) {
        const double *p = vertices + 3 * v;
        double along = p[0] * local[0] + p[1] * local[1] + p[2] * local[2];
        if (along > reach) reach = along, best = v;
    }
    const double *p = vertices + 3 * best;
    for (int i = 0; i < 3; ++i) out[i] = R[3 * i] * p[0] + R[3 * i + 1] * p[1] + R[3 * i + 2] * p[2] + t[i];
}

static double norm3(const double *x) { return sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]); }

/* convex.py's nearest_in_hull for one row: points (4, 3), the first always used; the
 * nearest point of the faces holding the first point into `nearest`, their points into
 * `keep`. */
static void nearest_in_hull_row(const double points[4][3], const int used[4], double nearest[3],
                                int keep[4]) {
    const double *p0 = points[0];
    double e[3][3], gram[3][3], toward[3];
    for (int i = 0; i < 3; ++i)
        for (int c = 0; c < 3; ++c) e[i][c] = points[i + 1][c] - p0[c];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) gram[i][j] = e[i][0] * e[j][0] + e[i][1] * e[j][1] + e[i][2] * e[j][2];
        toward[i] = -(e[i][0] * p0[0] + e[i][1] * p0[1] + e[i][2] * p0[2]);
    }
    double best = norm3(p0);
    memcpy(nearest, p0, sizeof(double) * 3);
    keep[0] = 1, keep[1] = keep[2] = keep[3] = 0;
#define OFFER(candidate, f1, f2, f3)                                                       \
    do {                                                                                   \
        double norm_ = norm3(candidate);                                                   \
        if (norm_ < best) {                                                                \
            best = norm_;                                                                  \
            memcpy(nearest, candidate, sizeof(double) * 3);                                \
            keep[0] = 1, keep[1] = (f1), keep[2] = (f2), keep[3] = (f3);                   \
        }                                                                                  \
    } while (0)
    for (int i = 0; i < 3; ++i) { /* edges {0, i} */
        double length = gram[i][i];
        double t = toward[i] / (length > 0 ? length : 1.0);
        if (used[i + 1] && length > 0 && t >= 0 && t <= 1) {
            double candidate[3];
            for (int c = 0; c < 3; ++c) candidate[c] = p0[c] + t * e[i][c];
            OFFER(candidate, i == 0, i == 1, i == 2);
        }
    }
    static const int faces[3][2] = {{0, 1}, {0, 2}, {1, 2}};
    for (int f = 0; f < 3; ++f) { /* triangles {0, i, j} */
        int i = faces[f][0], j = faces[f][1];
        double a = gram[i][i], b = gram[i][j], c = gram[j][j];
        double det = a * c - b * b;
        if (!(used[i + 1] && used[j + 1] && det > GJK_DEGENERATE * a * c)) continue;
        double s = (c * toward[i] - b * toward[j]) / det;
        double t = (a * toward[j] - b * toward[i]) / det;
        if (s >= 0 && t >= 0 && s + t <= 1) {
            double candidate[3];
            for (int k = 0; k < 3; ++k) candidate[k] = p0[k] + s * e[i][k] + t * e[j][k];
            OFFER(candidate, i == 0 || j == 0, i == 1 || j == 1, i == 2 || j == 2);
        }
    }
    /* The tetrahedron: p_0 + E mu = 0 by Cramer's rule, E's columns the edges. */
    if (used[1] && used[2] && used[3]) {
        double cross[3][3];
        const double *e1 = e[0], *e2 = e[1], *e3 = e[2];
        const double *pairs[3][2] = {{e2, e3}, {e3, e1}, {e1, e2}};
        for (int k = 0; k < 3; ++k) {
            const double *u = pairs[k][0], *v = pairs[k][1];
            cross[k][0] = u[1] * v[2] - u[2] * v[1];
            cross[k][1] = u[2] * v[0] - u[0] * v[2];
            cross[k][2] = u[0] * v[1] - u[1] * v[0];
        }
        double det = e1[0] * cross[0][0] + e1[1] * cross[0][1] + e1[2] * cross[0][2];
        double scale = sqrt(gram[0][0] * gram[1][1] * gram[2][2]);
        if (fabs(det) > GJK_DEGENERATE * scale) {
            double mu[3], total = 0.0;
            int inside = 1;
            for (int k = 0; k < 3; ++k) {
                mu[k] = -(cross[k][0] * p0[0] + cross[k][1] * p0[1] + cross[k][2] * p0[2]) / det;
                inside &= mu[k] >= 0;
                total += mu[k];
            }
            if (inside && total <= 1) {
                double origin[3] = {0.0, 0.0, 0.0};
                OFFER(origin, 1, 1, 1);
            }
        }
    }
#undef OFFER
}

/* A convex set by its support: `at` puts the point of `set` farthest along u (base frame)
 * into out. */
typedef struct {
    void (*at)(const void *set, const double *u, double *out);
    const void *set;
} SupportOf;

/* convex.py's separation_m on one row: GJK from x0, a point of A - B, to the best lower
 * bound of the distance between A + ball(pad_A) and B + ball(pad_B), pad = pad_A + pad_B. */
static double gjk_row(SupportOf a, SupportOf b, const double *x0, double pad, double margin) {
    double x[3] = {x0[0], x0[1], x0[2]}, simplex[4][3] = {{0}};
    int used[4] = {1, 0, 0, 0};
    memcpy(simplex[0], x, sizeof x);
    double best = -INFINITY;
    for (int iteration = 0; iteration < GJK_ITERATIONS; ++iteration) {
        double squared = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
        double minus_x[3] = {-x[0], -x[1], -x[2]}, sa[3], sb[3], z[3];
        a.at(a.set, minus_x, sa);
        b.at(b.set, x, sb);
        for (int c = 0; c < 3; ++c) z[c] = sa[c] - sb[c];
        double along = x[0] * z[0] + x[1] * z[1] + x[2] * z[2];
        double norm = sqrt(squared);
        double bound = norm > 0 ? along / norm : -INFINITY;
        if (bound - pad > best) best = bound - pad;
        int stalled = squared - along <= GJK_STALLED * squared;
        /* z first, then W's used points in order, then its unused ones: 3 of them. */
        double points[4][3];
        int kept[4] = {1, 0, 0, 0}, slot = 1;
        memcpy(points[0], z, sizeof z);
        for (int pass = 1; pass >= 0; --pass)
            for (int i = 0; i < 4 && slot < 4; ++i)
                if (used[i] == pass) {
                    memcpy(points[slot], simplex[i], sizeof z);
                    kept[slot++] = used[i];
                }
        nearest_in_hull_row((const double(*)[3])points, kept, x, used);
        memcpy(simplex, points, sizeof points);
        double upper = norm3(x) - pad;
        int met = used[0] && used[1] && used[2] && used[3];
        if (best >= margin || upper < margin + GJK_RESOLUTION_M || met || stalled) break;
    }
    return best;
}

/* A hull placed by R and t: its vertices (count, 3) in its own frame. */
typedef struct {
    const double *vertices, *R, *t;
    long long count;
} PlacedHull;

static void placed_hull_at(const void *set, const double *u, double *out) {
    const PlacedHull *h = set;
    hull_support_row(h->vertices, h->count, h->R, h->t, u, out);
}

/* GJK between two placed hulls. */
static double hull_separation_row(const double *vertices_a, long long count_a, const double *Ra,
                                  const double *ta, const double *vertices_b, long long count_b,
                                  const double *Rb, const double *tb, const double *x0, double pad,
                                  double margin) {
    PlacedHull a = {vertices_a, Ra, ta, count_a}, b = {vertices_b, Rb, tb, count_b};
    return gjk_row((SupportOf){placed_hull_at, &a}, (SupportOf){placed_hull_at, &b}, x0, pad,
                   margin);
}

/* hulls (H, V, 3) every hull padded, counts (H,); per row r of `measure`: hull index
 * hull_a[r] placed by rotation_a[r] (3, 3) and origin_a[r] (3), the same for b, x0 (3),
 * pad -> best[r]. */
static void hull_separation_rows(const double *hulls, const long long *counts, Py_ssize_t V,
                                 const long long *hull_a, const double *rotation_a,
                                 const double *origin_a, const long long *hull_b,
                                 const double *rotation_b, const double *origin_b,
                                 const double *x0, const double *pad, double margin,
                                 const long long *measure, Py_ssize_t M, double *best) {
    for (Py_ssize_t k = 0; k < M; ++k) {
        long long r = measure[k], a = hull_a[r], b = hull_b[r];
        best[r] = hull_separation_row(hulls + a * V * 3, counts[a], rotation_a + 9 * r,
                                      origin_a + 3 * r, hulls + b * V * 3, counts[b],
                                      rotation_b + 9 * r, origin_b + 3 * r, x0 + 3 * r, pad[r],
                                      margin);
    }
}

/* ---------------------------------------------------------------- obstacles (scene.py) */

/* A request's obstacles as scene.py's Scene gives them: per obstacle its shape (OBSTACLE_*),
 * dimensions (3, unused ones 0), rotation R (3, 3, obstacle frame -> base frame), position
 * t (3), reach (the radius about t that holds it) and pad (the radius its core is grown
 * by: a sphere's, a capsule's). */
enum { OBSTACLE_BOX = 0, OBSTACLE_SPHERE = 1, OBSTACLE_CYLINDER = 2, OBSTACLE_CAPSULE = 3 };
typedef struct {
    const long long *shape;
    const double *dims, *rotation, *position, *reach, *pad;
    Py_ssize_t count;
} Obstacles;

static double sign_of(double x) { return x != x ? x : (double)((x > 0) - (x < 0)); }

/* numpy's minimum and maximum: NaN wins. */
static double nan_min(double x, double y) { return x != x || y != y ? NAN : (x < y ? x : y); }
static double nan_max(double x, double y) { return x != x || y != y ? NAN : (x > y ? x : y); }

/* Obstacle.signed_distance_m at a base-frame point: R^T (p - t) as numpy's row vector
 * (p - t) @ R, then the shape's closed form (negative inside; NaN at a NaN point). */
static double obstacle_distance(const Obstacles *o, Py_ssize_t k, const double *p) {
    const double *R = o->rotation + 9 * k, *t = o->position + 3 * k, *d = o->dims + 3 * k;
    double v[3] = {p[0] - t[0], p[1] - t[1], p[2] - t[2]}, l[3];
    for (int j = 0; j < 3; ++j) l[j] = v[0] * R[j] + v[1] * R[3 + j] + v[2] * R[6 + j];
    switch (o->shape[k]) {
    case OBSTACLE_BOX: {
        double e[3], outside = 0.0;
        for (int i = 0; i < 3; ++i) {
            e[i] = fabs(l[i]) - 0.5 * d[i];
            double out = nan_max(e[i], 0.0);
            outside += out * out;
        }
        double most = nan_max(nan_max(e[0], e[1]), e[2]);
        return sqrt(outside) + nan_min(most, 0.0);
    }
    case OBSTACLE_SPHERE:
        return sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]) - d[0];
    case OBSTACLE_CYLINDER: {
        double radial = hypot(l[0], l[1]) - d[1], axial = fabs(l[2]) - 0.5 * d[0];
        double outside = hypot(nan_max(radial, 0.0), nan_max(axial, 0.0));
        return outside + nan_min(nan_max(radial, axial), 0.0);
    }
    default: { /* capsule */
        double half = 0.5 * d[0], z = l[2] < -half ? -half : (l[2] > half ? half : l[2]);
        return sqrt(l[0] * l[0] + l[1] * l[1] + (l[2] - z) * (l[2] - z)) - d[1];
    }
    }
}

/* Obstacle.support_m along a base-frame direction u: the point of its core farthest
 * along u (a box's corner, a cylinder's rim point, a capsule's cap centre, a sphere's
 * centre), base frame. */
static void obstacle_support(const Obstacles *o, Py_ssize_t k, const double *u, double *out) {
    const double *R = o->rotation + 9 * k, *t = o->position + 3 * k, *d = o->dims + 3 * k;
    double l[3], point[3] = {0.0, 0.0, 0.0};
    for (int j = 0; j < 3; ++j) l[j] = u[0] * R[j] + u[1] * R[3 + j] + u[2] * R[6 + j];
    long long shape = o->shape[k];
    if (shape == OBSTACLE_BOX)
        for (int i = 0; i < 3; ++i) point[i] = sign_of(l[i]) * (0.5 * d[i]);
    else if (shape == OBSTACLE_CYLINDER || shape == OBSTACLE_CAPSULE)
        point[2] = sign_of(l[2]) * (0.5 * d[0]);
    if (shape == OBSTACLE_CYLINDER) {
        double radial = sqrt(l[0] * l[0] + l[1] * l[1]);
        double scale = d[1] / (radial > 0 ? radial : 1.0);
        point[0] = l[0] * scale, point[1] = l[1] * scale;
    }
    for (int i = 0; i < 3; ++i)
        out[i] = point[0] * R[3 * i] + point[1] * R[3 * i + 1] + point[2] * R[3 * i + 2] + t[i];
}

/* Obstacle k's core, as gjk_row takes a set. */
typedef struct {
    const Obstacles *o;
    Py_ssize_t k;
} ObstacleCore;

static void obstacle_core_at(const void *set, const double *u, double *out) {
    const ObstacleCore *core = set;
    obstacle_support(core->o, core->k, u, out);
}

/* GJK between a placed hull (A) and obstacle k's core (B). */
static double obstacle_separation_row(const double *vertices, long long count, const double *Ra,
                                      const double *ta, const Obstacles *o, Py_ssize_t k,
                                      const double *x0, double pad, double margin) {
    PlacedHull a = {vertices, Ra, ta, count};
    ObstacleCore b = {o, k};
    return gjk_row((SupportOf){placed_hull_at, &a}, (SupportOf){obstacle_core_at, &b}, x0, pad,
                   margin);
}

/* The robot's bodies as the obstacle passes take them, placed at one configuration:
 * rotation (K, 3, 3) and origin (K, 3); spheres (K, S, 3) and radius (K, S) in each body's
 * frame, own (K,) of them its own; bounding spheres bound (K, 3), bound_radius (K,); the
 * moving bodies' indices (M,); hulls (K, S, V, 3), hull_count (K, S), hull_pad (K, S). */
typedef struct {
    const double *centre, *radius, *bound, *bound_radius, *hulls, *hull_pad;
    const long long *own, *moving, *hull_count;
    Py_ssize_t K, S, M, V;
} Bodies;

static void place_point(const double *R, const double *t, const double *c, double *out) {
    for (int r = 0; r < 3; ++r)
        out[r] = R[3 * r] * c[0] + R[3 * r + 1] * c[1] + R[3 * r + 2] * c[2] + t[r];
}

/* scene.py's Scene.clearance_m at one configuration: the least of `within` and the signed
 * distance of the moving bodies' spheres to any obstacle, with its bounds in its order:
 * each body's bounding sphere against each obstacle's (`coarse`), the first sphere of the
 * nearest such pair for an attained distance, then per obstacle the bodies whose bounds
 * are under the least distance found before it, sphere by sphere. `scratch` holds M (O + 6)
 * doubles: M O coarse bounds, M 3 bounding and M 3 first centres. */
static double obstacle_clearance_row(const Bodies *b, const Obstacles *o, const double *R,
                                     const double *t, double within, double *scratch) {
    Py_ssize_t M = b->M, O = o->count, S = b->S;
    double clearance = within;
    if (!O || !M) return clearance;
    double *coarse = scratch, *bounds = coarse + M * O, *firsts = bounds + M * 3;
    Py_ssize_t nearest = -1;
    double least = INFINITY;
    for (Py_ssize_t m = 0; m < M; ++m) {
        long long k = b->moving[m];
        place_point(R + 9 * k, t + 3 * k, b->bound + 3 * k, bounds + 3 * m);
        place_point(R + 9 * k, t + 3 * k, b->centre + k * S * 3, firsts + 3 * m);
        for (Py_ssize_t j = 0; j < O; ++j) {
            const double *c = bounds + 3 * m, *p = o->position + 3 * j;
            double dx = c[0] - p[0], dy = c[1] - p[1], dz = c[2] - p[2];
            double lower = sqrt(dx * dx + dy * dy + dz * dz) - (b->bound_radius[k] + o->reach[j]);
            coarse[m * O + j] = lower;
            if (nearest < 0 || lower < least || (lower != lower && least == least))
                least = lower, nearest = m * O + j;
        }
    }
    { /* numpy's argmin: the first least, or the first NaN */
        Py_ssize_t m = nearest / O, j = nearest % O;
        long long k = b->moving[m];
        clearance = nan_min(clearance, obstacle_distance(o, j, firsts + 3 * m) - b->radius[k * S]);
    }
    double sphere[3];
    for (Py_ssize_t j = 0; j < O; ++j) {
        double before = clearance, least_gap = INFINITY;
        int measured = 0;
        for (Py_ssize_t m = 0; m < M; ++m) {
            if (!(coarse[m * O + j] < before)) continue;
            long long k = b->moving[m];
            double lower = obstacle_distance(o, j, bounds + 3 * m) - b->bound_radius[k];
            if (!(lower < before)) continue;
            for (Py_ssize_t s = 0; s < S; ++s) {
                place_point(R + 9 * k, t + 3 * k, b->centre + (k * S + s) * 3, sphere);
                double gap = obstacle_distance(o, j, sphere) - b->radius[k * S + s];
                least_gap = measured ? nan_min(least_gap, gap) : gap;
                measured = 1;
            }
        }
        if (measured) clearance = nan_min(clearance, least_gap);
    }
    return clearance;
}

/* scene.py's Scene.refined_clearance_m at one configuration: a lower bound of the moving
 * bodies' least distance to the obstacles, obstacle by obstacle: a body clear by the
 * margin on its bounding sphere counts with that bound; a configuration already not free
 * is not measured again; every other body's own spheres with their distance, and those
 * under the margin with their hull's GJK separation from the obstacle, the deepest
 * first: where it leaves the configuration less clear than the margin, the others keep
 * their distance (convex.py's separation_deepest_first_m). `scratch` holds M (S + 4)
 * doubles: M S gaps, M lower bounds and M 3 bounding centres. */
static double refined_obstacle_clearance_row(const Bodies *b, const Obstacles *o,
                                             const double *R, const double *t, double margin,
                                             double *scratch) {
    Py_ssize_t M = b->M, O = o->count, S = b->S, V = b->V;
    double clearance = INFINITY;
    if (!O || !M) return clearance;
    double *gaps = scratch, *lower = gaps + M * S, *bounds = lower + M;
    for (Py_ssize_t m = 0; m < M; ++m) {
        long long k = b->moving[m];
        place_point(R + 9 * k, t + 3 * k, b->bound + 3 * k, bounds + 3 * m);
    }
    double sphere[3], x0[3];
    for (Py_ssize_t j = 0; j < O; ++j) {
        double clear_bound = INFINITY;
        for (Py_ssize_t m = 0; m < M; ++m) {
            lower[m] = obstacle_distance(o, j, bounds + 3 * m) - b->bound_radius[b->moving[m]];
            if (lower[m] >= margin && lower[m] < clear_bound) clear_bound = lower[m];
        }
        clearance = nan_min(clearance, clear_bound);
        if (!(clearance >= margin)) continue;
        /* The near bodies' own spheres: their gaps, and the deepest under the margin. */
        Py_ssize_t deepest = -1;
        int any_near = 0;
        for (Py_ssize_t m = 0; m < M; ++m) {
            if (!(lower[m] < margin)) continue;
            any_near = 1;
            long long k = b->moving[m];
            for (Py_ssize_t s = 0; s < S; ++s) {
                double gap = INFINITY;
                if (s < b->own[k]) {
                    place_point(R + 9 * k, t + 3 * k, b->centre + (k * S + s) * 3, sphere);
                    gap = obstacle_distance(o, j, sphere) - b->radius[k * S + s];
                }
                gaps[m * S + s] = gap;
                if (gap < margin && (deepest < 0 || gap < gaps[deepest])) deepest = m * S + s;
            }
        }
        if (!any_near) continue;
        if (deepest >= 0) {
            int failed = 0;
            for (int pass = 0; pass < 2 && !failed; ++pass)
                for (Py_ssize_t m = 0; m < M; ++m) {
                    if (!(lower[m] < margin)) continue;
                    long long k = b->moving[m];
                    for (Py_ssize_t s = 0; s < S; ++s) {
                        Py_ssize_t i = m * S + s;
                        if (!(gaps[i] < margin) || (pass == 0) != (i == deepest)) continue;
                        const double *vertices = b->hulls + (k * S + s) * V * 3;
                        place_point(R + 9 * k, t + 3 * k, vertices, x0);
                        for (int c = 0; c < 3; ++c) x0[c] -= o->position[3 * j + c];
                        double pad = b->hull_pad[k * S + s] + o->pad[j];
                        double bound = obstacle_separation_row(vertices, b->hull_count[k * S + s],
                                                               R + 9 * k, t + 3 * k, o, j, x0,
                                                               pad, margin);
                        if (bound > gaps[i]) gaps[i] = bound;
                        if (pass == 0) failed = gaps[i] < margin;
                    }
                }
        }
        for (Py_ssize_t m = 0; m < M; ++m) {
            if (!(lower[m] < margin)) continue;
            double least = gaps[m * S];
            for (Py_ssize_t s = 1; s < S; ++s) least = nan_min(least, gaps[m * S + s]);
            clearance = nan_min(clearance, least);
        }
    }
    return clearance;
}

/* Either obstacle pass over rows: rotation (B, K, 3, 3), origin (B, K, 3); the sphere pass
 * (refined 0) from within (B,), the refined pass (refined 1) at the margin. */
static void obstacle_clearance_rows(const Bodies *b, const Obstacles *o, const double *rotation,
                                    const double *origin, Py_ssize_t batch, int refined,
                                    double margin, const double *within, double *clearance,
                                    double *scratch) {
    for (Py_ssize_t r = 0; r < batch; ++r) {
        const double *R = rotation + r * b->K * 9, *t = origin + r * b->K * 3;
        clearance[r] = refined ? refined_obstacle_clearance_row(b, o, R, t, margin, scratch)
                               : obstacle_clearance_row(b, o, R, t, within[r], scratch);
    }
}

/* ---------------------------------------------------------------- smallest singular value */

/* J (m, n), m <= n -> its least singular value, by one-sided Jacobi (Hestenes) on J's rows:
 * plane rotations of row pairs until every pair is orthogonal to 1e-15 relative; the
 * singular values are then the rows' norms (to about eps x sigma_max, as an SVD's). NaN
 * for a J with a non-finite entry. `work` holds m * n doubles. */
static double smallest_singular_row(const double *J, Py_ssize_t m, Py_ssize_t n, double *work) {
    for (Py_ssize_t k = 0; k < m * n; ++k) {
        if (!isfinite(J[k])) return NAN;
        work[k] = J[k];
    }
    for (int sweep = 0; sweep < 60; ++sweep) {
        int rotated = 0;
        for (Py_ssize_t i = 0; i + 1 < m; ++i) {
            for (Py_ssize_t j = i + 1; j < m; ++j) {
                double *a = work + i * n, *b = work + j * n;
                double alpha = 0.0, beta = 0.0, gamma = 0.0;
                for (Py_ssize_t k = 0; k < n; ++k) {
                    alpha += a[k] * a[k];
                    beta += b[k] * b[k];
                    gamma += a[k] * b[k];
                }
                if (fabs(gamma) <= 1e-15 * sqrt(alpha * beta)) continue;
                rotated = 1;
                double zeta = (beta - alpha) / (2.0 * gamma);
                double t = (zeta >= 0.0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
                for (Py_ssize_t k = 0; k < n; ++k) {
                    double x = a[k], y = b[k];
                    a[k] = c * x - s * y;
                    b[k] = s * x + c * y;
                }
            }
        }
        if (!rotated) break;
    }
    double least = INFINITY;
    for (Py_ssize_t i = 0; i < m; ++i) {
        double norm2 = 0.0;
        for (Py_ssize_t k = 0; k < n; ++k) norm2 += work[i * n + k] * work[i * n + k];
        if (sqrt(norm2) < least) least = sqrt(norm2);
    }
    return least;
}

/* ---------------------------------------------------------------- continuation walk */


static const double PI = 3.141592653589793, TWO_PI = 2.0 * 3.141592653589793;

/* (-pi, pi], as joint_space.wrap_to_pi computes it. */
static double wrap_to_pi(double angle) { return angle - TWO_PI * ceil((angle - PI) / TWO_PI); }

static double norm_of(const double *x, Py_ssize_t n) {
    double sum = 0.0;
    for (Py_ssize_t k = 0; k < n; ++k) sum += x[k] * x[k];
    return sqrt(sum);
}

static double dot_of(const double *x, const double *y, Py_ssize_t n) {
    double sum = 0.0;
    for (Py_ssize_t k = 0; k < n; ++k) sum += x[k] * y[k];
    return sum;
}

/* A lower bound of J's least singular value (m <= n), from the Cholesky factor L of
 * J J^T: with T = tr((J J^T)^-1) = |L^-1|_F^2, sigma_min^2 >= 1 / T (and <= m / T), shrunk
 * by the rounding of forming and inverting J J^T so that it stays a bound. 0 where J J^T
 * is not numerically positive definite (J near rank deficiency: no cheap bound); NaN for
 * a J with a non-finite entry. `work` holds 2 m^2 doubles. */
static double singular_lower_bound_row(const double *J, Py_ssize_t m, Py_ssize_t n, double *work) {
    double *L = work, *inverse = work + m * m, trace = 0.0;
    for (Py_ssize_t k = 0; k < m * n; ++k)
        if (!isfinite(J[k])) return NAN;
    for (Py_ssize_t r = 0; r < m; ++r) {
        for (Py_ssize_t c = 0; c <= r; ++c) {
            double sum = dot_of(J + r * n, J + c * n, n);
            if (c == r) trace += sum;
            for (Py_ssize_t k = 0; k < c; ++k) sum -= L[r * m + k] * L[c * m + k];
            if (c == r) {
                if (!(sum > 0.0)) return 0.0;
                L[r * m + r] = sqrt(sum);
            } else {
                L[r * m + c] = sum / L[c * m + c];
            }
        }
    }
    double inverse_trace = 0.0; /* |L^-1|_F^2, column by column of L^-1 (lower triangular) */
    for (Py_ssize_t c = 0; c < m; ++c) {
        for (Py_ssize_t r = c; r < m; ++r) {
            double sum = r == c ? 1.0 : 0.0;
            for (Py_ssize_t k = c; k < r; ++k) sum -= L[r * m + k] * inverse[k];
            inverse[r] = sum / L[r * m + r];
            inverse_trace += inverse[r] * inverse[r];
        }
    }
    double bound2 = (1.0 / inverse_trace) * (1.0 - 1e-8) - 1e-12 * trace;
    return bound2 > 0.0 ? sqrt(bound2) : 0.0;
}

typedef struct {
    double bound;
    Py_ssize_t row;
} Bound;

static int by_bound(const void *a, const void *b) {
    const Bound *x = a, *y = b;
    return x->bound < y->bound ? -1 : x->bound > y->bound ? 1 : (x->row > y->row) - (x->row < y->row);
}

/* The least of smallest_singular_row over the rows of J (B, m, n) with no non-finite entry
 * (+inf for none), the same number: rows are visited by their lower bound, least first,
 * and the exact one-sided Jacobi runs only until the next bound is above the least found.
 * -1 when out of memory. */
static double least_singular_value(const double *jacobian, Py_ssize_t batch, Py_ssize_t m,
                                   Py_ssize_t n) {
    Bound *order = malloc((size_t)(batch > 0 ? batch : 1) * sizeof(Bound));
    double *work = malloc((size_t)(2 * m * m + m * n) * sizeof(double));
    if (order == NULL || work == NULL) {
        free(order), free(work);
        return -1.0;
    }
    Py_ssize_t count = 0;
    for (Py_ssize_t b = 0; b < batch; ++b) {
        double bound = singular_lower_bound_row(jacobian + b * m * n, m, n, work);
        if (isnan(bound)) continue;
        order[count].bound = bound, order[count].row = b;
        ++count;
    }
    qsort(order, (size_t)count, sizeof(Bound), by_bound);
    double least = INFINITY;
    for (Py_ssize_t i = 0; i < count && order[i].bound <= least; ++i) {
        double sigma = smallest_singular_row(jacobian + order[i].row * m * n, m, n, work);
        if (sigma < least) least = sigma;
    }
    free(order), free(work);
    return least;
}

static double monotonic_s(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (double)now.tv_sec + 1e-9 * (double)now.tv_nsec;
}

/* What a walk holds between its steps (trace/walk.py's arrays, updated in place), the
 * fibre's residual and the walk's constants. */
typedef struct {
    const double *fixed, *tip, *target_position, *target_rotation;
    const long long *rows;
    Py_ssize_t n, m, m_position, fronts;
    double *q, *tangent, *jacobian, *step; /* (F, n), (F, n), (F, m, n), (F,) */
    unsigned char *alive;                  /* (F,) */
    long long *partner;                    /* (F,) */
    double h, damping, meet_factor, twin_sigma, twin_offset;
    Py_ssize_t corrector_iterations;
} Walk;

typedef struct {
    long long a, b;
    double length;
} Pair;

/* trace/walk.py's `meet`, step for step: stop the pairs of fronts that meet head-on on one
 * curve, nearest pairs first. `previous` (F, n): the ends one step before; `circle`
 * (F, 2n) and `work` (m n) scratch; `*pairs` grows as candidates need. */
static int meet_fronts(Walk *w, const double *previous, double *circle, double *work,
                       Pair **pairs, Py_ssize_t *pair_capacity) {
    Py_ssize_t n = w->n, F = w->fronts, count = 0;
    double largest = -INFINITY;
    int any = 0;
    for (Py_ssize_t f = 0; f < F; ++f) {
        any |= w->alive[f];
        if (w->step[f] > largest || isnan(w->step[f])) largest = w->step[f];
        if (w->partner[f] >= 0) continue; /* met: never a candidate again (its circle unread) */
        for (Py_ssize_t k = 0; k < n; ++k) {
            circle[f * 2 * n + k] = cos(w->q[f * n + k]);
            circle[f * 2 * n + n + k] = sin(w->q[f * n + k]);
        }
    }
    if (!any) return 0;
    double reach = w->meet_factor * largest, reach2 = reach * reach + 1e-9;
    for (Py_ssize_t a = 0; a < F; ++a) {
        if (!w->alive[a]) continue;
        const double *ca = circle + a * 2 * n;
        for (Py_ssize_t b = 0; b < F; ++b) {
            if (a == b || w->partner[b] >= 0 || !(a < b || !w->alive[b])) continue;
            /* Far apart in the first joints already: the chordal distance below, a sum of
             * those joints' 2 - 2 cos(dq) and the rest's (each at least 0 up to rounding),
             * exceeds the reach too. The margin covers both sums' rounding (< 1e-13), so
             * the pairs kept are the same; most fronts are far from most. */
            const double *cb = circle + b * 2 * n;
            double partial = 0.0;
            Py_ssize_t k = 0;
            for (; k < n; ++k) {
                partial += 2.0 - 2.0 * (ca[k] * cb[k] + ca[n + k] * cb[n + k]);
                if (partial > reach2 + 1e-12) break;
            }
            if (k < n) continue;
            double chordal2 = 2.0 * n - 2.0 * dot_of(ca, cb, 2 * n);
            if (!(chordal2 <= reach2)) continue;
            if (count == *pair_capacity) {
                Py_ssize_t grown = 2 * *pair_capacity + 16;
                Pair *more = realloc(*pairs, grown * sizeof(Pair));
                if (more == NULL) return -1;
                *pairs = more, *pair_capacity = grown;
            }
            (*pairs)[count].a = a < b ? a : b;
            (*pairs)[count].b = a < b ? b : a;
            ++count;
        }
    }
    double chord[64], mean[64], offset_vector[64];
    Py_ssize_t ok = 0;
    for (Py_ssize_t p = 0; p < count; ++p) {
        long long a = (*pairs)[p].a, b = (*pairs)[p].b;
        const double *qa = w->q + a * n, *qb = w->q + b * n, *ta = w->tangent + a * n,
                     *tb = w->tangent + b * n;
        double before2 = 0.0;
        for (Py_ssize_t k = 0; k < n; ++k) {
            chord[k] = wrap_to_pi(qb[k] - qa[k]);
            double d = wrap_to_pi(previous[b * n + k] - previous[a * n + k]);
            before2 += d * d;
        }
        double length = norm_of(chord, n), before = sqrt(before2);
        double sa = w->step[a], sb = w->step[b];
        int near = length <= w->meet_factor * (sa > sb ? sa : sb);
        int head_on = dot_of(ta, tb, n) < -0.5;
        int along = fabs(dot_of(chord, ta, n)) >= 0.7 * length;
        int closer = length < before;
        if (near && head_on && along && closer) {
            for (Py_ssize_t k = 0; k < n; ++k) mean[k] = ta[k] - tb[k];
            double scale = norm_of(mean, n);
            scale = scale > 1e-300 ? scale : 1e-300;
            for (Py_ssize_t k = 0; k < n; ++k) mean[k] /= scale;
            double projected = dot_of(chord, mean, n);
            for (Py_ssize_t k = 0; k < n; ++k) offset_vector[k] = chord[k] - projected * mean[k];
            double offset = norm_of(offset_vector, n);
            if ((sa < sb ? sa : sb) >= w->h && offset > w->twin_offset * w->h) {
                size_t size = (size_t)(w->m * n);
                double sigma_a = smallest_singular_row(w->jacobian + a * size, w->m, n, work);
                double sigma_b = smallest_singular_row(w->jacobian + b * size, w->m, n, work);
                double sigma = isnan(sigma_a) || isnan(sigma_b) ? NAN
                               : sigma_a < sigma_b              ? sigma_a
                                                                : sigma_b;
                if (sigma < w->twin_sigma) along = 0;
            }
        }
        if (near && head_on && along && closer) {
            (*pairs)[ok] = (*pairs)[p];
            (*pairs)[ok].length = length;
            ++ok;
        }
    }
    /* Nearest first (insertion sort: a few pairs, ties kept in their order). */
    for (Py_ssize_t i = 1; i < ok; ++i) {
        Pair key = (*pairs)[i];
        Py_ssize_t j = i - 1;
        for (; j >= 0 && (*pairs)[j].length > key.length; --j) (*pairs)[j + 1] = (*pairs)[j];
        (*pairs)[j + 1] = key;
    }
    for (Py_ssize_t p = 0; p < ok; ++p) {
        long long i = (*pairs)[p].a, j = (*pairs)[p].b;
        if (w->partner[i] < 0 && w->partner[j] < 0) {
            w->partner[i] = j, w->partner[j] = i;
            w->alive[i] = w->alive[j] = 0;
        }
    }
    return 0;
}

/* trace/walk.py's `walk_fronts` loop, step for step, from the state in `w`: up to
 * `max_steps` lockstep steps (fewer once no front is alive), each followed by meet_fronts.
 * Each point a front moves to is written to the next row of out_q (C, n), out_error
 * (C, m), out_jacobian (C, m, n), out_tangent (C, n), out_front (C,), from row *count on.
 * Returns 0 when the walk is over, 1 when the next step might not fit in the C rows (call
 * again with more), 2 when `expires_at_s` (monotonic clock) has passed, -1 when out of
 * memory; *steps counts the steps taken. */
static int walk_steps(Walk *w, Py_ssize_t max_steps, double expires_at_s, double *out_q,
                      double *out_error, double *out_jacobian, double *out_tangent,
                      long long *out_front, Py_ssize_t capacity, Py_ssize_t *count,
                      Py_ssize_t *steps) {
    Py_ssize_t n = w->n, m = w->m, F = w->fronts, mn = m * n;
    double *previous = malloc((size_t)(F * n * 3 + (m + 3) * n + n * n + 4 * n + mn) * sizeof(double));
    if (previous == NULL) return -1;
    double *circle = previous + F * n, *newton_scratch = circle + 2 * F * n;
    double *system = newton_scratch + (m + 3) * n, *predicted = system + n * n;
    double *rhs = predicted + n, *direction = rhs + n, *moved_q = direction + n,
           *work = moved_q + n;
    Pair *pairs = NULL;
    Py_ssize_t pair_capacity = 0;
    int status = 0;
    double error[6], jacobian[6 * 64];
    for (; *steps < max_steps; ++*steps) {
        Py_ssize_t alive = 0;
        for (Py_ssize_t f = 0; f < F; ++f) alive += w->alive[f];
        if (alive == 0) break;
        if (monotonic_s() > expires_at_s) {
            status = 2;
            break;
        }
        if (*count + alive > capacity) {
            status = 1;
            break;
        }
        memcpy(previous, w->q, (size_t)(F * n) * sizeof(double));
        for (Py_ssize_t f = 0; f < F; ++f) {
            if (!w->alive[f]) continue;
            double h_f = w->step[f], *q = w->q + f * n, *t = w->tangent + f * n;
            for (Py_ssize_t k = 0; k < n; ++k) moved_q[k] = predicted[k] = q[k] + h_f * t[k];
            residual_rows(w->fixed, w->tip, n, moved_q, 1, w->rows, m, w->m_position,
                          w->target_position, w->target_rotation, error, jacobian);
            newton_rows(w->fixed, w->tip, n, w->rows, m, w->m_position, w->target_position,
                        w->target_rotation, moved_q, error, jacobian, 1,
                        w->corrector_iterations, -1.0, w->damping, NULL, t, NULL,
                        newton_scratch);
            double step2 = 0.0, pulled2 = 0.0;
            for (Py_ssize_t k = 0; k < n; ++k) {
                double d = moved_q[k] - q[k], p = moved_q[k] - predicted[k];
                step2 += d * d;
                pulled2 += p * p;
            }
            for (Py_ssize_t k = 0; k < n; ++k) rhs[k] = k < m ? 0.0 : 1.0;
            bordered_rows(jacobian, t, rhs, 1, n, direction, system);
            double scale = norm_of(direction, n);
            for (Py_ssize_t k = 0; k < n; ++k) direction[k] /= scale;
            double turn = dot_of(direction, t, n);
            int moved = (norm_of(error, m) < 1e-2 * h_f / w->h) && (sqrt(pulled2) < 0.25 * h_f) &&
                        (sqrt(step2) < 2.0 * h_f) && (turn > 0.5);
            if (!moved) {
                w->step[f] *= 0.5;
                if (w->step[f] < w->h / 16) w->alive[f] = 0;
                continue;
            }
            Py_ssize_t row = (*count)++;
            memcpy(out_q + row * n, moved_q, (size_t)n * sizeof(double));
            memcpy(out_error + row * m, error, (size_t)m * sizeof(double));
            memcpy(out_jacobian + row * mn, jacobian, (size_t)mn * sizeof(double));
            memcpy(out_tangent + row * n, direction, (size_t)n * sizeof(double));
            out_front[row] = f;
            memcpy(q, moved_q, (size_t)n * sizeof(double));
            memcpy(t, direction, (size_t)n * sizeof(double));
            memcpy(w->jacobian + f * mn, jacobian, (size_t)mn * sizeof(double));
            w->step[f] = 1.5 * h_f < w->h ? 1.5 * h_f : w->h;
        }
        if (meet_fronts(w, previous, circle, work, &pairs, &pair_capacity) < 0) {
            status = -1;
            break;
        }
    }
    free(pairs);
    free(previous);
    return status;
}

/* ---------------------------------------------------------------- projected walk */

/* local_planner.py's walk_on_fibre, one edge at a time: the same steps, projections, tests
 * and order as its lockstep numpy loop, with the fibre's coaxial crossings
 * (space.py's crossings_on_fibre) and collisions (collision/check.py's `free`: itself and
 * a scene's obstacles, each by the spheres, then the hulls where the spheres are within
 * the margin). */
typedef struct {
    const double *fixed, *tip, *target_position, *target_rotation;
    const long long *rows;
    Py_ssize_t n, m, m_position;
    double damping, delta, stretch, tolerance, margin, expires_at_s;
    double limit_check; /* space.py's LimitCheck spacing, 0: a step checked at its ends only */
    Py_ssize_t iterations, extra_iterations, set_iterations, max_steps;
    const double *lower, *upper;
    const unsigned char *periodic;
    Py_ssize_t sets;
    const long long *set_joint;
    const double *set_angle;
    int check_self;
    const double *joint_origin, *joint_axis, *centre, *radius, *bound, *bound_radius, *hulls,
        *hull_pad;
    const long long *frame, *own, *pair_a, *pair_b, *hull_count;
    Py_ssize_t K, S, P, V;
    /* A scene's obstacles, checked against the moving bodies (none: obstacles.count 0). */
    Bodies scene_bodies;
    Obstacles obstacles;
} Planner;

/* Scratch of one projected or steered walk, in doubles. */
static Py_ssize_t planner_scratch(const Planner *p) {
    Py_ssize_t n = p->n, m = p->m;
    /* steer_one's layout, the larger: J, e, q_new, e_new, J_new, d, g, gram, y, Jf, start,
     * the Newton scratch, e2, J2, then self_free_row's frames. */
    return m * n + m + n + m + m * n + n + n + m * m + m + m * n + n + (m + 1) * n + 2 * n + m +
           m * n + (n + 1) * 16 + p->K * 18 + p->K * p->S * 3 +
           p->scene_bodies.M * (p->obstacles.count + p->S + 10);
}

static double distance_of(const double *a, const double *b, Py_ssize_t n) {
    double total = 0.0;
    for (Py_ssize_t k = 0; k < n; ++k) total += (a[k] - b[k]) * (a[k] - b[k]);
    return sqrt(total);
}

/* evaluate q, then `iterations` DLS steps (locked: joint `lock` held, -1 none); error and
 * Jacobian measured at the returned q. */
static void project_row(const Planner *p, double *q, double *e, double *J, Py_ssize_t iterations,
                        Py_ssize_t lock, unsigned char *locked, double *scratch) {
    residual_rows(p->fixed, p->tip, p->n, q, 1, p->rows, p->m, p->m_position, p->target_position,
                  p->target_rotation, e, J);
    if (lock >= 0) {
        memset(locked, 0, (size_t)p->n);
        locked[lock] = 1;
    }
    newton_rows(p->fixed, p->tip, p->n, p->rows, p->m, p->m_position, p->target_position,
                p->target_rotation, q, e, J, 1, iterations, -1.0, p->damping,
                lock >= 0 ? locked : NULL, NULL, NULL, scratch);
}

/* The fibre reaches a coaxial set where Newton, the aligning joint held on it, gets this
 * near (space.py's SET_REACH_TOLERANCE): the answers' tolerance, not the walks' coarser
 * 1e-4, which counts as reached a set the fibre misses by less (an iiwa elbow 0.04 rad
 * from straight on a fibre whose |q4| is fixed). */
#define SET_REACH_TOLERANCE 1e-6

/* Whether the step q_from -> q_to crosses no coaxial set, or crosses one where the fibre
 * reaches it. */
static int crossings_on_fibre_row(const Planner *p, const double *q_from, const double *q_to,
                                  double *guess, double *e, double *J, double *scratch) {
    Py_ssize_t n = p->n;
    unsigned char locked[64];
    for (Py_ssize_t c = 0; c < p->sets; ++c) {
        Py_ssize_t j = p->set_joint[c];
        double angle = p->set_angle[c];
        double before = q_from[j] - angle, after = q_to[j] - angle;
        if (p->periodic[j]) before = wrap_to_pi(before), after = wrap_to_pi(after);
        if (!(before * after < 0 && fabs(before) < PI / 2 && fabs(after) < PI / 2)) continue;
        double fraction = before / (before - after), step_norm = 0.0;
        for (Py_ssize_t k = 0; k < n; ++k) {
            double step = q_to[k] - q_from[k];
            guess[k] = q_from[k] + fraction * step;
            step_norm += step * step;
        }
        guess[j] = angle;
        double start[64];
        memcpy(start, guess, sizeof(double) * (size_t)n);
        project_row(p, guess, e, J, p->set_iterations, j, locked, scratch);
        double error = 0.0;
        for (Py_ssize_t k = 0; k < p->m; ++k) error += e[k] * e[k];
        double reach = p->tolerance < SET_REACH_TOLERANCE ? p->tolerance : SET_REACH_TOLERANCE;
        if (!(sqrt(error) <= reach && distance_of(guess, start, n) <= sqrt(step_norm)))
            return 0;
    }
    return 1;
}

/* GJK between hull ha and hull hb (body * S + sphere) of the bodies placed by rotation
 * (K, 3, 3) and origin (K, 3), started from their first vertices' difference, as
 * robot.py's PlacedBodies.hull_separation starts it. */
static double placed_hull_separation(const Planner *p, const double *rotation,
                                     const double *origin, Py_ssize_t ha, Py_ssize_t hb) {
    Py_ssize_t ka = ha / p->S, kb = hb / p->S;
    const double *va = p->hulls + ha * p->V * 3, *vb = p->hulls + hb * p->V * 3;
    const double *Ra = rotation + 9 * ka, *Rb = rotation + 9 * kb;
    const double *ta = origin + 3 * ka, *tb = origin + 3 * kb;
    double x0[3];
    for (int r = 0; r < 3; ++r)
        x0[r] = (Ra[3 * r] * va[0] + Ra[3 * r + 1] * va[1] + Ra[3 * r + 2] * va[2] + ta[r]) -
                (Rb[3 * r] * vb[0] + Rb[3 * r + 1] * vb[1] + Rb[3 * r + 2] * vb[2] + tb[r]);
    return hull_separation_row(va, p->hull_count[ha], Ra, ta, vb, p->hull_count[hb], Rb, tb, x0,
                               p->hull_pad[ha] + p->hull_pad[hb], p->margin);
}

/* collision/check.py's `free` at q with self-collision only: the spheres' clearance (the
 * compiled self-clearance), and where it is under the margin, the refined pass of
 * robot.py's refined_self_clearance_m: every hull pair whose spheres are within the margin,
 * of a body pair whose bounding spheres are, must be separated by at least the margin. */
static int self_free_row(const Planner *p, const double *q, double *scratch) {
    Py_ssize_t K = p->K, S = p->S, n = p->n;
    double *T = scratch, *rotation = T + (n + 1) * 16, *origin = rotation + K * 9;
    double *placed = origin + K * 3, *bounds = placed + K * S * 3 + K * 3;
    frame_rows(p->joint_origin, p->joint_axis, n, q, 1, T);
    body_frames(T, p->frame, K, rotation, origin);
    double clearance;
    self_clearance_rows(rotation, origin, 1, K, S, p->centre, p->radius, p->own, p->bound,
                        p->bound_radius, p->pair_a, p->pair_b, p->P, &clearance, placed);
    if (isnan(clearance)) return 0;
    if (clearance >= p->margin) return 1;
    for (Py_ssize_t k = 0; k < K; ++k) {
        place_spheres(rotation + 9 * k, origin + 3 * k, p->bound + 3 * k, 1, bounds + 3 * k);
        place_spheres(rotation + 9 * k, origin + 3 * k, p->centre + k * S * 3, p->own[k],
                      placed + k * S * 3);
    }
    for (Py_ssize_t pair = 0; pair < p->P; ++pair) {
        Py_ssize_t ka = p->pair_a[pair], kb = p->pair_b[pair];
        double lower = distance_of(bounds + 3 * ka, bounds + 3 * kb, 3) -
                       (p->bound_radius[ka] + p->bound_radius[kb]);
        if (lower >= p->margin) continue;
        for (Py_ssize_t i = 0; i < p->own[ka]; ++i)
            for (Py_ssize_t j = 0; j < p->own[kb]; ++j) {
                double gap = distance_of(placed + (ka * S + i) * 3, placed + (kb * S + j) * 3, 3) -
                             (p->radius[ka * S + i] + p->radius[kb * S + j]);
                if (gap >= p->margin) continue;
                double bound = placed_hull_separation(p, rotation, origin, ka * S + i, kb * S + j);
                if (!((gap > bound ? gap : bound) >= p->margin)) return 0;
            }
    }
    return 1;
}

/* collision/check.py's `free` at q: free of itself where self-collision is checked
 * (self_free_row), and of the scene's obstacles: the spheres' clearance to them
 * (obstacle_clearance_row), and where it is under the margin, the refined pass's
 * (refined_obstacle_clearance_row). Either verdict alone decides as check.py's combined
 * clearance does: a configuration is free when both are at least the margin. */
static int free_row(const Planner *p, const double *q, double *scratch) {
    if (p->check_self && !self_free_row(p, q, scratch)) return 0;
    if (!p->obstacles.count || !p->scene_bodies.M) return 1;
    Py_ssize_t K = p->K, n = p->n;
    double *T = scratch, *rotation = T + (n + 1) * 16, *origin = rotation + K * 9;
    double *work = origin + K * 3;
    if (!p->check_self) { /* self_free_row placed them otherwise */
        frame_rows(p->joint_origin, p->joint_axis, n, q, 1, T);
        body_frames(T, p->frame, K, rotation, origin);
    }
    double clearance =
        obstacle_clearance_row(&p->scene_bodies, &p->obstacles, rotation, origin, INFINITY, work);
    if (isnan(clearance)) return 0;
    if (clearance >= p->margin) return 1;
    return refined_obstacle_clearance_row(&p->scene_bodies, &p->obstacles, rotation, origin,
                                          p->margin, work) >= p->margin;
}

/* robot.py's refined_self_clearance_m at one configuration q, its number exactly: body
 * pairs whose bounding spheres are clear by the margin count with that bound, sphere pairs
 * clear by it with their distance, and every other sphere pair with its hulls' GJK
 * separation (at least its sphere gap), the configuration's deepest pair first: when that
 * one is not clear by the margin the others keep their sphere gaps. `candidates` holds
 * 4 P S^2 doubles; `scratch` as self_free_row's. */
static double refined_self_clearance_row(const Planner *p, const double *q, double *candidates,
                                         double *scratch) {
    Py_ssize_t K = p->K, S = p->S, n = p->n;
    double *T = scratch, *rotation = T + (n + 1) * 16, *origin = rotation + K * 9;
    double *placed = origin + K * 3, *bounds = placed + K * S * 3 + K * 3;
    frame_rows(p->joint_origin, p->joint_axis, n, q, 1, T);
    body_frames(T, p->frame, K, rotation, origin);
    for (Py_ssize_t k = 0; k < K; ++k) {
        place_spheres(rotation + 9 * k, origin + 3 * k, p->bound + 3 * k, 1, bounds + 3 * k);
        place_spheres(rotation + 9 * k, origin + 3 * k, p->centre + k * S * 3, p->own[k],
                      placed + k * S * 3);
    }
    double clearance = INFINITY;
    Py_ssize_t count = 0, deepest = -1;
    for (Py_ssize_t pair = 0; pair < p->P; ++pair) {
        Py_ssize_t ka = p->pair_a[pair], kb = p->pair_b[pair];
        double lower = distance_of(bounds + 3 * ka, bounds + 3 * kb, 3) -
                       (p->bound_radius[ka] + p->bound_radius[kb]);
        if (lower >= p->margin) {
            if (lower < clearance) clearance = lower;
            continue;
        }
        for (Py_ssize_t i = 0; i < p->own[ka]; ++i)
            for (Py_ssize_t j = 0; j < p->own[kb]; ++j) {
                double gap = distance_of(placed + (ka * S + i) * 3, placed + (kb * S + j) * 3, 3) -
                             (p->radius[ka * S + i] + p->radius[kb * S + j]);
                if (!(gap < p->margin)) {
                    if (gap < clearance) clearance = gap;
                    continue;
                }
                double *c = candidates + 4 * count;
                c[0] = gap, c[1] = (double)(ka * S + i), c[2] = (double)(kb * S + j), c[3] = gap;
                if (deepest < 0 || gap < candidates[4 * deepest]) deepest = count;
                ++count;
            }
    }
    for (Py_ssize_t pass = 0; pass < 2 && count; ++pass) {
        for (Py_ssize_t k = 0; k < count; ++k) {
            if ((pass == 0) != (k == deepest)) continue;
            double *c = candidates + 4 * k;
            double separation =
                placed_hull_separation(p, rotation, origin, (Py_ssize_t)c[1], (Py_ssize_t)c[2]);
            if (separation > c[3]) c[3] = separation;
        }
        if (pass == 0 && candidates[4 * deepest + 3] < p->margin) break; /* not free: the rest keep their gaps */
    }
    for (Py_ssize_t k = 0; k < count; ++k)
        if (candidates[4 * k + 3] < clearance) clearance = candidates[4 * k + 3];
    return clearance;
}

/* Newton steps each step of inside_between's fine walk takes onto the fibre at most
 * (space.py's LIMIT_CHECK_ITERATIONS). */
#define LIMIT_CHECK_ITERATIONS 6

/* space.py's `inside_between` for one step a -> b (b unwrapped toward a), both on the
 * fibre inside the limits: 1 when the step needs no check (no limit check asked, a step
 * no longer than its spacing, or no bounded joint near enough a limit at both ends that
 * a path of stretch x the step could reach it), else whether a walk from a toward b at
 * steps of the spacing gets within one step of b in at most ceil(stretch x |b - a| /
 * spacing) + 1 steps, each projected onto the fibre (at most LIMIT_CHECK_ITERATIONS
 * Newton steps, until within tolerance; a joint on one limit at the step's start and at b
 * held there), within tolerance, inside the limits, no farther than stretch x the
 * spacing and nearer b. `e`, `J`, `scratch` as project_row's. */
static int inside_between(const Planner *p, const double *a, const double *b, double *e,
                          double *J, double *scratch) {
    Py_ssize_t n = p->n, m = p->m;
    double spacing = p->limit_check;
    if (!(spacing > 0.0)) return 1;
    double length = distance_of(a, b, n);
    if (!(length > spacing)) return 1;
    double reach = p->stretch * length;
    int near = 0;
    for (Py_ssize_t k = 0; k < n; ++k) {
        if (p->periodic[k]) continue;
        double low = p->lower[k], high = p->upper[k];
        near |= (a[k] - low) + (b[k] - low) <= reach || (high - a[k]) + (high - b[k]) <= reach;
    }
    if (!near) return 1;
    Py_ssize_t most = (Py_ssize_t)ceil(reach / spacing) + 1;
    double x[64], guess[64];
    unsigned char held[64];
    memcpy(x, a, sizeof(double) * (size_t)n);
    for (Py_ssize_t step = 0; step < most; ++step) {
        double left = distance_of(b, x, n);
        if (left <= spacing) return 1;
        for (Py_ssize_t k = 0; k < n; ++k) {
            guess[k] = x[k] + spacing * (b[k] - x[k]) / left;
            held[k] = !p->periodic[k] && ((x[k] <= p->lower[k] && b[k] <= p->lower[k]) ||
                                          (x[k] >= p->upper[k] && b[k] >= p->upper[k]));
        }
        residual_rows(p->fixed, p->tip, n, guess, 1, p->rows, m, p->m_position,
                      p->target_position, p->target_rotation, e, J);
        newton_rows(p->fixed, p->tip, n, p->rows, m, p->m_position, p->target_position,
                    p->target_rotation, guess, e, J, 1, LIMIT_CHECK_ITERATIONS, p->tolerance,
                    p->damping, held, NULL, NULL, scratch);
        double error = 0.0;
        for (Py_ssize_t k = 0; k < m; ++k) error += e[k] * e[k];
        if (!(sqrt(error) <= p->tolerance) || !(distance_of(guess, x, n) <= p->stretch * spacing) ||
            !(distance_of(b, guess, n) < left))
            return 0;
        for (Py_ssize_t k = 0; k < n; ++k)
            if (!p->periodic[k] && !(guess[k] >= p->lower[k] && guess[k] <= p->upper[k])) return 0;
        memcpy(x, guess, sizeof(double) * (size_t)n);
    }
    return 0;
}

/* One edge: from q_from toward goal (unwrapped), steps of delta projected onto the fibre,
 * each a valid motion (converged, inside the limits, no jump, nearer the goal, no detour,
 * no unreached coaxial crossing, free) until within delta of the goal, and the last hop
 * to it crossing no coaxial set the fibre does not reach: 1 reached, 0 not,
 * -1 the deadline passed. The steps' points go to `path` (count of them) when given. */
static int walk_edge(const Planner *p, const double *q_from, const double *goal, double chord,
                     double *path, Py_ssize_t *count, double *work) {
    Py_ssize_t n = p->n, m = p->m;
    double *q = work, *q_new = q + n, *guess = q_new + n, *e = guess + n, *J = e + m;
    double *scratch = J + m * n, *e2 = scratch + (m + 1) * n + 2 * n, *J2 = e2 + m,
           *frames = J2 + m * n;
    memcpy(q, q_from, sizeof(double) * (size_t)n);
    double travelled = 0.0;
    *count = 0;
    for (Py_ssize_t step = 0; step < p->max_steps; ++step) {
        double distance = distance_of(goal, q, n);
        /* The last hop, under delta, is taken as it is, but not across a coaxial set the
         * fibre does not reach (samples either side of a singular set it keeps apart). */
        if (distance <= p->delta)
            return (!p->sets || crossings_on_fibre_row(p, q, goal, guess, e2, J2, scratch)) &&
                   inside_between(p, q, goal, e2, J2, scratch);
        if (p->expires_at_s < INFINITY && monotonic_s() > p->expires_at_s) return -1;
        for (Py_ssize_t k = 0; k < n; ++k) q_new[k] = q[k] + p->delta * (goal[k] - q[k]) / distance;
        project_row(p, q_new, e, J, p->iterations, -1, NULL, scratch);
        double error = 0.0;
        for (Py_ssize_t k = 0; k < m; ++k) error += e[k] * e[k];
        error = sqrt(error);
        for (Py_ssize_t extra = 0; extra < p->extra_iterations && !(error <= p->tolerance); ++extra) {
            project_row(p, q_new, e, J, 1, -1, NULL, scratch);
            error = 0.0;
            for (Py_ssize_t k = 0; k < m; ++k) error += e[k] * e[k];
            error = sqrt(error);
        }
        double moved = distance_of(q_new, q, n);
        int ok = error <= p->tolerance && moved <= p->stretch * p->delta &&
                 distance_of(goal, q_new, n) < distance &&
                 travelled + moved <= p->stretch * chord;
        for (Py_ssize_t k = 0; k < n && ok; ++k)
            ok = p->periodic[k] || (q_new[k] >= p->lower[k] && q_new[k] <= p->upper[k]);
        if (ok && p->sets) ok = crossings_on_fibre_row(p, q, q_new, guess, e2, J2, scratch);
        if (ok) ok = inside_between(p, q, q_new, e2, J2, scratch);
        if (ok && (p->check_self || p->obstacles.count)) ok = free_row(p, q_new, frames);
        if (!ok) return 0;
        memcpy(q, q_new, sizeof(double) * (size_t)n);
        travelled += moved;
        if (path != NULL) memcpy(path + (*count)++ * n, q_new, sizeof(double) * (size_t)n);
    }
    return 0;
}

/* ---------------------------------------------------------------- the path a sample is on */

/* q (K, n), points (P, n) of every path, before / after (P,) each point's neighbours along
 * its path, nearest (K, k) rows of points: for each q the least joint-metric distance to
 * the segments point-before and point-after of its k nearest points (differences wrapped
 * on the periodic joints), as curves.segment_distance computes it, and the first nearest
 * point that reaches it (-1 where no distance is finite). */
static double segment_distance_row(const double *q, const double *a, const double *b,
                                   const unsigned char *periodic, Py_ssize_t n) {
    double along[64], offset[64], length2 = 0.0, dot = 0.0;
    for (Py_ssize_t j = 0; j < n; ++j) {
        along[j] = b[j] - a[j];
        offset[j] = q[j] - a[j];
        if (periodic[j]) along[j] = wrap_to_pi(along[j]), offset[j] = wrap_to_pi(offset[j]);
        length2 += along[j] * along[j];
        dot += offset[j] * along[j];
    }
    double fraction = dot / (length2 > 1e-300 ? length2 : 1e-300);
    fraction = fraction < 0.0 ? 0.0 : (fraction > 1.0 ? 1.0 : fraction);
    double total = 0.0;
    for (Py_ssize_t j = 0; j < n; ++j) {
        double d = offset[j] - fraction * along[j];
        total += d * d;
    }
    return sqrt(total);
}

static void nearest_segment_rows(const double *q, const double *points, const long long *before,
                                 const long long *after, const long long *nearest,
                                 const unsigned char *periodic, Py_ssize_t K, Py_ssize_t k,
                                 Py_ssize_t n, double *distance, long long *point) {
    for (Py_ssize_t r = 0; r < K; ++r) {
        const double *qr = q + r * n;
        double best = INFINITY;
        long long which = -1;
        for (Py_ssize_t c = 0; c < k; ++c) {
            long long i = nearest[r * k + c];
            if (i < 0) continue; /* no candidate */
            const double *a = points + i * n;
            double d_before = segment_distance_row(qr, a, points + before[i] * n, periodic, n);
            double d_after = segment_distance_row(qr, a, points + after[i] * n, periodic, n);
            double d = d_after < d_before ? d_after : d_before;
            if (d < best) best = d, which = i;
        }
        distance[r] = best;
        point[r] = which;
    }
}

/* For each query row, the nearest point of its own group (joint metric, wrapped on the
   periodic joints): points are sorted by group, group g's rows [start[g], start[g + 1]).
   The first of equally near points; -1 for a group with no point. */
static void nearest_in_group_rows(const double *points, const long long *start,
                                  const double *queries, const long long *query_group,
                                  const unsigned char *periodic, Py_ssize_t Q, Py_ssize_t n,
                                  long long *nearest) {
    for (Py_ssize_t r = 0; r < Q; ++r) {
        const double *q = queries + r * n;
        long long g = query_group[r], which = -1;
        double best = INFINITY;
        for (long long i = start[g]; i < start[g + 1]; ++i) {
            const double *p = points + i * n;
            double total = 0.0;
            for (Py_ssize_t j = 0; j < n; ++j) {
                double d = q[j] - p[j];
                if (periodic[j]) d = wrap_to_pi(d);
                total += d * d;
            }
            if (total < best) best = total, which = i;
        }
        nearest[r] = which;
    }
}

/* cut.py's `along`: each tangent row with the sign that points it along its direction row;
   a row with a non-finite entry is replaced by the unit direction. */
static void along_rows(const double *tangent, const double *direction, Py_ssize_t K, Py_ssize_t n,
                       double *out) {
    for (Py_ssize_t r = 0; r < K; ++r) {
        const double *t = tangent + r * n, *d = direction + r * n;
        double *o = out + r * n;
        int finite = 1;
        for (Py_ssize_t j = 0; j < n; ++j) finite &= isfinite(t[j]) != 0;
        if (finite) {
            for (Py_ssize_t j = 0; j < n; ++j) o[j] = t[j];
        } else {
            double length = norm_of(d, n);
            for (Py_ssize_t j = 0; j < n; ++j) o[j] = d[j] / length;
        }
        if (dot_of(o, d, n) < 0.0)
            for (Py_ssize_t j = 0; j < n; ++j) o[j] = -o[j];
    }
}

/* cut.py's `hermite`: the cubic Hermite curve from p0 to p1 with end tangents t0, t1 scaled
   by the chord length, at parameter s; its point and unit direction per row. The
   arithmetic is numpy's, term by term, so the points are the same to the bit. */
static void hermite_rows(const double *p0, const double *t0, const double *p1, const double *t1,
                         const double *s, Py_ssize_t K, Py_ssize_t n, double *point,
                         double *direction) {
    double chord[64];
    for (Py_ssize_t r = 0; r < K; ++r) {
        const double *a = p0 + r * n, *b = p1 + r * n, *u = t0 + r * n, *v = t1 + r * n;
        double *x = point + r * n, *d = direction + r * n;
        for (Py_ssize_t j = 0; j < n; ++j) chord[j] = b[j] - a[j];
        double length = norm_of(chord, n), sr = s[r], rr = 1.0 - sr;
        double c1 = sr * sr * (3.0 - 2.0 * sr), c2 = length * sr * rr * rr;
        double c3 = length * sr * sr * rr, c4 = 6.0 * sr * rr;
        double c5 = length * rr * (1.0 - 3.0 * sr), c6 = length * sr * (3.0 * sr - 2.0);
        for (Py_ssize_t j = 0; j < n; ++j) {
            x[j] = a[j] + c1 * chord[j] + c2 * u[j] - c3 * v[j];
            d[j] = c4 * chord[j] + c5 * u[j] + c6 * v[j];
        }
        double size = norm_of(d, n);
        for (Py_ssize_t j = 0; j < n; ++j) d[j] = d[j] / size;
    }
}

/* densify.py's last pass over the dense points, in place: a point Newton carried more than
   `stray_rad` from where it was placed is out; every point into the 2 pi window from `low`
   (numpy's mod); the `fixed` rows set to their given values (limit points, exactly on their
   limit); inside = within the limits and not strayed, false on the `excluded` rows; then the
   periodic joints wrapped to (-pi, pi]. */
static double mod_two_pi(double x) {
    double m = fmod(x, TWO_PI);
    if (m != 0.0) {
        if (m < 0.0) m += TWO_PI;
    } else {
        m = copysign(0.0, TWO_PI);
    }
    return m;
}

static void settle_dense_rows(double *q, const double *placed, const double *low,
                              const double *lower, const double *upper,
                              const unsigned char *periodic, Py_ssize_t D, Py_ssize_t n,
                              double stray_rad, const long long *fixed_rows,
                              const double *fixed_q, Py_ssize_t F, const long long *excluded,
                              Py_ssize_t E, unsigned char *inside) {
    for (Py_ssize_t r = 0; r < D; ++r) {
        double *x = q + r * n, moved = 0.0;
        const double *y = placed + r * n;
        for (Py_ssize_t j = 0; j < n; ++j) {
            double d = x[j] - y[j];
            moved += d * d;
        }
        inside[r] = !(sqrt(moved) > stray_rad);
        for (Py_ssize_t j = 0; j < n; ++j) x[j] = low[j] + mod_two_pi(x[j] - low[j]);
    }
    for (Py_ssize_t f = 0; f < F; ++f)
        for (Py_ssize_t j = 0; j < n; ++j) q[fixed_rows[f] * n + j] = fixed_q[f * n + j];
    for (Py_ssize_t r = 0; r < D; ++r) {
        double *x = q + r * n;
        int within = 1;
        for (Py_ssize_t j = 0; j < n; ++j)
            within &= periodic[j] || (x[j] >= lower[j] && x[j] <= upper[j]);
        inside[r] = inside[r] && within;
        for (Py_ssize_t j = 0; j < n; ++j)
            if (periodic[j]) x[j] = wrap_to_pi(x[j]);
    }
    for (Py_ssize_t e = 0; e < E; ++e) inside[excluded[e]] = 0;
}

/* strands.py's chaining of the trace's fronts into curves. Rows [0, S) of q (T, n) are the
   seeds; row S + i was reached by front by_front[i] (fronts 2 s and 2 s + 1 leave seed s
   along +t and -t), in travel order. A front's last point lies past its partner's when the
   partner's last point is behind it against its last step (the fronts met just after
   passing): that point is dropped from the front followed forward. From each seed not yet
   on a curve: the seed, its + front, the partner front backwards to its seed, that seed's
   other front, ... until back at the first seed (closed), at a front that met none, or at
   a seed another chain took (open; then the same backwards from the - front, in front of
   the seed). Writes the curves' rows to out_rows, curve c at [first[c], first[c + 1]),
   closed[c]; returns the number of curves. Scratch: `front_first` F + 1 and `front_rows`
   T - S longs, `visited` S and `overlap` F bytes, `ahead` and `behind` T longs. */
static long long follow_fronts(const long long *front_first, const long long *front_rows,
                               const long long *partner, const unsigned char *overlap,
                               unsigned char *visited, long long front, long long stop,
                               long long *out, long long *count) {
    long long k = 0;
    for (;;) {
        long long other = partner[front], a = front_first[front], b = front_first[front + 1];
        if (other < 0) {
            for (long long i = a; i < b; ++i) out[k++] = front_rows[i];
            *count = k;
            return 0;
        }
        if (overlap[front]) --b;
        for (long long i = a; i < b; ++i) out[k++] = front_rows[i];
        for (long long i = front_first[other + 1] - 1; i >= front_first[other]; --i)
            out[k++] = front_rows[i];
        long long seed = other / 2;
        if (seed == stop || visited[seed]) {
            *count = k;
            return seed == stop;
        }
        visited[seed] = 1;
        out[k++] = seed;
        front = other ^ 1;
    }
}

static Py_ssize_t chain_fronts_of(const double *q, Py_ssize_t T, Py_ssize_t n, Py_ssize_t S,
                                  const long long *by_front, const long long *partner,
                                  long long *front_first, long long *front_rows,
                                  unsigned char *visited, unsigned char *overlap,
                                  long long *ahead, long long *behind, long long *out_rows,
                                  long long *first, unsigned char *closed) {
    Py_ssize_t F = 2 * S, reached = T - S, C = 0, written = 0;
    for (Py_ssize_t f = 0; f <= F; ++f) front_first[f] = 0;
    for (Py_ssize_t i = 0; i < reached; ++i) ++front_first[by_front[i] + 1];
    for (Py_ssize_t f = 0; f < F; ++f) front_first[f + 1] += front_first[f];
    /* Each front's start is its fill position (there are 2 S fronts and may be fewer than
       2 S points, so no T-long scratch holds them), moved on to the next front's start by
       the fill; then shifted back one place. */
    for (Py_ssize_t i = 0; i < reached; ++i) front_rows[front_first[by_front[i]]++] = S + i;
    for (Py_ssize_t f = F; f > 0; --f) front_first[f] = front_first[f - 1];
    front_first[0] = 0;
    for (Py_ssize_t f = 0; f < F; ++f) {
        long long other = partner[f], a = front_first[f], b = front_first[f + 1];
        overlap[f] = 0;
        if (other < 0 || b - a < 2 || front_first[other + 1] == front_first[other]) continue;
        const double *before = q + front_rows[b - 2] * n, *last = q + front_rows[b - 1] * n;
        const double *theirs = q + front_rows[front_first[other + 1] - 1] * n;
        double dot = 0.0;
        for (Py_ssize_t j = 0; j < n; ++j)
            dot += wrap_to_pi(theirs[j] - last[j]) * wrap_to_pi(last[j] - before[j]);
        overlap[f] = dot < 0.0;
    }
    for (Py_ssize_t s = 0; s < S; ++s) visited[s] = 0;
    first[0] = 0;
    for (Py_ssize_t s = 0; s < S; ++s) {
        if (visited[s]) continue;
        visited[s] = 1;
        long long forward, backward = 0;
        int loop = (int)follow_fronts(front_first, front_rows, partner, overlap, visited, 2 * s,
                                      s, ahead, &forward);
        if (!loop)
            follow_fronts(front_first, front_rows, partner, overlap, visited, 2 * s + 1, s,
                          behind, &backward);
        for (long long i = backward - 1; i >= 0; --i) out_rows[written++] = behind[i];
        out_rows[written++] = s;
        for (long long i = 0; i < forward; ++i) out_rows[written++] = ahead[i];
        closed[C] = (unsigned char)loop;
        first[++C] = written;
    }
    return C;
}

/* points.py's `unwrap` of every curve: curve c's rows [first[c], first[c + 1]) of q read in
   order, each step the short way round (wrap_to_pi of every joint), the points the first
   one plus the running sum of the steps (numpy's cumsum, to the bit). */
static void unwrap_curves_of(const double *q, const long long *rows, const long long *first,
                             Py_ssize_t C, Py_ssize_t n, double *out) {
    double sum[64];
    for (Py_ssize_t c = 0; c < C; ++c) {
        long long a = first[c], b = first[c + 1];
        if (a == b) continue;
        const double *head = q + rows[a] * n;
        for (Py_ssize_t j = 0; j < n; ++j) {
            out[a * n + j] = head[j];
            sum[j] = 0.0;
        }
        for (long long i = a + 1; i < b; ++i) {
            const double *x = q + rows[i] * n, *y = q + rows[i - 1] * n;
            for (Py_ssize_t j = 0; j < n; ++j) {
                sum[j] += wrap_to_pi(x[j] - y[j]);
                out[i * n + j] = head[j] + sum[j];
            }
        }
    }
}

/* cut.py's curves cut by the limits into runs of consecutive points inside them. Curve c
   is rows [first[c], first[c + 1]) of `points` (unwrapped along it) and `rows` (the
   evaluated rows), closed or not; a point is inside when, read in the 2 pi window from
   `low`, every limited joint lies within [lower, upper] (numpy's `to_window` and
   `contains`, to the bit). A curve inside all along is one run (closed as the curve); a
   closed curve that leaves the limits is turned to start outside (the points before its
   first outside one moved on by the curve's turns), so no run wraps round. Each run of an
   open or turned curve is open, with the outside point before it and after it (`exits`
   (R, 2, n), `has_exit` (R, 2): 0 at a curve's own end). Runs are written in order to
   out_points / out_rows, run r at [run_first[r], run_first[r + 1]); returns R. `inside`:
   P bytes of scratch. */
static Py_ssize_t cut_runs_of(const double *points, const long long *rows, const long long *first,
                              const unsigned char *closed, Py_ssize_t C, Py_ssize_t n,
                              const double *low, const double *lower, const double *upper,
                              const unsigned char *periodic, unsigned char *inside,
                              double *out_points, long long *out_rows, long long *run_first,
                              unsigned char *run_closed, double *exits,
                              unsigned char *has_exit) {
    Py_ssize_t R = 0, written = 0;
    double turns[64];
    run_first[0] = 0;
    for (Py_ssize_t c = 0; c < C; ++c) {
        Py_ssize_t a = first[c], k = first[c + 1] - first[c], count = 0, shift = -1;
        for (Py_ssize_t i = 0; i < k; ++i) {
            const double *x = points + (a + i) * n;
            int within = 1;
            for (Py_ssize_t j = 0; j < n; ++j) {
                double w = low[j] + mod_two_pi(x[j] - low[j]);
                within &= periodic[j] || (w >= lower[j] && w <= upper[j]);
            }
            inside[i] = (unsigned char)within;
            count += within;
            if (!within && shift < 0) shift = i;
        }
        if (count == 0) continue;
        if (count == k) { /* one run, the curve as it is */
            memcpy(out_points + written * n, points + a * n, (size_t)(k * n) * sizeof(double));
            memcpy(out_rows + written, rows + a, (size_t)k * sizeof(long long));
            written += k;
            run_closed[R] = closed[c];
            has_exit[2 * R] = has_exit[2 * R + 1] = 0;
            run_first[++R] = written;
            continue;
        }
        int loop = closed[c] != 0;
        if (!loop) shift = 0;
        const double *head = points + a * n, *tail = points + (a + k - 1) * n;
        for (Py_ssize_t j = 0; j < n; ++j)
            turns[j] = loop ? tail[j] + wrap_to_pi(head[j] - tail[j]) - head[j] : 0.0;
/* the i-th point of the (turned) curve, written to x */
#define TURNED(i, x)                                                                          \
    do {                                                                                      \
        Py_ssize_t at_ = shift + (i), wrapped_ = at_ >= k;                                    \
        if (wrapped_) at_ -= k;                                                               \
        const double *p_ = points + (a + at_) * n;                                            \
        for (Py_ssize_t j_ = 0; j_ < n; ++j_) (x)[j_] = wrapped_ ? p_[j_] + turns[j_] : p_[j_]; \
    } while (0)
#define INSIDE(i) inside[(shift + (i)) >= k ? shift + (i) - k : shift + (i)]
        Py_ssize_t i = 0;
        while (i < k) {
            if (!INSIDE(i)) {
                ++i;
                continue;
            }
            Py_ssize_t begin = i;
            while (i < k && INSIDE(i)) {
                Py_ssize_t at = shift + i;
                out_rows[written] = rows[a + (at >= k ? at - k : at)];
                TURNED(i, out_points + written * n);
                ++written;
                ++i;
            }
            double *before = exits + 2 * R * n, *after = before + n;
            has_exit[2 * R] = begin > 0 || loop;
            if (begin > 0) TURNED(begin - 1, before);
            else if (loop) TURNED(k - 1, before);
            has_exit[2 * R + 1] = i < k || loop;
            if (i < k) TURNED(i, after);
            else if (loop) TURNED(0, after);
            run_closed[R] = 0;
            run_first[++R] = written;
        }
#undef TURNED
#undef INSIDE
    }
    return R;
}

/* densify.py's nodes: each run's refined start (limit_of[2 r] >= 0: row L0 of `found`),
   its points, its refined end (limit_of[2 r + 1]), and for a closed run its first point
   again, the short way round; node_row is the node's evaluated row (T + l for limit
   point l), node_kind 0 for a point Newton moves, 1 for a limit point (kept as refined),
   2 for a closed run's closing repeat. Then how many inner points the segment after each
   node gets: ceil(|chord| / (0.9 spacing)) - 1, at least 0, none after a run's last node
   (numpy's order to the bit). Returns the dense points in all (nodes and inner points). */
static Py_ssize_t dense_nodes_of(const double *points, const long long *rows,
                                 const long long *first, const unsigned char *closed,
                                 Py_ssize_t R, Py_ssize_t n, const long long *limit_of,
                                 const double *found, Py_ssize_t T, double spacing_rad,
                                 double *node_q, long long *node_row, long long *node_run,
                                 unsigned char *node_kind, long long *inner) {
    Py_ssize_t N = 0;
    double gap = 0.9 * spacing_rad;
    for (Py_ssize_t r = 0; r < R; ++r) {
        Py_ssize_t start = N;
        long long head = limit_of[2 * r], end = limit_of[2 * r + 1];
        if (head >= 0) {
            memcpy(node_q + N * n, found + head * n, (size_t)n * sizeof(double));
            node_row[N] = T + head;
            node_kind[N++] = 1;
        }
        for (long long i = first[r]; i < first[r + 1]; ++i) {
            memcpy(node_q + N * n, points + i * n, (size_t)n * sizeof(double));
            node_row[N] = rows[i];
            node_kind[N++] = 0;
        }
        if (end >= 0) {
            memcpy(node_q + N * n, found + end * n, (size_t)n * sizeof(double));
            node_row[N] = T + end;
            node_kind[N++] = 1;
        }
        if (closed[r]) { /* back to the first point, the short way round */
            const double *last = node_q + (N - 1) * n, *head_q = node_q + start * n;
            double *x = node_q + N * n;
            for (Py_ssize_t j = 0; j < n; ++j) x[j] = last[j] + wrap_to_pi(head_q[j] - last[j]);
            node_row[N] = node_row[start];
            node_kind[N++] = 2;
        }
        for (Py_ssize_t i = start; i < N; ++i) node_run[i] = r;
    }
    Py_ssize_t D = 0;
    for (Py_ssize_t i = 0; i < N; ++i) {
        inner[i] = 0;
        if (i + 1 < N && node_run[i + 1] == node_run[i]) {
            double sum = 0.0;
            for (Py_ssize_t j = 0; j < n; ++j) {
                double d = node_q[(i + 1) * n + j] - node_q[i * n + j];
                sum += d * d;
            }
            double count = ceil(sqrt(sum) / gap);
            inner[i] = (long long)(count > 1.0 ? count : 1.0) - 1;
        }
        D += inner[i] + 1;
    }
    return D;
}

/* densify.py's dense path from the nodes: node i at dense row offset[i], then its
   segment's inner points, the p-th of c on the cubic Hermite curve between the node and
   the next at s = p / (c + 1) with their tangents (rows of `tangent` (T, n), then of
   `found_tangent`) signed along the chord (`along_rows`, `hermite_rows`). placed (D, n):
   where each dense point is put before Newton; dense_run (D,): its run; between (I,):
   the inner points' dense rows, guess and direction (I, n) theirs. */
static void dense_layout_of(const double *node_q, const long long *node_row,
                            const long long *node_run, const long long *inner, Py_ssize_t N,
                            Py_ssize_t n, const double *tangent, const double *found_tangent,
                            Py_ssize_t T, double *placed, long long *dense_run,
                            long long *offset, long long *between, double *guess,
                            double *direction) {
    double chord[64], t0[64], t1[64];
    Py_ssize_t row = 0, I = 0;
    for (Py_ssize_t i = 0; i < N; ++i) {
        const double *a = node_q + i * n;
        offset[i] = row;
        memcpy(placed + row * n, a, (size_t)n * sizeof(double));
        dense_run[row++] = node_run[i];
        long long c = inner[i];
        if (c == 0) continue;
        const double *b = a + n;
        long long ra = node_row[i], rb = node_row[i + 1];
        const double *ta = ra < T ? tangent + ra * n : found_tangent + (ra - T) * n;
        const double *tb = rb < T ? tangent + rb * n : found_tangent + (rb - T) * n;
        for (Py_ssize_t j = 0; j < n; ++j) chord[j] = b[j] - a[j];
        along_rows(ta, chord, 1, n, t0);
        along_rows(tb, chord, 1, n, t1);
        for (long long p = 1; p <= c; ++p) {
            double s = (double)p / (double)(c + 1);
            hermite_rows(a, t0, b, t1, &s, 1, n, guess + I * n, direction + I * n);
            memcpy(placed + row * n, guess + I * n, (size_t)n * sizeof(double));
            between[I++] = row;
            dense_run[row++] = node_run[i];
        }
    }
}

/* densify.py's dense path after Newton. q starts as the placed points (D, n); each node's
   error is the one measured at it (`evaluated_error` (T, m) rows, or `found_error` of a
   limit point, row T + l); the moved rows (`moved_rows` (M,)) take Newton's points and
   errors; a limit node (kind 1) is set to its refined point in the window (`found_window`)
   and a closing repeat (kind 2) is left out; then `settle_dense_rows`. The points inside
   are written in order to q_out and error_out, and counted per run (`dense_run` (D,) ->
   run_count (R,)); returns how many. Scratch: q (D n), error (D m), fixed_rows (N),
   fixed_q (N n), excluded (N), inside (D). */
static Py_ssize_t dense_finish_of(
    const double *placed, Py_ssize_t D, Py_ssize_t n, Py_ssize_t m, const double *moved_q,
    const double *moved_error, const long long *moved_rows, Py_ssize_t M,
    const long long *offset, const long long *node_row, const unsigned char *node_kind,
    Py_ssize_t N, const double *evaluated_error, Py_ssize_t T, const double *found_error,
    const double *found_window, const long long *dense_run, Py_ssize_t R, const double *low,
    const double *lower, const double *upper, const unsigned char *periodic, double stray_rad,
    double *q, double *error, long long *fixed_rows, double *fixed_q, long long *excluded,
    unsigned char *inside, double *q_out, double *error_out, long long *run_count) {
    memcpy(q, placed, (size_t)(D * n) * sizeof(double));
    Py_ssize_t F = 0, E = 0;
    for (Py_ssize_t i = 0; i < N; ++i) {
        long long row = node_row[i];
        const double *measured = row < T ? evaluated_error + row * m : found_error + (row - T) * m;
        memcpy(error + offset[i] * m, measured, (size_t)m * sizeof(double));
        if (node_kind[i] == 1) {
            fixed_rows[F] = offset[i];
            memcpy(fixed_q + F * n, found_window + (row - T) * n, (size_t)n * sizeof(double));
            ++F;
        } else if (node_kind[i] == 2) {
            excluded[E++] = offset[i];
        }
    }
    for (Py_ssize_t k = 0; k < M; ++k) {
        memcpy(q + moved_rows[k] * n, moved_q + k * n, (size_t)n * sizeof(double));
        memcpy(error + moved_rows[k] * m, moved_error + k * m, (size_t)m * sizeof(double));
    }
    settle_dense_rows(q, placed, low, lower, upper, periodic, D, n, stray_rad, fixed_rows,
                      fixed_q, F, excluded, E, inside);
    for (Py_ssize_t r = 0; r < R; ++r) run_count[r] = 0;
    Py_ssize_t count = 0;
    for (Py_ssize_t d = 0; d < D; ++d) {
        if (!inside[d]) continue;
        memcpy(q_out + count * n, q + d * n, (size_t)n * sizeof(double));
        memcpy(error_out + count * m, error + d * m, (size_t)m * sizeof(double));
        ++run_count[dense_run[d]];
        ++count;
    }
    return count;
}

/* strands.py's closest approach of two strands of the traced fibre: the least joint-metric
   distance, at most `within_rad`, between points of two different curves, or of one curve
   but more than `strand_arc` apart along it (the shorter way round a closed one); +inf
   when none. Curve c is rows [first[c], first[c + 1]) of `points`. Every step, arc and
   distance is summed in numpy's order, so the answer is the numpy one to the bit.

   Candidate pairs come from a grid on two joints' embedded coordinates (a limited joint, or
   the cosine or sine of a periodic one) that spread the points most: two points within
   `within_rad` differ by no more in either. The points are sorted by their column of width
   w >= `within_rad` in the first and by the second within it; a point is paired with the
   later points of its column and those of the next within `within_rad` in the second.
   `work`: 2 P doubles; `order`: P; `curve_of`: P; `column`: P + 2. */
typedef struct {
    double x, y; /* the two coordinates */
    long long cell, row;
} Gridded;

static int by_cell(const void *a, const void *b) {
    const Gridded *u = a, *v = b;
    if (u->cell != v->cell) return (u->cell > v->cell) - (u->cell < v->cell);
    return (u->y > v->y) - (u->y < v->y);
}

/* wrap_to_pi, with no division for |angle| < 3 (there ceil((angle - pi) / 2 pi) is 0, so the
   formula gives the angle itself, to the bit). */
static double wrap_near(double angle) { return fabs(angle) < 3.0 ? angle : wrap_to_pi(angle); }

static double joint_distance_row(const double *a, const double *b, const unsigned char *periodic,
                                 Py_ssize_t n) {
    double sum = 0.0;
    for (Py_ssize_t j = 0; j < n; ++j) {
        double d = a[j] - b[j];
        if (periodic[j]) d = wrap_near(d);
        sum += d * d;
    }
    return sqrt(sum);
}

/* Coordinate e of the embedding: joint j itself, or the cosine (t = 1) or sine (t = 2). */
static double embedded(const double *q, Py_ssize_t j, int t) {
    return t == 0 ? q[j] : (t == 1 ? cos(q[j]) : sin(q[j]));
}

static double closest_strands(const double *points, Py_ssize_t P, Py_ssize_t n,
                              const long long *first, Py_ssize_t C, const unsigned char *closed,
                              const unsigned char *periodic, double within_rad,
                              double strand_arc, double *work, Gridded *order,
                              long long *curve_of, long long *column) {
    double *arc = work, *total = work + P;
    for (Py_ssize_t c = 0; c < C; ++c) {
        long long a = first[c], b = first[c + 1];
        double s = 0.0;
        for (long long i = a; i < b; ++i) {
            if (i > a) s += joint_distance_row(points + i * n, points + (i - 1) * n, periodic, n);
            arc[i] = s, curve_of[i] = c;
        }
        double closing = 0.0;
        if (closed[c] && b > a)
            closing = joint_distance_row(points + a * n, points + (b - 1) * n, periodic, n);
        for (long long i = a; i < b; ++i) total[i] = s + closing;
    }
    if (P < 2 || !(within_rad >= 0.0)) return INFINITY;
    /* Two joints' embedded coordinates of widest spread (a periodic joint's the wider of
       its cosine and sine): two of one joint would put every point on its circle. */
    double spread[2] = {-1.0, -1.0}, low[2] = {0.0, 0.0};
    Py_ssize_t joint[2] = {0, 0};
    int trig[2] = {0, 0};
    for (Py_ssize_t j = 0; j < n; ++j) {
        double width = -1.0, from = 0.0;
        int kind = 0;
        for (int t = 0; t < (periodic[j] ? 2 : 1); ++t) {
            int k = periodic[j] ? 1 + t : 0;
            double lo = INFINITY, hi = -INFINITY;
            for (Py_ssize_t i = 0; i < P; ++i) {
                double v = embedded(points + i * n, j, k);
                lo = v < lo ? v : lo, hi = v > hi ? v : hi;
            }
            if (hi - lo > width) width = hi - lo, from = lo, kind = k;
        }
        if (width > spread[0]) {
            spread[1] = spread[0], joint[1] = joint[0], trig[1] = trig[0], low[1] = low[0];
            spread[0] = width, joint[0] = j, trig[0] = kind, low[0] = from;
        } else if (width > spread[1]) {
            spread[1] = width, joint[1] = j, trig[1] = kind, low[1] = from;
        }
    }
    if (spread[1] < 0.0) joint[1] = joint[0], trig[1] = trig[0]; /* one coordinate only */
    double w = within_rad > spread[0] / (double)P ? within_rad : spread[0] / (double)P;
    long long cells = 1;
    for (Py_ssize_t i = 0; i < P; ++i) {
        const double *q = points + i * n;
        double x = embedded(q, joint[0], trig[0]);
        long long cell = isfinite(w) && w > 0.0 ? (long long)floor((x - low[0]) / w) : 0;
        cell = cell < 0 ? 0 : (cell > P ? P : cell);
        order[i] = (Gridded){x, embedded(q, joint[1], trig[1]), cell, i};
        cells = cell + 1 > cells ? cell + 1 : cells;
    }
    qsort(order, (size_t)P, sizeof *order, by_cell);
    for (long long c = 0; c <= cells; ++c) column[c] = P;
    for (Py_ssize_t u = P - 1; u >= 0; --u) column[order[u].cell] = u;
    for (long long c = cells - 1; c >= 0; --c)
        if (column[c] > column[c + 1]) column[c] = column[c + 1];
    double best = INFINITY;
    for (Py_ssize_t u = 0; u < P; ++u) {
        const Gridded *g = order + u;
        long long a = g->row;
        for (int next = 0; next < 2; ++next) {
            long long c = g->cell + next;
            if (c >= cells) break;
            Py_ssize_t v = next ? column[c] : u + 1, end = column[c + 1];
            if (next) { /* the first of the next column within reach in y: binary search */
                Py_ssize_t lo = v, hi = end;
                while (lo < hi) {
                    Py_ssize_t mid = lo + (hi - lo) / 2;
                    if (order[mid].y < g->y - within_rad) lo = mid + 1; else hi = mid;
                }
                v = lo;
            }
            for (; v < end; ++v) {
                const Gridded *h = order + v;
                if (!(h->y - g->y <= within_rad)) break;
                if (!(fabs(h->x - g->x) <= within_rad)) continue;
                long long b = h->row;
                if (curve_of[a] == curve_of[b]) {
                    double d = fabs(arc[a] - arc[b]);
                    if (closed[curve_of[a]]) d = d < total[a] - d ? d : total[a] - d;
                    if (!(d > strand_arc)) continue;
                }
                double distance = joint_distance_row(points + a * n, points + b * n, periodic, n);
                if (distance <= within_rad && distance < best) best = distance;
            }
        }
    }
    return best;
}

/* cut.py's test of which trace steps the refinement splits: a step from `start` by `delta`
   (unwrapped like its curve), read in the 2 pi window from `low`, with neither end inside
   the limits, whose chord, the limits widened by a quarter of its length (how far a curve
   bends off its chord in a step), passes through the box: the slab test over the limited
   joints, NaN as numpy carries it (no step). */
static void steps_near_limits_rows(const double *start, const double *delta, const double *low,
                                   const double *lower, const double *upper,
                                   const unsigned char *periodic, Py_ssize_t S, Py_ssize_t n,
                                   unsigned char *split) {
    for (Py_ssize_t r = 0; r < S; ++r) {
        const double *x = start + r * n, *d = delta + r * n;
        double margin = 0.25 * norm_of(d, n), entry = -INFINITY, leave = INFINITY;
        int inside_a = 1, inside_b = 1;
        for (Py_ssize_t j = 0; j < n; ++j) {
            double a = low[j] + mod_two_pi(x[j] - low[j]), b = a + d[j];
            inside_a &= periodic[j] || (a >= lower[j] && a <= upper[j]);
            inside_b &= periodic[j] || (b >= lower[j] && b <= upper[j]);
            if (periodic[j]) continue;
            double lo = lower[j] - margin, hi = upper[j] + margin, step = b - a;
            double in, out;
            if (step == 0.0) {
                int within = a >= lo && a <= hi;
                in = within ? -INFINITY : INFINITY, out = within ? INFINITY : -INFINITY;
            } else {
                double t1 = (lo - a) / step, t2 = (hi - a) / step;
                in = nan_min(t1, t2), out = nan_max(t1, t2);
            }
            entry = nan_max(entry, in), leave = nan_min(leave, out);
        }
        split[r] = entry <= leave && leave >= 0.0 && entry <= 1.0 && !inside_a && !inside_b;
    }
}

/* cut.py's `Steps.of`: every step of every curve (the closing step of a closed one
   included), in curve order, point order within each: the curve (`loop`), the index of its
   first point in the curve (`key`), span 1, its start (the curve's unwrapped point), delta
   (the evaluated ends' difference the short way round, torus_difference) and the ends'
   tangents signed along delta (`along`). Returns the step count. */
static Py_ssize_t curve_steps_of(const double *q, const double *tangent, Py_ssize_t n,
                                 const double *points, const long long *rows,
                                 const long long *first, const unsigned char *closed,
                                 Py_ssize_t L, long long *loop, double *key, double *span,
                                 double *start, double *delta, double *start_tangent,
                                 double *end_tangent) {
    Py_ssize_t c = 0;
    for (Py_ssize_t l = 0; l < L; ++l) {
        long long a0 = first[l], size = first[l + 1] - first[l];
        for (long long i = 0; i < size; ++i) {
            int last = i == size - 1;
            if (last && !closed[l]) continue;
            long long p = a0 + i, ra = rows[p], rb = rows[last ? a0 : p + 1];
            double *d = delta + c * n;
            loop[c] = l, key[c] = (double)i, span[c] = 1.0;
            for (Py_ssize_t j = 0; j < n; ++j) {
                start[c * n + j] = points[p * n + j];
                d[j] = wrap_to_pi(q[rb * n + j] - q[ra * n + j]);
            }
            along_rows(tangent + ra * n, d, 1, n, start_tangent + c * n);
            along_rows(tangent + rb * n, d, 1, n, end_tangent + c * n);
            ++c;
        }
    }
    return c;
}

/* A refinement's steps (S of them) and where it writes the next round's (p S at most). */
typedef struct {
    long long *loop;
    double *key, *span, *start, *delta, *start_tangent, *end_tangent;
} Steps;

/* One round of cut.py's `refine_near_limits` on the steps `in` (S): the steps near the limits
   (`steps_near_limits_rows`) each split at fractions i / p (i = 1 .. p - 1) of the cubic
   Hermite curve through its ends, each guess projected onto the fibre by Newton
   (`newton_rows`: evaluated first, `iterations` bordered steps orthogonal to the curve's
   direction, a row stopping once |e| <= until); a step whose p - 1 points all end within
   |e| < 1e-6 is split there: its points are added (q, error, Jacobian, the unit tangent
   from [J; direction^T] t = [0; 1], their curve and place `key + span i / p`) and its p
   pieces are the next round's steps (`Steps.split`). The arithmetic is numpy's, term by
   term. counts[0]: the steps near the limits; counts[1]: those split (their (p - 1) points
   added, p counts[1] next steps). `scratch` holds (p - 1) (2 n + m + m n) + n n + 2 n +
   (m + 3) n doubles (at most 64 pieces). */
static void refine_round_of(const double *fixed, const double *tip, Py_ssize_t n,
                            const long long *rows, Py_ssize_t m, Py_ssize_t m_position,
                            const double *target_position, const double *target_rotation,
                            Py_ssize_t S, Steps in, const double *low, const double *lower,
                            const double *upper, const unsigned char *periodic, Py_ssize_t p,
                            Py_ssize_t iterations, double until, double damping,
                            double *added_q, double *added_error, double *added_jacobian,
                            double *added_tangent, long long *added_loop, double *added_key,
                            Steps out, Py_ssize_t *counts, double *scratch) {
    Py_ssize_t k = p - 1, near = 0, split = 0;
    double *end = scratch, *guess = end + n, *direction = guess + k * n;
    double *error = direction + k * n, *jacobian = error + k * m, *solve = jacobian + k * m * n;
    double *rhs = solve + n * n, *newton_scratch = rhs + n;
    for (Py_ssize_t s = 0; s < S; ++s) {
        const double *a = in.start + s * n, *d = in.delta + s * n;
        unsigned char is_near;
        steps_near_limits_rows(a, d, low, lower, upper, periodic, 1, n, &is_near);
        if (!is_near) continue;
        ++near;
        for (Py_ssize_t j = 0; j < n; ++j) end[j] = a[j] + d[j];
        for (Py_ssize_t i = 0; i < k; ++i) {
            double fraction = (double)(i + 1) / (double)p;
            hermite_rows(a, in.start_tangent + s * n, end, in.end_tangent + s * n, &fraction, 1, n,
                         guess + i * n, direction + i * n);
        }
        unsigned char fresh[64];
        for (Py_ssize_t i = 0; i < k; ++i) fresh[i] = 1;
        newton_rows(fixed, tip, n, rows, m, m_position, target_position, target_rotation, guess,
                    error, jacobian, k, iterations, until, damping, NULL, direction, fresh,
                    newton_scratch);
        int ok = 1;
        for (Py_ssize_t i = 0; i < k; ++i) ok &= norm_of(error + i * m, m) < 1e-6;
        if (!ok) continue;
        /* The step's points, added after those of the steps split before it. */
        Py_ssize_t at = split * k;
        for (Py_ssize_t i = 0; i < k; ++i) {
            double *t = added_tangent + (at + i) * n;
            for (Py_ssize_t j = 0; j < n; ++j) rhs[j] = j == m ? 1.0 : 0.0;
            bordered_rows(jacobian + i * m * n, direction + i * n, rhs, 1, n, t, solve);
            double length = norm_of(t, n);
            for (Py_ssize_t j = 0; j < n; ++j) t[j] = t[j] / length;
            memcpy(added_q + (at + i) * n, guess + i * n, n * sizeof(double));
            memcpy(added_error + (at + i) * m, error + i * m, m * sizeof(double));
            memcpy(added_jacobian + (at + i) * m * n, jacobian + i * m * n,
                   m * n * sizeof(double));
            added_loop[at + i] = in.loop[s];
            added_key[at + i] = in.key[s] + in.span[s] * ((double)(i + 1) / (double)p);
        }
        /* Its p pieces: nodes a, the added points unwrapped like a, a + d. */
        for (Py_ssize_t i = 0; i < p; ++i) {
            Py_ssize_t o = split * p + i;
            double *start = out.start + o * n, *delta = out.delta + o * n;
            for (Py_ssize_t j = 0; j < n; ++j) {
                double from = i == 0 ? a[j] : a[j] + wrap_to_pi(guess[(i - 1) * n + j] - a[j]);
                double to = i == k ? end[j] : a[j] + wrap_to_pi(guess[i * n + j] - a[j]);
                start[j] = from, delta[j] = to - from;
            }
            const double *t_from = i == 0 ? in.start_tangent + s * n : added_tangent + (at + i - 1) * n;
            const double *t_to = i == k ? in.end_tangent + s * n : added_tangent + (at + i) * n;
            along_rows(t_from, delta, 1, n, out.start_tangent + o * n);
            along_rows(t_to, delta, 1, n, out.end_tangent + o * n);
            out.loop[o] = in.loop[s];
            out.span[o] = in.span[s] / (double)p;
            out.key[o] = in.key[s] + out.span[o] * (double)i;
        }
        ++split;
    }
    counts[0] = near, counts[1] = split;
}

/* densify.py's `limit_points` for E run ends: each from its inner point a (unwrapped) toward
   its outside point b, read in the 2 pi window from `low`, the joint that leaves first set on
   the limit it crosses and held there while `iterations` DLS steps (rows within `until`
   stop) put the rest back on the fibre; then that joint exactly on its limit, whether the
   point is good (inside the limits, within twice the step of a, |e| < 1e-8), its unit
   tangent from [J; b - a] t = [0; 1], and the point in a's unwrapped coordinates. The
   arithmetic is numpy's, term by term (argmin: the first least, or the first NaN). Writes
   q_window (E, n), q_unwrapped (E, n), error (E, m), jacobian (E, m, n), tangent (E, n) and
   good (E,). `scratch` holds n n + 5 n + (m + 3) n doubles. */
static void limit_points_of(const double *fixed, const double *tip, Py_ssize_t n,
                            const long long *rows, Py_ssize_t m, Py_ssize_t m_position,
                            const double *target_position, const double *target_rotation,
                            Py_ssize_t E, const double *a_in, const double *b_in,
                            const double *low, const double *lower, const double *upper,
                            const unsigned char *periodic, Py_ssize_t iterations, double until,
                            double damping, double *q_window, double *q_unwrapped,
                            double *error, double *jacobian, double *tangent,
                            unsigned char *good, double *scratch) {
    double *solve = scratch, *b = solve + n * n, *a_w = b + n, *b_w = a_w + n, *rhs = b_w + n;
    double *previous = rhs + n, *newton_scratch = previous + n;
    unsigned char locked[64];
    for (Py_ssize_t e = 0; e < E; ++e) {
        const double *a = a_in + e * n, *raw = b_in + e * n;
        double *q = q_window + e * n;
        Py_ssize_t joint = 0;
        double least = 0.0, t_low_j = 0.0, t_high_j = 0.0;
        for (Py_ssize_t j = 0; j < n; ++j) {
            b[j] = a[j] + wrap_to_pi(raw[j] - a[j]);
            a_w[j] = low[j] + mod_two_pi(a[j] - low[j]);
            b_w[j] = a_w[j] + (b[j] - a[j]);
            double t_low = b_w[j] < lower[j] ? (a_w[j] - lower[j]) / (a_w[j] - b_w[j]) : INFINITY;
            double t_high = b_w[j] > upper[j] ? (upper[j] - a_w[j]) / (b_w[j] - a_w[j]) : INFINITY;
            double t_cross = periodic[j] ? INFINITY : nan_min(t_low, t_high);
            /* np.argmin: the first NaN, else the first least */
            if (j == 0 || (least == least && (t_cross != t_cross || t_cross < least))) {
                joint = j, least = t_cross, t_low_j = t_low, t_high_j = t_high;
            }
        }
        double t = nan_min(nan_max(least, 0.0), 1.0);
        for (Py_ssize_t j = 0; j < n; ++j) q[j] = a_w[j] + t * (b_w[j] - a_w[j]);
        double bound = t_low_j <= t_high_j ? lower[joint] : upper[joint];
        q[joint] = bound;
        for (Py_ssize_t j = 0; j < n; ++j) locked[j] = j == joint;
        unsigned char fresh = 1;
        double *err = error + e * m, *J = jacobian + e * m * n;
        newton_rows(fixed, tip, n, rows, m, m_position, target_position, target_rotation, q, err,
                    J, 1, iterations, until, damping, locked, NULL, &fresh, newton_scratch);
        q[joint] = bound;
        int inside = 1;
        for (Py_ssize_t j = 0; j < n; ++j)
            inside &= periodic[j] || (q[j] >= lower[j] && q[j] <= upper[j]);
        for (Py_ssize_t j = 0; j < n; ++j) rhs[j] = q[j] - a_w[j], previous[j] = b_w[j] - a_w[j];
        int close = norm_of(rhs, n) <= 2.0 * norm_of(previous, n);
        good[e] = inside && close && norm_of(err, m) < 1e-8;
        for (Py_ssize_t j = 0; j < n; ++j) {
            previous[j] = b[j] - a[j];
            rhs[j] = j == m ? 1.0 : 0.0;
            q_unwrapped[e * n + j] = q[j] + (a[j] - a_w[j]);
        }
        double *t_row = tangent + e * n;
        bordered_rows(J, previous, rhs, 1, n, t_row, solve);
        double length = norm_of(t_row, n);
        for (Py_ssize_t j = 0; j < n; ++j) t_row[j] = t_row[j] / length;
    }
}

/* Each query's k nearest points (joint metric, wrapped on the periodic joints), nearest
   first, the lower row first among equally near ones; fewer than k points give -1 after
   them. The points are binned on a grid over two joints (those that spread the points and
   queries most; a periodic joint's cells go round its circle), about 4 P cells; a query looks at rings of cells around its own until the k-th nearest so far is no
   farther than the ring's reach (a point beyond it differs by more than that in one of
   the two joints, hence in the metric) or every point within `reach` is seen, or past
   FAR_RINGS rings measures every point; only points within `reach` are returned. */
typedef struct {
    Py_ssize_t joint;
    int periodic;
    double low, width;
    long long cells;
} Axis;

static double axis_value(const Axis *axis, const double *q) {
    double v = q[axis->joint];
    return axis->periodic ? wrap_to_pi(v) : v;
}

static long long cell_of(const Axis *axis, const double *q) {
    double at = floor((axis_value(axis, q) - axis->low) / axis->width);
    if (!(at >= 0.0)) return 0; /* below, or NaN */
    if (at >= (double)axis->cells) return axis->cells - 1;
    return (long long)at;
}

/* The cell `offset` cells from `from` along the axis, -1 where there is none at exactly that
   distance (off a limited axis, or round a periodic one to a nearer cell). */
static long long cell_at(const Axis *axis, long long from, long long offset) {
    if (!axis->periodic) {
        long long c = from + offset;
        return c < 0 || c >= axis->cells ? -1 : c;
    }
    long long span = offset < 0 ? -offset : offset;
    if (2 * span > axis->cells || (2 * span == axis->cells && offset < 0 && span > 0)) return -1;
    return ((from + offset) % axis->cells + axis->cells) % axis->cells;
}

/* Rings of cells a query searches before it measures every point instead: beyond them the
   rings are mostly empty cells, and a far query is cheaper taken point by point. */
#define FAR_RINGS 4

static void nearest_points_rows(const double *points, Py_ssize_t P, const double *queries,
                                Py_ssize_t K, const unsigned char *periodic, Py_ssize_t n,
                                Py_ssize_t k, double reach, long long *out, long long *cell_start,
                                long long *binned, long long *cell_point, const Axis *axes) {
    long long cells = axes[0].cells * axes[1].cells;
    for (long long c = 0; c <= cells; ++c) cell_start[c] = 0;
    for (Py_ssize_t i = 0; i < P; ++i) {
        const double *q = points + i * n;
        cell_point[i] = cell_of(axes, q) * axes[1].cells + cell_of(axes + 1, q);
        cell_start[cell_point[i] + 1] += 1;
    }
    for (long long c = 0; c < cells; ++c) cell_start[c + 1] += cell_start[c];
    for (Py_ssize_t i = 0; i < P; ++i) binned[cell_start[cell_point[i]]++] = i;
    for (long long c = cells; c > 0; --c) cell_start[c] = cell_start[c - 1];
    cell_start[0] = 0;
    double reach_step = axes[0].width < axes[1].width ? axes[0].width : axes[1].width;
    long long rings = axes[0].cells > axes[1].cells ? axes[0].cells : axes[1].cells;
    for (Py_ssize_t r = 0; r < K; ++r) {
        const double *q = queries + r * n;
        long long *best = out + r * k;
        double best_d[64];
        Py_ssize_t found = 0;
        long long cx = cell_of(axes, q), cy = cell_of(axes + 1, q);
        for (long long ring = 0; ring <= rings; ++ring) {
            /* The ring's cells along y: every one on its edges in x, its two ends between. */
            long long ys[2 * FAR_RINGS + 1], ends[2];
            Py_ssize_t count = 0;
            for (long long dy = -ring; dy <= ring && ring <= FAR_RINGS; ++dy) {
                long long y = cell_at(axes + 1, cy, dy);
                if (y >= 0) ys[count++] = y;
            }
            ends[0] = cell_at(axes + 1, cy, -ring), ends[1] = ring ? cell_at(axes + 1, cy, ring) : -1;
            for (long long dx = -ring; dx <= ring; ++dx) {
                long long x = cell_at(axes, cx, dx);
                if (x < 0) continue;
                int edge = dx == -ring || dx == ring;
                const long long *row = edge ? ys : ends;
                Py_ssize_t across = edge ? count : 2;
                for (Py_ssize_t e = 0; e < across; ++e) {
                    long long y = row[e];
                    if (y < 0) continue;
                    long long c = x * axes[1].cells + y;
                    for (long long t = cell_start[c]; t < cell_start[c + 1]; ++t) {
                        long long i = binned[t];
                        double d = joint_distance_row(q, points + i * n, periodic, n);
                        /* insert (d, i) into the sorted best list, ties by lower row */
                        Py_ssize_t at = found;
                        while (at > 0 && (best_d[at - 1] > d ||
                                          (best_d[at - 1] == d && best[at - 1] > i)))
                            --at;
                        if (at >= k) continue;
                        Py_ssize_t last = found < k ? found : k - 1;
                        for (Py_ssize_t m = last; m > at; --m)
                            best_d[m] = best_d[m - 1], best[m] = best[m - 1];
                        best_d[at] = d, best[at] = i;
                        if (found < k) ++found;
                    }
                }
            }
            /* Unseen points lie more than ring x width away in one joint. */
            if (found == k && best_d[k - 1] <= (double)ring * reach_step) break;
            if ((double)ring * reach_step >= reach) break; /* every point within reach seen */
            if (ring == FAR_RINGS) { /* far from every point: all of them, one by one */
                found = 0;
                for (long long i = 0; i < P; ++i) {
                    /* A point whose partial sum already passes the k-th nearest is out. */
                    const double *x = points + i * n;
                    double bound = found == k ? best_d[k - 1] * best_d[k - 1] * (1.0 + 1e-9) : INFINITY;
                    double sum = 0.0;
                    Py_ssize_t j = 0;
                    for (; j < n && !(sum > bound); ++j) {
                        double e = q[j] - x[j];
                        if (periodic[j]) e = wrap_near(e);
                        sum += e * e;
                    }
                    if (j < n) continue;
                    double d = sqrt(sum);
                    Py_ssize_t at = found;
                    while (at > 0 && best_d[at - 1] > d) --at; /* rows come in order */
                    if (at >= k) continue;
                    Py_ssize_t last = found < k ? found : k - 1;
                    for (Py_ssize_t m = last; m > at; --m)
                        best_d[m] = best_d[m - 1], best[m] = best[m - 1];
                    best_d[at] = d, best[at] = i;
                    if (found < k) ++found;
                }
                break;
            }
        }
        while (found > 0 && !(best_d[found - 1] <= reach)) --found; /* only those within */
        for (Py_ssize_t m = found; m < k; ++m) best[m] = -1;
    }
}

/* seeds.py's greedy spread: in order, each configuration not within `spacing_rad` of a
   seed already chosen (the torus metric: every joint a circle) becomes one; the rows
   chosen, in order, and their count. */
static Py_ssize_t spread_seeds_rows(const double *q, Py_ssize_t M, Py_ssize_t n,
                                    double spacing_rad, long long *chosen) {
    double r2 = spacing_rad * spacing_rad;
    Py_ssize_t count = 0;
    for (Py_ssize_t i = 0; i < M; ++i) {
        const double *x = q + i * n;
        int covered = 0;
        for (Py_ssize_t c = 0; c < count && !covered; ++c) {
            const double *y = q + chosen[c] * n;
            double sum = 0.0;
            for (Py_ssize_t j = 0; j < n && !(sum > r2); ++j) {
                double d = wrap_near(x[j] - y[j]);
                sum += d * d;
            }
            covered = sum <= r2;
        }
        if (!covered) chosen[count++] = i;
    }
    return count;
}

/* roadmap.py's links between components, in the KD-tree's box coordinates (a dimension
   with a finite `box` width is periodic with it, as cKDTree's boxsize is). */
static double box_distance2(const double *a, const double *b, const double *box, Py_ssize_t n) {
    double sum = 0.0;
    for (Py_ssize_t j = 0; j < n; ++j) {
        double d = a[j] - b[j];
        if (isfinite(box[j])) {
            double half = 0.5 * box[j];
            if (d > half) d -= box[j];
            else if (d < -half) d += box[j];
        }
        sum += d * d;
    }
    return sum;
}

/* For each row x in [x0, x1) and each set m (the nodes of one component of several), the
   nearest node y of the set to x within `radius` (strictly), when x is not in it:
   best[x - x0, m] its row (-1 for none), distance[x - x0, m] its distance; the lower row
   among equally near.
   `grouped` holds the sets' nodes' coordinates set after set (rows `member`, ascending
   within a set), set m at [start[m], start[m + 1]). */
static void nearest_of_sets_rows(const double *points, Py_ssize_t n, const double *box,
                                 const long long *set_of, const double *grouped,
                                 const long long *member, const long long *start, Py_ssize_t M,
                                 double radius, Py_ssize_t x0, Py_ssize_t x1, long long *best,
                                 double *distance) {
    int periodic = 0;
    for (Py_ssize_t j = 0; j < n; ++j) periodic |= isfinite(box[j]) != 0;
    for (Py_ssize_t x = x0; x < x1; ++x) {
        const double *p = points + x * n;
        for (Py_ssize_t m = 0; m < M; ++m) {
            long long found = -1;
            double least = INFINITY;
            if (m != set_of[x]) {
                for (long long t = start[m]; t < start[m + 1]; ++t) {
                    const double *o = grouped + t * n;
                    double sum = 0.0;
                    if (periodic) {
                        sum = box_distance2(p, o, box, n);
                    } else {
                        for (Py_ssize_t j = 0; j < n; ++j) {
                            double e = p[j] - o[j];
                            sum += e * e;
                        }
                    }
                    if (sum < least) least = sum, found = t;
                }
            }
            least = sqrt(least);
            int near = found >= 0 && least < radius;
            best[(x - x0) * M + m] = near ? member[found] : -1;
            distance[(x - x0) * M + m] = near ? least : INFINITY;
        }
    }
}

/* Every pair (rows[i], y), y != rows[i], within `radius` (strictly): counted when `fill` is
   0, else written to (i_out, y_out, length) in order of i then y; the count. */
static Py_ssize_t links_within_rows(const double *points, Py_ssize_t N, Py_ssize_t n,
                                    const double *box, const long long *rows, Py_ssize_t R,
                                    double radius, int fill, long long *i_out, long long *y_out,
                                    double *length) {
    Py_ssize_t count = 0;
    for (Py_ssize_t i = 0; i < R; ++i) {
        const double *p = points + rows[i] * n;
        for (Py_ssize_t y = 0; y < N; ++y) {
            if (y == rows[i]) continue;
            double d = sqrt(box_distance2(p, points + y * n, box, n));
            if (!(d < radius)) continue;
            if (fill) i_out[count] = i, y_out[count] = y, length[count] = d;
            ++count;
        }
    }
    return count;
}

/* roadmap.py's components after new edges: the parts (labels in [0, L), one per node) merged
   along the edges a-b between parts, renumbered 0, 1, ... in the order of their lowest
   node. Union-find over the parts; `parent`, `number`: L each. */
static long long find_root(long long *parent, long long x) {
    while (parent[x] != x) parent[x] = parent[parent[x]], x = parent[x];
    return x;
}

static void merge_labels_rows(const long long *labels, Py_ssize_t N, Py_ssize_t L,
                              const long long *a, const long long *b, Py_ssize_t E,
                              long long *out, long long *parent, long long *number) {
    for (Py_ssize_t k = 0; k < L; ++k) parent[k] = k, number[k] = -1;
    for (Py_ssize_t e = 0; e < E; ++e) {
        long long x = find_root(parent, a[e]), y = find_root(parent, b[e]);
        if (x != y) parent[x > y ? x : y] = x < y ? x : y;
    }
    long long next = 0;
    for (Py_ssize_t i = 0; i < N; ++i) {
        long long r = find_root(parent, labels[i]);
        if (number[r] < 0) number[r] = next++;
        out[i] = number[r];
    }
}

/* ---------------------------------------------------------------- Python entry points */

static PyObject *py_chain(PyObject *self, PyObject *args) {
    Py_buffer fixed, tip, q, position, rotation, jacobian;
    Py_ssize_t n, batch;
    if (!PyArg_ParseTuple(args, "y*y*y*nnw*w*w*", &fixed, &tip, &q, &n, &batch, &position,
                          &rotation, &jacobian))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    chain_rows(fixed.buf, tip.buf, n, q.buf, batch, position.buf, rotation.buf, jacobian.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&fixed), PyBuffer_Release(&tip), PyBuffer_Release(&q);
    PyBuffer_Release(&position), PyBuffer_Release(&rotation), PyBuffer_Release(&jacobian);
    Py_RETURN_NONE;
}

static PyObject *py_rotation_error(PyObject *self, PyObject *args) {
    Py_buffer target, rotation, error;
    Py_ssize_t batch;
    if (!PyArg_ParseTuple(args, "y*y*nw*", &target, &rotation, &batch, &error)) return NULL;
    Py_BEGIN_ALLOW_THREADS
    rotation_error_rows(target.buf, rotation.buf, batch, error.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&target), PyBuffer_Release(&rotation), PyBuffer_Release(&error);
    Py_RETURN_NONE;
}

static PyObject *py_dls_step(PyObject *self, PyObject *args) {
    Py_buffer jacobian, error, step, singular;
    Py_ssize_t batch, m, n;
    double damping;
    if (!PyArg_ParseTuple(args, "y*y*nnndw*w*", &jacobian, &error, &batch, &m, &n, &damping,
                          &step, &singular))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    dls_rows(jacobian.buf, error.buf, batch, m, n, damping, step.buf, singular.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&jacobian), PyBuffer_Release(&error);
    PyBuffer_Release(&step), PyBuffer_Release(&singular);
    Py_RETURN_NONE;
}

static PyObject *py_frames(PyObject *self, PyObject *args) {
    Py_buffer origin, axis, q, frames;
    Py_ssize_t n, batch;
    if (!PyArg_ParseTuple(args, "y*y*y*nnw*", &origin, &axis, &q, &n, &batch, &frames)) return NULL;
    Py_BEGIN_ALLOW_THREADS
    frame_rows(origin.buf, axis.buf, n, q.buf, batch, frames.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&origin), PyBuffer_Release(&axis), PyBuffer_Release(&q), PyBuffer_Release(&frames);
    Py_RETURN_NONE;
}

static PyObject *py_self_clearance(PyObject *self, PyObject *args) {
    Py_buffer rotation, origin, centre, radius, own, bound, bound_radius, pair_a, pair_b;
    Py_buffer clearance, scratch;
    Py_ssize_t batch, K, S, P;
    if (!PyArg_ParseTuple(args, "y*y*nnny*y*y*y*y*y*y*nw*w*", &rotation, &origin, &batch, &K, &S,
                          &centre, &radius, &own, &bound, &bound_radius, &pair_a, &pair_b, &P,
                          &clearance, &scratch))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    self_clearance_rows(rotation.buf, origin.buf, batch, K, S, centre.buf, radius.buf, own.buf,
                        bound.buf, bound_radius.buf, pair_a.buf, pair_b.buf, P, clearance.buf,
                        scratch.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&rotation, &origin, &centre, &radius, &own, &bound, &bound_radius,
                        &pair_a, &pair_b, &clearance, &scratch};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_bordered_solve(PyObject *self, PyObject *args) {
    Py_buffer jacobian, border, rhs, x, scratch;
    Py_ssize_t batch, n;
    if (!PyArg_ParseTuple(args, "y*y*y*nnw*w*", &jacobian, &border, &rhs, &batch, &n, &x, &scratch))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    bordered_rows(jacobian.buf, border.buf, rhs.buf, batch, n, x.buf, scratch.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&jacobian), PyBuffer_Release(&border), PyBuffer_Release(&rhs);
    PyBuffer_Release(&x), PyBuffer_Release(&scratch);
    Py_RETURN_NONE;
}

static PyObject *py_task_residual(PyObject *self, PyObject *args) {
    Py_buffer fixed, tip, q, rows, target_position, target_rotation, error, jacobian;
    Py_ssize_t n, batch, m, m_position;
    int orientation;
    if (!PyArg_ParseTuple(args, "y*y*y*nny*nny*y*pw*w*", &fixed, &tip, &q, &n, &batch, &rows, &m,
                          &m_position, &target_position, &target_rotation, &orientation, &error,
                          &jacobian))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    residual_rows(fixed.buf, tip.buf, n, q.buf, batch, rows.buf, m, m_position,
                  target_position.buf, orientation ? target_rotation.buf : NULL, error.buf,
                  jacobian.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&fixed, &tip, &q, &rows, &target_position, &target_rotation, &error,
                        &jacobian};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

/* newton_rows' arguments, for a part of its rows (split_rows). */
typedef struct {
    const double *fixed, *tip, *target_position, *target_rotation, *tangent;
    const long long *rows;
    const unsigned char *locked, *fresh;
    double *q, *error, *jacobian, *scratch;
    Py_ssize_t n, m, m_position, iterations, scratch_size;
    double until, damping;
} NewtonRows;

static void newton_part(void *context, Py_ssize_t start, Py_ssize_t stop, int on_helper) {
    const NewtonRows *a = context;
    Py_ssize_t n = a->n, m = a->m;
    /* The helper's part works in the second half of the scratch. */
    double *scratch = a->scratch + (on_helper ? a->scratch_size : 0);
    newton_rows(a->fixed, a->tip, n, a->rows, m, a->m_position, a->target_position,
                a->target_rotation, a->q + start * n, a->error + start * m,
                a->jacobian + start * m * n, stop - start, a->iterations, a->until, a->damping,
                a->locked != NULL ? a->locked + start * n : NULL,
                a->tangent != NULL ? a->tangent + start * n : NULL,
                a->fresh != NULL ? a->fresh + start : NULL, scratch);
}

static PyObject *py_newton(PyObject *self, PyObject *args) {
    Py_buffer fixed, tip, rows, target_position, target_rotation, q, error, jacobian, locked,
        tangent, fresh, scratch;
    Py_ssize_t n, m, m_position, batch, iterations, first;
    int orientation, has_locked, has_tangent, has_fresh;
    double until, damping;
    if (!PyArg_ParseTuple(args, "y*y*ny*nny*y*pw*w*w*nnddy*py*py*pw*n", &fixed, &tip, &n, &rows,
                          &m, &m_position, &target_position, &target_rotation, &orientation, &q,
                          &error, &jacobian, &batch, &iterations, &until, &damping, &locked,
                          &has_locked, &tangent, &has_tangent, &fresh, &has_fresh, &scratch,
                          &first))
        return NULL;
    NewtonRows a = {
        .fixed = fixed.buf, .tip = tip.buf, .target_position = target_position.buf,
        .target_rotation = orientation ? target_rotation.buf : NULL,
        .tangent = has_tangent ? tangent.buf : NULL, .rows = rows.buf,
        .locked = has_locked ? locked.buf : NULL, .fresh = has_fresh ? fresh.buf : NULL,
        .q = q.buf, .error = error.buf, .jacobian = jacobian.buf, .scratch = scratch.buf,
        .n = n, .m = m, .m_position = m_position, .iterations = iterations,
        .scratch_size = (m + 3) * n, .until = until, .damping = damping};
    Py_BEGIN_ALLOW_THREADS
    split_rows(newton_part, &a, batch, first);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&fixed,  &tip,     &rows,   &target_position, &target_rotation,
                        &q,      &error,   &jacobian, &locked,        &tangent,
                        &fresh,  &scratch};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_walk(PyObject *self, PyObject *args) {
    Py_buffer fixed, tip, rows, target_position, target_rotation, q, tangent, jacobian, step,
        alive, partner, out_q, out_error, out_jacobian, out_tangent, out_front;
    Walk w;
    int orientation;
    Py_ssize_t max_steps, capacity, count, steps = 0;
    double expires_at_s;
    if (!PyArg_ParseTuple(args, "y*y*ny*nny*y*pnw*w*w*w*w*w*dddddnndw*w*w*w*w*nn", &fixed, &tip,
                          &w.n, &rows, &w.m, &w.m_position, &target_position, &target_rotation,
                          &orientation, &w.fronts, &q, &tangent, &jacobian, &step, &alive,
                          &partner, &w.h, &w.damping, &w.meet_factor, &w.twin_sigma,
                          &w.twin_offset, &w.corrector_iterations, &max_steps, &expires_at_s,
                          &out_q, &out_error, &out_jacobian, &out_tangent, &out_front, &capacity,
                          &count))
        return NULL;
    w.fixed = fixed.buf, w.tip = tip.buf, w.rows = rows.buf;
    w.target_position = target_position.buf;
    w.target_rotation = orientation ? target_rotation.buf : NULL;
    w.q = q.buf, w.tangent = tangent.buf, w.jacobian = jacobian.buf, w.step = step.buf;
    w.alive = alive.buf, w.partner = partner.buf;
    int status;
    Py_BEGIN_ALLOW_THREADS
    status = walk_steps(&w, max_steps, expires_at_s, out_q.buf, out_error.buf, out_jacobian.buf,
                        out_tangent.buf, out_front.buf, capacity, &count, &steps);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&fixed, &tip, &rows, &target_position, &target_rotation, &q, &tangent,
                        &jacobian, &step, &alive, &partner, &out_q, &out_error, &out_jacobian,
                        &out_tangent, &out_front};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    if (status < 0) return PyErr_NoMemory();
    return Py_BuildValue("inn", status, count, steps);
}

static PyObject *py_smallest_singular_values(PyObject *self, PyObject *args) {
    Py_buffer jacobian, sigma, work;
    Py_ssize_t batch, m, n;
    if (!PyArg_ParseTuple(args, "y*nnnw*w*", &jacobian, &batch, &m, &n, &sigma, &work))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t b = 0; b < batch; ++b)
        ((double *)sigma.buf)[b] =
            smallest_singular_row((const double *)jacobian.buf + b * m * n, m, n, work.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&jacobian), PyBuffer_Release(&sigma), PyBuffer_Release(&work);
    Py_RETURN_NONE;
}

static PyObject *py_least_singular_value(PyObject *self, PyObject *args) {
    Py_buffer jacobian;
    Py_ssize_t batch, m, n;
    if (!PyArg_ParseTuple(args, "y*nnn", &jacobian, &batch, &m, &n)) return NULL;
    double least;
    Py_BEGIN_ALLOW_THREADS
    least = least_singular_value(jacobian.buf, batch, m, n);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&jacobian);
    if (least < 0.0) return PyErr_NoMemory();
    return PyFloat_FromDouble(least);
}

/* self_clearance_at_rows' arguments, for a part of its rows (split_rows). */
typedef struct {
    const double *origin, *axis, *q, *centre, *radius, *bound, *bound_radius;
    const long long *frame, *own, *pair_a, *pair_b;
    double *clearance, *scratch;
    Py_ssize_t n, K, S, P, scratch_size;
} ClearanceRows;

static void self_clearance_part(void *context, Py_ssize_t start, Py_ssize_t stop,
                                int on_helper) {
    const ClearanceRows *a = context;
    double *scratch = a->scratch + (on_helper ? a->scratch_size : 0);
    self_clearance_at_rows(a->origin, a->axis, a->n, a->q + start * a->n, stop - start, a->frame,
                           a->K, a->S, a->centre, a->radius, a->own, a->bound, a->bound_radius,
                           a->pair_a, a->pair_b, a->P, a->clearance + start, scratch);
}

static PyObject *py_self_clearance_at(PyObject *self, PyObject *args) {
    Py_buffer origin, axis, q, frame, centre, radius, own, bound, bound_radius, pair_a, pair_b;
    Py_buffer clearance, scratch;
    Py_ssize_t n, batch, K, S, P, first;
    if (!PyArg_ParseTuple(args, "y*y*ny*ny*nny*y*y*y*y*y*y*nw*w*n", &origin, &axis, &n, &q,
                          &batch, &frame, &K, &S, &centre, &radius, &own, &bound, &bound_radius,
                          &pair_a, &pair_b, &P, &clearance, &scratch, &first))
        return NULL;
    ClearanceRows a = {
        .origin = origin.buf, .axis = axis.buf, .q = q.buf, .centre = centre.buf,
        .radius = radius.buf, .bound = bound.buf, .bound_radius = bound_radius.buf,
        .frame = frame.buf, .own = own.buf, .pair_a = pair_a.buf, .pair_b = pair_b.buf,
        .clearance = clearance.buf, .scratch = scratch.buf, .n = n, .K = K, .S = S, .P = P,
        .scratch_size = (n + 1) * 16 + K * 12 + K * S * 3 + K * 3 + 1};
    Py_BEGIN_ALLOW_THREADS
    split_rows(self_clearance_part, &a, batch, first);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&origin, &axis, &q, &frame, &centre, &radius, &own, &bound,
                        &bound_radius, &pair_a, &pair_b, &clearance, &scratch};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_hull_separation(PyObject *self, PyObject *args) {
    Py_buffer hulls, counts, hull_a, rotation_a, origin_a, hull_b, rotation_b, origin_b, x0, pad;
    Py_buffer measure, best;
    Py_ssize_t V, M;
    double margin;
    if (!PyArg_ParseTuple(args, "y*y*ny*y*y*y*y*y*y*y*dy*nw*", &hulls, &counts, &V, &hull_a,
                          &rotation_a, &origin_a, &hull_b, &rotation_b, &origin_b, &x0, &pad,
                          &margin, &measure, &M, &best))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    hull_separation_rows(hulls.buf, counts.buf, V, hull_a.buf, rotation_a.buf, origin_a.buf,
                         hull_b.buf, rotation_b.buf, origin_b.buf, x0.buf, pad.buf, margin,
                         measure.buf, M, best.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&hulls, &counts, &hull_a, &rotation_a, &origin_a, &hull_b,
                        &rotation_b, &origin_b, &x0, &pad, &measure, &best};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_obstacle_clearance(PyObject *self, PyObject *args) {
    Py_buffer centre, radius, own, bound, bound_radius, moving, hulls, hull_count, hull_pad;
    Py_buffer shape, dims, o_rotation, o_position, reach, pad, rotation, origin, within;
    Py_buffer clearance, scratch;
    Py_ssize_t K, S, M, V, O, batch;
    int refined;
    double margin;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*nnnny*y*y*y*y*y*ny*y*npdy*w*w*", &centre,
                          &radius, &own, &bound, &bound_radius, &moving, &hulls, &hull_count,
                          &hull_pad, &K, &S, &M, &V, &shape, &dims, &o_rotation, &o_position,
                          &reach, &pad, &O, &rotation, &origin, &batch, &refined, &margin,
                          &within, &clearance, &scratch))
        return NULL;
    Bodies b = {.centre = centre.buf, .radius = radius.buf, .bound = bound.buf,
                .bound_radius = bound_radius.buf, .hulls = hulls.buf, .hull_pad = hull_pad.buf,
                .own = own.buf, .moving = moving.buf, .hull_count = hull_count.buf, .K = K,
                .S = S, .M = M, .V = V};
    Obstacles o = {.shape = shape.buf, .dims = dims.buf, .rotation = o_rotation.buf,
                   .position = o_position.buf, .reach = reach.buf, .pad = pad.buf, .count = O};
    Py_BEGIN_ALLOW_THREADS
    obstacle_clearance_rows(&b, &o, rotation.buf, origin.buf, batch, refined, margin, within.buf,
                            clearance.buf, scratch.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&centre, &radius, &own, &bound, &bound_radius, &moving, &hulls,
                        &hull_count, &hull_pad, &shape, &dims, &o_rotation, &o_position, &reach,
                        &pad, &rotation, &origin, &within, &clearance, &scratch};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

/* steering.py's steer for one walk from q (updated in place to where it ends, unwrapped)
 * toward goal: 1 arrived, 0 not, -1 the deadline passed. p->delta is the step length;
 * p->iterations Newton steps per projected step, stopping once within tolerance. */
static int steer_one(const Planner *p, Py_ssize_t stall_steps, double min_progress,
                     const double *goal, double *q, double *work) {
    Py_ssize_t n = p->n, m = p->m;
    double *J = work, *e = J + m * n, *q_new = e + m, *e_new = q_new + n, *J_new = e_new + m;
    double *d = J_new + m * n, *g = d + n, *gram = g + n, *y = gram + m * m, *Jf = y + m;
    double *start = Jf + m * n, *scratch = start + n, *e2 = scratch + (m + 1) * n + 2 * n;
    double *J2 = e2 + m, *frames = J2 + m * n;
    unsigned char on_limit[64];
    residual_rows(p->fixed, p->tip, n, q, 1, p->rows, m, p->m_position, p->target_position,
                  p->target_rotation, e, J);
    double best = distance_of(goal, q, n);
    Py_ssize_t since_best = 0;
    for (Py_ssize_t step = 0; step < p->max_steps; ++step) {
        if (distance_of(goal, q, n) <= p->delta) return 1;
        if (p->expires_at_s < INFINITY && monotonic_s() > p->expires_at_s) return -1;
        /* The direction to the goal projected onto J's null space, the joints on a limit
         * that it pushes further out held (tangent_direction). */
        for (Py_ssize_t k = 0; k < n; ++k) {
            double wanted = goal[k] - q[k];
            int held = !p->periodic[k] && ((q[k] <= p->lower[k] && wanted < 0) ||
                                           (q[k] >= p->upper[k] && wanted > 0));
            g[k] = held ? 0.0 : wanted;
            for (Py_ssize_t i = 0; i < m; ++i) Jf[i * n + k] = held ? 0.0 : J[i * n + k];
        }
        for (Py_ssize_t i = 0; i < m; ++i) {
            double rhs = 0.0;
            for (Py_ssize_t k = 0; k < n; ++k) rhs += Jf[i * n + k] * g[k];
            y[i] = rhs;
            for (Py_ssize_t l = 0; l < m; ++l) {
                double sum = 0.0;
                for (Py_ssize_t k = 0; k < n; ++k) sum += Jf[i * n + k] * Jf[l * n + k];
                gram[i * m + l] = sum + (i == l ? 1e-9 : 0.0);
            }
        }
        if (!gauss_solve(gram, y, m))
            for (Py_ssize_t i = 0; i < m; ++i) y[i] = NAN;
        double length = 0.0;
        for (Py_ssize_t k = 0; k < n; ++k) {
            double sum = 0.0;
            for (Py_ssize_t i = 0; i < m; ++i) sum += Jf[i * n + k] * y[i];
            d[k] = g[k] - sum;
            length += d[k] * d[k];
        }
        length = sqrt(length);
        int moving = length > 1e-9;
        double scale = (p->delta < length ? p->delta : length) / (length > 1e-300 ? length : 1e-300);
        for (Py_ssize_t k = 0; k < n; ++k) {
            double x = q[k] + d[k] * scale;
            if (!p->periodic[k]) x = x < p->lower[k] ? p->lower[k] : (x > p->upper[k] ? p->upper[k] : x);
            q_new[k] = x;
            on_limit[k] = !p->periodic[k] && (x <= p->lower[k] || x >= p->upper[k]);
        }
        residual_rows(p->fixed, p->tip, n, q_new, 1, p->rows, m, p->m_position,
                      p->target_position, p->target_rotation, e_new, J_new);
        newton_rows(p->fixed, p->tip, n, p->rows, m, p->m_position, p->target_position,
                    p->target_rotation, q_new, e_new, J_new, 1, p->iterations, p->tolerance,
                    p->damping, on_limit, NULL, NULL, scratch);
        double error = 0.0;
        for (Py_ssize_t k = 0; k < m; ++k) error += e_new[k] * e_new[k];
        int ok = sqrt(error) <= p->tolerance && distance_of(q_new, q, n) <= p->stretch * p->delta &&
                 moving;
        for (Py_ssize_t k = 0; k < n && ok; ++k)
            ok = p->periodic[k] || (q_new[k] >= p->lower[k] && q_new[k] <= p->upper[k]);
        if (ok && p->sets) ok = crossings_on_fibre_row(p, q, q_new, start, e2, J2, scratch);
        if (ok) ok = inside_between(p, q, q_new, e2, J2, scratch);
        if (ok && (p->check_self || p->obstacles.count)) ok = free_row(p, q_new, frames);
        if (!ok) return 0;
        memcpy(q, q_new, sizeof(double) * (size_t)n);
        memcpy(J, J_new, sizeof(double) * (size_t)(m * n));
        double now = distance_of(goal, q, n);
        if (now < best - min_progress) {
            best = now;
            since_best = 0;
        } else if (++since_best >= stall_steps) {
            return 0;
        }
    }
    return distance_of(goal, q, n) <= p->delta;
}

/* The buffers every walk takes (native.py's CompiledSpace.arguments), in that order. */
enum { SPACE_BUFFERS = 30 };

/* numbers: damping, step, stretch, tolerance, margin, expires_at_s, limit_check (and for
 * the steer, min_progress); sizes: n, m, m_position, orientation, sets, check_self, K, S, P, V,
 * iterations, (extra iterations or stall steps), set_iterations, max_steps. */
static Planner planner_of(const double *number, const long long *size, Py_buffer *space) {
    Planner p = {
        .fixed = space[0].buf, .tip = space[1].buf, .rows = space[2].buf,
        .target_position = space[3].buf, .target_rotation = size[3] ? space[4].buf : NULL,
        .lower = space[5].buf, .upper = space[6].buf, .periodic = space[7].buf,
        .set_joint = space[8].buf, .set_angle = space[9].buf, .joint_origin = space[10].buf,
        .joint_axis = space[11].buf, .frame = space[12].buf, .centre = space[13].buf,
        .radius = space[14].buf, .own = space[15].buf, .bound = space[16].buf,
        .bound_radius = space[17].buf, .pair_a = space[18].buf, .pair_b = space[19].buf,
        .hulls = space[20].buf, .hull_count = space[21].buf, .hull_pad = space[22].buf,
        .n = size[0], .m = size[1], .m_position = size[2], .sets = size[4],
        .check_self = (int)size[5], .K = size[6], .S = size[7], .P = size[8], .V = size[9],
        .iterations = size[10], .extra_iterations = size[11], .set_iterations = size[12],
        .max_steps = size[13], .damping = number[0], .delta = number[1], .stretch = number[2],
        .tolerance = number[3], .margin = number[4], .expires_at_s = number[5],
        .limit_check = number[6],
    };
    p.scene_bodies = (Bodies){.centre = p.centre, .radius = p.radius, .bound = p.bound,
                              .bound_radius = p.bound_radius, .hulls = p.hulls,
                              .hull_pad = p.hull_pad, .own = p.own, .moving = space[23].buf,
                              .hull_count = p.hull_count, .K = p.K, .S = p.S,
                              .M = space[23].len / (Py_ssize_t)sizeof(long long), .V = p.V};
    p.obstacles = (Obstacles){.shape = space[24].buf, .dims = space[25].buf,
                              .rotation = space[26].buf, .position = space[27].buf,
                              .reach = space[28].buf, .pad = space[29].buf,
                              .count = space[24].len / (Py_ssize_t)sizeof(long long)};
    return p;
}

/* Parses (numbers, sizes, the space's buffers, then `more` buffers: the first `read` of
 * them read-only) into `buffers`; 0 on failure (the exception set). */
static int parse_walk(PyObject *args, Py_buffer *buffers, Py_ssize_t read, Py_ssize_t more) {
    Py_ssize_t total = 2 + SPACE_BUFFERS + more;
    if (PyTuple_GET_SIZE(args) != total) {
        PyErr_Format(PyExc_TypeError, "expected %zd arguments, got %zd", total,
                     PyTuple_GET_SIZE(args));
        return 0;
    }
    for (Py_ssize_t i = 0; i < total; ++i) {
        int writable = i >= 2 + SPACE_BUFFERS + read;
        if (PyObject_GetBuffer(PyTuple_GET_ITEM(args, i), &buffers[i],
                               writable ? PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS : PyBUF_C_CONTIGUOUS) < 0) {
            for (Py_ssize_t k = 0; k < i; ++k) PyBuffer_Release(&buffers[k]);
            return 0;
        }
    }
    return 1;
}

/* A projected or steered walk's edges, for a part of them (split_rows): the planner, the
 * call's buffers, the scratch of one part (the helper's part works past it) and each
 * part's status (1 when the deadline passed). */
typedef struct {
    const Planner *p;
    Py_buffer *io;
    const long long *size;
    const double *number;
    Py_ssize_t record, scratch_size;
    int status[2];
} Walks;

static void projected_walk_part(void *context, Py_ssize_t start, Py_ssize_t stop, int on_helper) {
    Walks *w = context;
    const Planner *p = w->p;
    Py_buffer *io = w->io; /* q_from, goal, chord, reached, points, counts, work */
    Py_ssize_t n = p->n;
    double *work = (double *)io[6].buf + (on_helper ? w->scratch_size : 0);
    int status = 0;
    for (Py_ssize_t edge = start; edge < stop && status == 0; ++edge) {
        Py_ssize_t count = 0;
        int result = walk_edge(p, (const double *)io[0].buf + edge * n,
                               (const double *)io[1].buf + edge * n, ((const double *)io[2].buf)[edge],
                               w->record ? (double *)io[4].buf + edge * p->max_steps * n : NULL,
                               &count, work);
        if (result < 0) status = 1;
        ((unsigned char *)io[3].buf)[edge] = result == 1;
        ((long long *)io[5].buf)[edge] = count;
    }
    w->status[on_helper] = status;
}

static void steer_walk_part(void *context, Py_ssize_t start, Py_ssize_t stop, int on_helper) {
    Walks *w = context;
    const Planner *p = w->p;
    Py_buffer *io = w->io; /* goal, q, arrived, work */
    Py_ssize_t n = p->n;
    double *work = (double *)io[3].buf + (on_helper ? w->scratch_size : 0);
    int status = 0;
    for (Py_ssize_t k = start; k < stop && status == 0; ++k) {
        int result = steer_one(p, w->size[11], w->number[7], (const double *)io[0].buf + k * n,
                               (double *)io[1].buf + k * n, work);
        if (result < 0) status = 1;
        ((unsigned char *)io[2].buf)[k] = result == 1;
    }
    w->status[on_helper] = status;
}

/* The walks of a call, parsed by parse_walk (`read` inputs, `more` buffers after the
 * space's) and split by `part`: size[14] walks, size[15] record, size[16] the walks before
 * it on the row helper; 1 when the deadline passed in either part. */
static PyObject *walks_call(PyObject *args, Py_ssize_t read, Py_ssize_t more, RowPart part) {
    Py_buffer b[2 + SPACE_BUFFERS + 7];
    if (!parse_walk(args, b, read, more)) return NULL;
    const long long *size = b[1].buf;
    Planner p = planner_of(b[0].buf, size, b + 2);
    Walks w = {.p = &p, .io = b + 2 + SPACE_BUFFERS, .size = size, .number = b[0].buf,
               .record = size[15], .scratch_size = planner_scratch(&p)};
    Py_BEGIN_ALLOW_THREADS
    split_rows(part, &w, size[14], size[16]);
    Py_END_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < 2 + SPACE_BUFFERS + more; ++i) PyBuffer_Release(&b[i]);
    return PyLong_FromLong(w.status[0] || w.status[1]);
}

/* io: q_from, goal, chord (read); reached, points, counts, work. */
static PyObject *py_projected_walk(PyObject *self, PyObject *args) {
    return walks_call(args, 3, 7, projected_walk_part);
}

/* io: goal (read); q, arrived, work. */
static PyObject *py_steer_walk(PyObject *self, PyObject *args) {
    return walks_call(args, 1, 4, steer_walk_part);
}

static PyObject *py_refined_self_clearance(PyObject *self, PyObject *args) {
    Py_buffer b[2 + SPACE_BUFFERS + 4];
    if (!parse_walk(args, b, 1, 4)) return NULL;
    const long long *size = b[1].buf;
    Planner p = planner_of(b[0].buf, size, b + 2);
    Py_buffer *io = b + 2 + SPACE_BUFFERS; /* q, clearance, candidates, work */
    Py_ssize_t rows = size[14], n = p.n;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < rows; ++r)
        ((double *)io[1].buf)[r] = refined_self_clearance_row(
            &p, (const double *)io[0].buf + r * n, io[2].buf, io[3].buf);
    Py_END_ALLOW_THREADS
    for (size_t i = 0; i < sizeof b / sizeof *b; ++i) PyBuffer_Release(&b[i]);
    Py_RETURN_NONE;
}

static PyObject *py_walk_scratch(PyObject *self, PyObject *args) {
    Py_ssize_t n, m, K, S, M = 0, O = 0;
    if (!PyArg_ParseTuple(args, "nnnn|nn", &n, &m, &K, &S, &M, &O)) return NULL;
    Planner p = {.n = n, .m = m, .K = K, .S = S};
    p.scene_bodies.M = M, p.obstacles.count = O;
    return PyLong_FromSsize_t(planner_scratch(&p));
}

static PyObject *py_nearest_segment(PyObject *self, PyObject *args) {
    Py_buffer q, points, before, after, nearest, periodic, distance, point;
    Py_ssize_t K, k, n;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*nnnw*w*", &q, &points, &before, &after, &nearest,
                          &periodic, &K, &k, &n, &distance, &point))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    nearest_segment_rows(q.buf, points.buf, before.buf, after.buf, nearest.buf, periodic.buf, K,
                         k, n, distance.buf, point.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&q, &points, &before, &after, &nearest, &periodic, &distance, &point};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_nearest_in_group(PyObject *self, PyObject *args) {
    Py_buffer points, start, queries, query_group, periodic, nearest;
    Py_ssize_t Q, n;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*nnw*", &points, &start, &queries, &query_group,
                          &periodic, &Q, &n, &nearest))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    nearest_in_group_rows(points.buf, start.buf, queries.buf, query_group.buf, periodic.buf, Q, n,
                          nearest.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&points, &start, &queries, &query_group, &periodic, &nearest};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_along(PyObject *self, PyObject *args) {
    Py_buffer tangent, direction, out;
    Py_ssize_t K, n;
    if (!PyArg_ParseTuple(args, "y*y*nnw*", &tangent, &direction, &K, &n, &out)) return NULL;
    Py_BEGIN_ALLOW_THREADS
    along_rows(tangent.buf, direction.buf, K, n, out.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&tangent), PyBuffer_Release(&direction), PyBuffer_Release(&out);
    Py_RETURN_NONE;
}

static PyObject *py_hermite(PyObject *self, PyObject *args) {
    Py_buffer p0, t0, p1, t1, s, point, direction;
    Py_ssize_t K, n;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*nnw*w*", &p0, &t0, &p1, &t1, &s, &K, &n, &point,
                          &direction))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    hermite_rows(p0.buf, t0.buf, p1.buf, t1.buf, s.buf, K, n, point.buf, direction.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&p0, &t0, &p1, &t1, &s, &point, &direction};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_settle_dense(PyObject *self, PyObject *args) {
    Py_buffer q, placed, low, lower, upper, periodic, fixed_rows, fixed_q, excluded, inside;
    Py_ssize_t D, n, F, E;
    double stray_rad;
    if (!PyArg_ParseTuple(args, "w*y*y*y*y*y*nndy*y*ny*nw*", &q, &placed, &low, &lower, &upper,
                          &periodic, &D, &n, &stray_rad, &fixed_rows, &fixed_q, &F, &excluded,
                          &E, &inside))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    settle_dense_rows(q.buf, placed.buf, low.buf, lower.buf, upper.buf, periodic.buf, D, n,
                      stray_rad, fixed_rows.buf, fixed_q.buf, F, excluded.buf, E, inside.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&q,         &placed,  &low,      &lower, &upper,
                        &periodic,  &fixed_rows, &fixed_q, &excluded, &inside};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_chain_fronts(PyObject *self, PyObject *args) {
    Py_buffer q, by_front, partner, front_first, front_rows, visited, overlap, ahead, behind,
        out_rows, first, closed;
    Py_ssize_t T, n, S, C;
    if (!PyArg_ParseTuple(args, "y*nnny*y*w*w*w*w*w*w*w*w*w*", &q, &T, &n, &S, &by_front, &partner,
                          &front_first, &front_rows, &visited, &overlap, &ahead, &behind,
                          &out_rows, &first, &closed))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    C = chain_fronts_of(q.buf, T, n, S, by_front.buf, partner.buf, front_first.buf,
                        front_rows.buf, visited.buf, overlap.buf, ahead.buf, behind.buf,
                        out_rows.buf, first.buf, closed.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&q,       &by_front, &partner, &front_first, &front_rows, &visited,
                        &overlap, &ahead,    &behind,  &out_rows,    &first,      &closed};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    return PyLong_FromSsize_t(C);
}

static PyObject *py_unwrap_curves(PyObject *self, PyObject *args) {
    Py_buffer q, rows, first, out;
    Py_ssize_t C, n;
    if (!PyArg_ParseTuple(args, "y*y*y*nnw*", &q, &rows, &first, &C, &n, &out)) return NULL;
    Py_BEGIN_ALLOW_THREADS
    unwrap_curves_of(q.buf, rows.buf, first.buf, C, n, out.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&q);
    PyBuffer_Release(&rows);
    PyBuffer_Release(&first);
    PyBuffer_Release(&out);
    Py_RETURN_NONE;
}

static PyObject *py_cut_runs(PyObject *self, PyObject *args) {
    Py_buffer points, rows, first, closed, low, lower, upper, periodic, inside, out_points,
        out_rows, run_first, run_closed, exits, has_exit;
    Py_ssize_t C, n, R;
    if (!PyArg_ParseTuple(args, "y*y*y*y*nny*y*y*y*w*w*w*w*w*w*w*", &points, &rows, &first,
                          &closed, &C, &n, &low, &lower, &upper, &periodic, &inside,
                          &out_points, &out_rows, &run_first, &run_closed, &exits, &has_exit))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    R = cut_runs_of(points.buf, rows.buf, first.buf, closed.buf, C, n, low.buf, lower.buf,
                    upper.buf, periodic.buf, inside.buf, out_points.buf, out_rows.buf,
                    run_first.buf, run_closed.buf, exits.buf, has_exit.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&points,     &rows,     &first,     &closed,     &low,
                        &lower,      &upper,    &periodic,  &inside,     &out_points,
                        &out_rows,   &run_first, &run_closed, &exits,    &has_exit};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    return PyLong_FromSsize_t(R);
}

static PyObject *py_dense_nodes(PyObject *self, PyObject *args) {
    Py_buffer points, rows, first, closed, limit_of, found, node_q, node_row, node_run, node_kind,
        inner;
    Py_ssize_t R, n, T, D;
    double spacing_rad;
    if (!PyArg_ParseTuple(args, "y*y*y*y*nny*y*ndw*w*w*w*w*", &points, &rows, &first, &closed, &R,
                          &n, &limit_of, &found, &T, &spacing_rad, &node_q, &node_row,
                          &node_run, &node_kind, &inner))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    D = dense_nodes_of(points.buf, rows.buf, first.buf, closed.buf, R, n, limit_of.buf, found.buf,
                       T, spacing_rad, node_q.buf, node_row.buf, node_run.buf, node_kind.buf,
                       inner.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&points,   &rows,     &first,    &closed,    &limit_of, &found,
                        &node_q,   &node_row, &node_run, &node_kind, &inner};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    return PyLong_FromSsize_t(D);
}

static PyObject *py_dense_layout(PyObject *self, PyObject *args) {
    Py_buffer node_q, node_row, node_run, inner, tangent, found_tangent, placed, dense_run, offset,
        between, guess, direction;
    Py_ssize_t N, n, T;
    if (!PyArg_ParseTuple(args, "y*y*y*y*nny*y*nw*w*w*w*w*w*", &node_q, &node_row, &node_run,
                          &inner, &N, &n, &tangent, &found_tangent, &T, &placed, &dense_run,
                          &offset, &between, &guess, &direction))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    dense_layout_of(node_q.buf, node_row.buf, node_run.buf, inner.buf, N, n, tangent.buf,
                    found_tangent.buf, T, placed.buf, dense_run.buf, offset.buf, between.buf,
                    guess.buf, direction.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&node_q,    &node_row, &node_run, &inner,   &tangent, &found_tangent,
                        &placed,    &dense_run, &offset,  &between, &guess,   &direction};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_dense_finish(PyObject *self, PyObject *args) {
    Py_buffer placed, moved_q, moved_error, moved_rows, offset, node_row, node_kind,
        evaluated_error, found_error, found_window, dense_run, low, lower, upper, periodic, q,
        error, fixed_rows, fixed_q, excluded, inside, q_out, error_out, run_count;
    Py_ssize_t D, n, m, M, N, T, R, count;
    double stray_rad;
    if (!PyArg_ParseTuple(args, "y*nnny*y*y*ny*y*y*ny*ny*y*y*ny*y*y*y*dw*w*w*w*w*w*w*w*w*",
                          &placed, &D, &n, &m, &moved_q, &moved_error, &moved_rows, &M, &offset,
                          &node_row, &node_kind, &N, &evaluated_error, &T, &found_error,
                          &found_window, &dense_run, &R, &low, &lower, &upper, &periodic,
                          &stray_rad, &q, &error, &fixed_rows, &fixed_q, &excluded, &inside,
                          &q_out, &error_out, &run_count))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    count = dense_finish_of(placed.buf, D, n, m, moved_q.buf, moved_error.buf, moved_rows.buf, M,
                            offset.buf, node_row.buf, node_kind.buf, N, evaluated_error.buf, T,
                            found_error.buf, found_window.buf, dense_run.buf, R, low.buf,
                            lower.buf, upper.buf, periodic.buf, stray_rad, q.buf, error.buf,
                            fixed_rows.buf, fixed_q.buf, excluded.buf, inside.buf, q_out.buf,
                            error_out.buf, run_count.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&placed,     &moved_q,     &moved_error, &moved_rows, &offset,
                        &node_row,   &node_kind,   &evaluated_error, &found_error,
                        &found_window, &dense_run, &low,        &lower,      &upper,
                        &periodic,   &q,           &error,      &fixed_rows, &fixed_q,
                        &excluded,   &inside,      &q_out,      &error_out,  &run_count};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    return PyLong_FromSsize_t(count);
}

static PyObject *py_closest_strands(PyObject *self, PyObject *args) {
    Py_buffer points, first, closed, periodic, work, curve_of, column;
    Py_ssize_t P, n, C;
    double within_rad, strand_arc, best = INFINITY;
    if (!PyArg_ParseTuple(args, "y*nny*ny*y*ddw*w*w*", &points, &P, &n, &first, &C, &closed,
                          &periodic, &within_rad, &strand_arc, &work, &curve_of, &column))
        return NULL;
    Gridded *order = PyMem_RawMalloc((size_t)(P > 0 ? P : 1) * sizeof *order);
    if (order != NULL) {
        Py_BEGIN_ALLOW_THREADS
        best = closest_strands(points.buf, P, n, first.buf, C, closed.buf, periodic.buf,
                               within_rad, strand_arc, work.buf, order, curve_of.buf, column.buf);
        Py_END_ALLOW_THREADS
        PyMem_RawFree(order);
    }
    Py_buffer *all[] = {&points, &first, &closed, &periodic, &work, &curve_of, &column};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    if (order == NULL) return PyErr_NoMemory();
    return PyFloat_FromDouble(best);
}

static PyObject *py_steps_near_limits(PyObject *self, PyObject *args) {
    Py_buffer start, delta, low, lower, upper, periodic, split;
    Py_ssize_t S, n;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*nnw*", &start, &delta, &low, &lower, &upper,
                          &periodic, &S, &n, &split))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    steps_near_limits_rows(start.buf, delta.buf, low.buf, lower.buf, upper.buf, periodic.buf, S, n,
                           split.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&start, &delta, &low, &lower, &upper, &periodic, &split};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_curve_steps(PyObject *self, PyObject *args) {
    Py_buffer q, tangent, points, rows, first, closed, loop, key, span, start, delta,
        start_tangent, end_tangent;
    Py_ssize_t n, L;
    if (!PyArg_ParseTuple(args, "y*y*ny*y*y*y*nw*w*w*w*w*w*w*", &q, &tangent, &n, &points, &rows,
                          &first, &closed, &L, &loop, &key, &span, &start, &delta, &start_tangent,
                          &end_tangent))
        return NULL;
    Py_ssize_t count;
    Py_BEGIN_ALLOW_THREADS
    count = curve_steps_of(q.buf, tangent.buf, n, points.buf, rows.buf, first.buf, closed.buf, L,
                           loop.buf, key.buf, span.buf, start.buf, delta.buf, start_tangent.buf,
                           end_tangent.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&q,    &tangent, &points, &rows,  &first,         &closed,     &loop,
                        &key,  &span,    &start,  &delta, &start_tangent, &end_tangent};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    return PyLong_FromSsize_t(count);
}

static PyObject *py_refine_round(PyObject *self, PyObject *args) {
    Py_buffer fixed, tip, rows, target_position, target_rotation, loop, key, span, start, delta,
        start_tangent, end_tangent, low, lower, upper, periodic, added_q, added_error,
        added_jacobian, added_tangent, added_loop, added_key, out_loop, out_key, out_span,
        out_start, out_delta, out_start_tangent, out_end_tangent, scratch;
    Py_ssize_t n, m, m_position, S, p, iterations;
    int orientation;
    double until, damping;
    if (!PyArg_ParseTuple(args, "y*y*ny*nny*y*pny*y*y*y*y*y*y*y*y*y*y*nnddw*w*w*w*w*w*w*w*w*w*w*w*w*w*",
                          &fixed, &tip, &n, &rows, &m, &m_position, &target_position,
                          &target_rotation, &orientation, &S, &loop, &key, &span, &start, &delta,
                          &start_tangent, &end_tangent, &low, &lower, &upper, &periodic, &p,
                          &iterations, &until, &damping, &added_q, &added_error, &added_jacobian,
                          &added_tangent, &added_loop, &added_key, &out_loop, &out_key, &out_span,
                          &out_start, &out_delta, &out_start_tangent, &out_end_tangent, &scratch))
        return NULL;
    Py_ssize_t counts[2] = {0, 0};
    Steps in = {loop.buf, key.buf, span.buf, start.buf, delta.buf, start_tangent.buf,
                end_tangent.buf};
    Steps out = {out_loop.buf, out_key.buf, out_span.buf, out_start.buf, out_delta.buf,
                 out_start_tangent.buf, out_end_tangent.buf};
    Py_BEGIN_ALLOW_THREADS
    refine_round_of(fixed.buf, tip.buf, n, rows.buf, m, m_position, target_position.buf,
                    orientation ? target_rotation.buf : NULL, S, in, low.buf, lower.buf, upper.buf,
                    periodic.buf, p, iterations, until, damping, added_q.buf, added_error.buf,
                    added_jacobian.buf, added_tangent.buf, added_loop.buf, added_key.buf, out,
                    counts, scratch.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&fixed,         &tip,           &rows,          &target_position,
                        &target_rotation, &loop,        &key,           &span,
                        &start,         &delta,         &start_tangent, &end_tangent,
                        &low,           &lower,         &upper,         &periodic,
                        &added_q,       &added_error,   &added_jacobian, &added_tangent,
                        &added_loop,    &added_key,     &out_loop,      &out_key,
                        &out_span,      &out_start,     &out_delta,     &out_start_tangent,
                        &out_end_tangent, &scratch};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    return Py_BuildValue("nn", counts[0], counts[1]);
}

static PyObject *py_limit_points(PyObject *self, PyObject *args) {
    Py_buffer fixed, tip, rows, target_position, target_rotation, a, b, low, lower, upper,
        periodic, q_window, q_unwrapped, error, jacobian, tangent, good, scratch;
    Py_ssize_t n, m, m_position, E, iterations;
    int orientation;
    double until, damping;
    if (!PyArg_ParseTuple(args, "y*y*ny*nny*y*pny*y*y*y*y*y*nddw*w*w*w*w*w*w*", &fixed, &tip, &n,
                          &rows, &m, &m_position, &target_position, &target_rotation,
                          &orientation, &E, &a, &b, &low, &lower, &upper, &periodic, &iterations,
                          &until, &damping, &q_window, &q_unwrapped, &error, &jacobian, &tangent,
                          &good, &scratch))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    limit_points_of(fixed.buf, tip.buf, n, rows.buf, m, m_position, target_position.buf,
                    orientation ? target_rotation.buf : NULL, E, a.buf, b.buf, low.buf, lower.buf,
                    upper.buf, periodic.buf, iterations, until, damping, q_window.buf,
                    q_unwrapped.buf, error.buf, jacobian.buf, tangent.buf, good.buf, scratch.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&fixed, &tip,      &rows,        &target_position, &target_rotation,
                        &a,     &b,        &low,         &lower,           &upper,
                        &periodic, &q_window, &q_unwrapped, &error,        &jacobian,
                        &tangent, &good,    &scratch};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static Axis axis_of(const double *points, Py_ssize_t P, const double *queries, Py_ssize_t K,
                    Py_ssize_t n, Py_ssize_t joint, int periodic) {
    Axis axis = {joint, periodic, -PI, TWO_PI, 1};
    if (periodic) return axis;
    double lo = INFINITY, hi = -INFINITY;
    for (Py_ssize_t i = 0; i < P + K; ++i) {
        double v = (i < P ? points + i * n : queries + (i - P) * n)[joint];
        if (v == v) lo = v < lo ? v : lo, hi = v > hi ? v : hi;
    }
    axis.low = isfinite(lo) ? lo : 0.0, axis.width = hi - lo;
    return axis;
}

static PyObject *py_nearest_points(PyObject *self, PyObject *args) {
    Py_buffer points, queries, periodic, out;
    Py_ssize_t P, K, n, k;
    double reach;
    if (!PyArg_ParseTuple(args, "y*ny*ny*nndw*", &points, &P, &queries, &K, &periodic, &n, &k,
                          &reach, &out))
        return NULL;
    const double *pts = points.buf, *qs = queries.buf;
    const unsigned char *per = periodic.buf;
    /* The two joints of widest spread over the points and queries (a periodic one: 2 pi). */
    Axis axes[2] = {{0, 0, 0.0, -1.0, 1}, {0, 0, 0.0, -1.0, 1}};
    for (Py_ssize_t j = 0; j < n; ++j) {
        Axis a = axis_of(pts, P, qs, K, n, j, per[j]);
        if (!(a.width <= axes[0].width)) axes[1] = axes[0], axes[0] = a;
        else if (!(a.width <= axes[1].width)) axes[1] = a;
    }
    if (axes[1].width < 0.0) axes[1] = axes[0];
    /* About 4 P cells: the points lie along curves, which cross few of them (a cell then
       holds a few consecutive points of a curve); at most P cells per axis. */
    long long most = P > 0 ? P : 1;
    double area = axes[0].width * axes[1].width, side = sqrt(area / (4.0 * (double)most));
    for (int a = 0; a < 2; ++a) {
        double width = axes[a].width;
        long long cells = side > 0.0 && isfinite(side) ? (long long)ceil(width / side) : 1;
        cells = cells < 1 ? 1 : (cells > most ? most : cells);
        axes[a].cells = cells;
        axes[a].width = width > 0.0 && isfinite(width) ? width / (double)cells : INFINITY;
    }
    long long cells = axes[0].cells * axes[1].cells;
    long long *scratch = PyMem_RawMalloc((size_t)(cells + 1 + 2 * most) * sizeof *scratch);
    if (scratch != NULL) {
        Py_BEGIN_ALLOW_THREADS
        nearest_points_rows(pts, P, qs, K, per, n, k, reach, out.buf, scratch, scratch + cells + 1,
                            scratch + cells + 1 + most, axes);
        Py_END_ALLOW_THREADS
        PyMem_RawFree(scratch);
    }
    PyBuffer_Release(&points), PyBuffer_Release(&queries), PyBuffer_Release(&periodic);
    PyBuffer_Release(&out);
    if (scratch == NULL) return PyErr_NoMemory();
    Py_RETURN_NONE;
}

static PyObject *py_spread_seeds(PyObject *self, PyObject *args) {
    Py_buffer q, chosen;
    Py_ssize_t M, n, count;
    double spacing_rad;
    if (!PyArg_ParseTuple(args, "y*nndw*", &q, &M, &n, &spacing_rad, &chosen)) return NULL;
    Py_BEGIN_ALLOW_THREADS
    count = spread_seeds_rows(q.buf, M, n, spacing_rad, chosen.buf);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&q), PyBuffer_Release(&chosen);
    return PyLong_FromSsize_t(count);
}

/* nearest_of_sets_rows' arguments, for a part of its rows (split_rows). */
typedef struct {
    const double *points, *box, *grouped;
    const long long *set_of, *member, *start;
    long long *best;
    double *distance, radius;
    Py_ssize_t n, M, x0;
} SetRows;

static void nearest_of_sets_part(void *context, Py_ssize_t start, Py_ssize_t stop, int on_helper) {
    const SetRows *a = context;
    (void)on_helper;
    nearest_of_sets_rows(a->points, a->n, a->box, a->set_of, a->grouped, a->member, a->start,
                         a->M, a->radius, a->x0 + start, a->x0 + stop, a->best + start * a->M,
                         a->distance + start * a->M);
}

static PyObject *py_nearest_of_sets(PyObject *self, PyObject *args) {
    Py_buffer points, box, set_of, grouped, member, start, best, distance;
    Py_ssize_t n, M, x0, x1, first;
    double radius;
    if (!PyArg_ParseTuple(args, "y*ny*y*y*y*y*ndnnw*w*n", &points, &n, &box, &set_of, &grouped,
                          &member, &start, &M, &radius, &x0, &x1, &best, &distance, &first))
        return NULL;
    SetRows a = {.points = points.buf, .box = box.buf, .grouped = grouped.buf,
                 .set_of = set_of.buf, .member = member.buf, .start = start.buf,
                 .best = best.buf, .distance = distance.buf, .radius = radius, .n = n, .M = M,
                 .x0 = x0};
    Py_BEGIN_ALLOW_THREADS
    split_rows(nearest_of_sets_part, &a, x1 - x0, first);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&points, &box, &set_of, &grouped, &member, &start, &best, &distance};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyObject *py_links_within(PyObject *self, PyObject *args) {
    Py_buffer points, box, rows, i_out, y_out, length;
    Py_ssize_t N, n, R, count;
    double radius;
    int fill;
    if (!PyArg_ParseTuple(args, "y*nny*y*ndpw*w*w*", &points, &N, &n, &box, &rows, &R, &radius,
                          &fill, &i_out, &y_out, &length))
        return NULL;
    Py_BEGIN_ALLOW_THREADS
    count = links_within_rows(points.buf, N, n, box.buf, rows.buf, R, radius, fill, i_out.buf,
                              y_out.buf, length.buf);
    Py_END_ALLOW_THREADS
    Py_buffer *all[] = {&points, &box, &rows, &i_out, &y_out, &length};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    return PyLong_FromSsize_t(count);
}

static PyObject *py_merge_labels(PyObject *self, PyObject *args) {
    Py_buffer labels, a, b, out, parent, number;
    Py_ssize_t N, L, E;
    if (!PyArg_ParseTuple(args, "y*nny*y*nw*w*w*", &labels, &N, &L, &a, &b, &E, &out, &parent,
                          &number))
        return NULL;
    merge_labels_rows(labels.buf, N, L, a.buf, b.buf, E, out.buf, parent.buf, number.buf);
    Py_buffer *all[] = {&labels, &a, &b, &out, &parent, &number};
    for (size_t i = 0; i < sizeof all / sizeof *all; ++i) PyBuffer_Release(all[i]);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"chain", py_chain, METH_VARARGS,
     "chain(fixed, tip, q, n, batch, position, rotation, jacobian): serial-chain FK and Jacobian."},
    {"rotation_error", py_rotation_error, METH_VARARGS,
     "rotation_error(target, rotation, batch, error): log(R* R^T) per row."},
    {"dls_step", py_dls_step, METH_VARARGS,
     "dls_step(jacobian, error, batch, m, n, damping, step, singular): one DLS step per row."},
    {"frames", py_frames, METH_VARARGS,
     "frames(origin, axis, q, n, batch, frames): every URDF joint frame of a serial chain."},
    {"self_clearance", py_self_clearance, METH_VARARGS,
     "self_clearance(rotation, origin, batch, K, S, centre, radius, own, bound, bound_radius, "
     "pair_a, pair_b, P, clearance, scratch): least sphere gap over the checked body pairs."},
    {"bordered_solve", py_bordered_solve, METH_VARARGS,
     "bordered_solve(jacobian, border, rhs, batch, n, x, scratch): [J; t^T] x = rhs per row."},
    {"task_residual", py_task_residual, METH_VARARGS,
     "task_residual(fixed, tip, q, n, batch, rows, m, m_position, target_position, "
     "target_rotation, orientation, error, jacobian): task error and Jacobian per row."},
    {"newton", py_newton, METH_VARARGS,
     "newton(fixed, tip, n, rows, m, m_position, target_position, target_rotation, orientation, "
     "q, error, jacobian, batch, iterations, until, damping, locked, has_locked, tangent, "
     "has_tangent, fresh, has_fresh, scratch, first): Newton steps onto the fibre per row, in "
     "place (a fresh row evaluated first); rows before `first` on the row helper."},
    {"walk", py_walk, METH_VARARGS,
     "walk(fixed, tip, n, rows, m, m_position, target_position, target_rotation, orientation, "
     "fronts, q, tangent, jacobian, step, alive, partner, h, damping, meet_factor, twin_sigma, "
     "twin_offset, corrector_iterations, max_steps, expires_at_s, out_q, out_error, "
     "out_jacobian, out_tangent, out_front, capacity, count) -> (status, count, steps): the "
     "trace's fronts walked in lockstep until they meet."},
    {"smallest_singular_values", py_smallest_singular_values, METH_VARARGS,
     "smallest_singular_values(jacobian, batch, m, n, sigma, work): sigma_min per row."},
    {"least_singular_value", py_least_singular_value, METH_VARARGS,
     "least_singular_value(jacobian, batch, m, n) -> the least sigma_min over the finite rows."},
    {"projected_walk", py_projected_walk, METH_VARARGS,
     "local_planner.py's walk on the fibre, edge by edge: 1 when the deadline passed"},
    {"steer_walk", py_steer_walk, METH_VARARGS,
     "steering.py's walks on the fibre, walk by walk: 1 when the deadline passed"},
    {"refined_self_clearance", py_refined_self_clearance, METH_VARARGS,
     "robot.py's refined self-clearance at joint values, row by row"},
    {"helper_spin", row_helper_spin, METH_VARARGS,
     "helper_spin(seconds) -> the spin it replaces: how long the row helper waits hot"},
    {"helper_parts", row_helper_parts, METH_NOARGS,
     "helper_parts() -> the parts the row helper (row_helper.h) has done in this process"},
    {"walk_scratch", py_walk_scratch, METH_VARARGS,
     "doubles of scratch one projected or steered walk needs"},
    {"obstacle_clearance", py_obstacle_clearance, METH_VARARGS,
     "scene.py's obstacle clearance of placed bodies, row by row: the spheres' pass from "
     "`within`, or the refined pass (hulls against the obstacles) at the margin"},
    {"hull_separation", py_hull_separation, METH_VARARGS,
     "GJK lower bounds of the distance between pairs of placed hulls"},
    {"self_clearance_at", py_self_clearance_at, METH_VARARGS,
     "self_clearance_at(origin, axis, n, q, batch, frame, K, S, centre, radius, own, bound, "
     "bound_radius, pair_a, pair_b, P, clearance, scratch, first): self_clearance at joint "
     "values; rows before `first` on the row helper."},
    {"nearest_segment", py_nearest_segment, METH_VARARGS,
     "nearest_segment(q, points, before, after, nearest, periodic, K, k, n, distance, point): "
     "the least distance to the path segments beside each row's nearest points."},
    {"along", py_along, METH_VARARGS,
     "along(tangent, direction, K, n, out): each tangent signed along its direction."},
    {"hermite", py_hermite, METH_VARARGS,
     "hermite(p0, t0, p1, t1, s, K, n, point, direction): cubic Hermite points and directions."},
    {"settle_dense", py_settle_dense, METH_VARARGS,
     "settle_dense(q, placed, low, lower, upper, periodic, D, n, stray_rad, fixed_rows, "
     "fixed_q, F, excluded, E, inside): densify's window, limits and wrap, in place."},
    {"chain_fronts", py_chain_fronts, METH_VARARGS,
     "chain_fronts(q, T, n, S, by_front, partner, front_first, front_rows, visited, overlap, "
     "ahead, behind, out_rows, first, closed) -> C: the trace's fronts chained into curves."},
    {"unwrap_curves", py_unwrap_curves, METH_VARARGS,
     "unwrap_curves(q, rows, first, C, n, out): each curve's points, every step the short "
     "way round."},
    {"cut_runs", py_cut_runs, METH_VARARGS,
     "cut_runs(points, rows, first, closed, C, n, low, lower, upper, periodic, inside, "
     "out_points, out_rows, run_first, run_closed, exits, has_exit) -> R: the traced curves "
     "cut by the limits into runs."},
    {"dense_nodes", py_dense_nodes, METH_VARARGS,
     "dense_nodes(points, rows, first, closed, R, n, limit_of, found, T, spacing_rad, node_q, "
     "node_row, node_run, node_kind, inner) -> D: densify's nodes and inner point counts."},
    {"dense_layout", py_dense_layout, METH_VARARGS,
     "dense_layout(node_q, node_row, node_run, inner, N, n, tangent, found_tangent, T, placed, "
     "dense_run, offset, between, guess, direction): densify's dense points before Newton."},
    {"dense_finish", py_dense_finish, METH_VARARGS,
     "dense_finish(placed, D, n, m, moved_q, moved_error, moved_rows, M, offset, node_row, "
     "node_kind, N, evaluated_error, T, found_error, found_window, dense_run, R, low, lower, "
     "upper, periodic, stray_rad, q, error, fixed_rows, fixed_q, excluded, inside, q_out, "
     "error_out, run_count) -> count: densify's points after Newton, settled, those inside."},
    {"closest_strands", py_closest_strands, METH_VARARGS,
     "closest_strands(points, P, n, first, C, closed, periodic, within_rad, strand_arc, work, "
     "curve_of, column) -> the least distance between two strands of the traced curves."},
    {"curve_steps", py_curve_steps, METH_VARARGS,
     "curve_steps(q, tangent, n, points, rows, first, closed, L, loop, key, span, start, delta, "
     "start_tangent, end_tangent) -> count: every step of the traced curves (cut.Steps.of)."},
    {"refine_round", py_refine_round, METH_VARARGS,
     "refine_round(fixed, tip, n, rows, m, m_position, target_position, target_rotation, "
     "orientation, S, loop, key, span, start, delta, start_tangent, end_tangent, low, lower, "
     "upper, periodic, p, iterations, until, damping, added_q, added_error, added_jacobian, "
     "added_tangent, added_loop, added_key, out_loop, out_key, out_span, out_start, out_delta, "
     "out_start_tangent, out_end_tangent, scratch) -> (near, split): one round of the "
     "refinement near the limits (cut.refine_near_limits)."},
    {"limit_points", py_limit_points, METH_VARARGS,
     "limit_points(fixed, tip, n, rows, m, m_position, target_position, target_rotation, "
     "orientation, E, a, b, low, lower, upper, periodic, iterations, until, damping, q_window, "
     "q_unwrapped, error, jacobian, tangent, good, scratch): each run end refined onto the "
     "limit its curve crosses (densify.limit_points)."},
    {"steps_near_limits", py_steps_near_limits, METH_VARARGS,
     "steps_near_limits(start, delta, low, lower, upper, periodic, S, n, split): the trace "
     "steps whose chord may pass through the limits unseen."},
    {"nearest_points", py_nearest_points, METH_VARARGS,
     "nearest_points(points, P, queries, K, periodic, n, k, reach, out): each query's k "
     "nearest points within reach, nearest first."},
    {"spread_seeds", py_spread_seeds, METH_VARARGS,
     "spread_seeds(q, M, n, spacing_rad, chosen) -> count: the trace's greedy seeds."},
    {"nearest_of_sets", py_nearest_of_sets, METH_VARARGS,
     "nearest_of_sets(points, n, box, set_of, grouped, member, start, M, radius, x0, x1, best, "
     "distance): each row's nearest node of every other set within the radius."},
    {"links_within", py_links_within, METH_VARARGS,
     "links_within(points, N, n, box, rows, R, radius, fill, i, y, length) -> count: every "
     "node within the radius of each of `rows`."},
    {"merge_labels", py_merge_labels, METH_VARARGS,
     "merge_labels(labels, N, L, a, b, E, out, parent, number): parts merged along edges, "
     "numbered by their lowest node."},
    {"nearest_in_group", py_nearest_in_group, METH_VARARGS,
     "nearest_in_group(points, start, queries, query_group, periodic, Q, n, nearest): each "
     "query's nearest point of its own group."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_native", NULL, -1, methods};

PyMODINIT_FUNC PyInit__native(void) { return PyModule_Create(&module); }
