/* The reference for benchmarks/hexapod.py: the warm-started Newton solve of a
 * 6-strut platform's forward kinematics in plain C (as LinuxCNC's genhexkins solves
 * it, with the rotation updated on SO(3) as pkm_kinematics.bars does), over a
 * stream of strut readings, each solve starting from the previous pose.
 * Built by the benchmark with `cc -O2 -shared -fPIC`; called once per stream
 * through ctypes, so the per-reading time is the C solve's own. */
#include <math.h>

static int invert6(double a[6][6], double out[6][6]) {
    double scale = 0.0;
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 6; j++) {
            out[i][j] = (i == j) ? 1.0 : 0.0;
            if (fabs(a[i][j]) > scale) scale = fabs(a[i][j]);
        }
    for (int c = 0; c < 6; c++) {
        int piv = c;
        for (int r = c + 1; r < 6; r++) if (fabs(a[r][c]) > fabs(a[piv][c])) piv = r;
        if (!(fabs(a[piv][c]) > 1e-14 * scale)) return 0;
        if (piv != c)
            for (int j = 0; j < 6; j++) {
                double t = a[c][j]; a[c][j] = a[piv][j]; a[piv][j] = t;
                t = out[c][j]; out[c][j] = out[piv][j]; out[piv][j] = t;
            }
        double inv = 1.0 / a[c][c];
        for (int j = 0; j < 6; j++) { a[c][j] *= inv; out[c][j] *= inv; }
        for (int r = 0; r < 6; r++) {
            if (r == c) continue;
            double f = a[r][c];
            if (f != 0.0)
                for (int j = 0; j < 6; j++) { a[r][j] -= f * a[c][j]; out[r][j] -= f * out[c][j]; }
        }
    }
    return 1;
}

static void exp_so3(double wx, double wy, double wz, double e[9]) {
    double t2 = wx * wx + wy * wy + wz * wz, a, b;
    if (t2 < 1e-16) { a = 1.0; b = 0.5; }
    else { double t = sqrt(t2); a = sin(t) / t; b = (1.0 - cos(t)) / t2; }
    e[0] = 1.0 - b * (wy * wy + wz * wz); e[1] = -a * wz + b * wx * wy; e[2] = a * wy + b * wx * wz;
    e[3] = a * wz + b * wx * wy; e[4] = 1.0 - b * (wx * wx + wz * wz); e[5] = -a * wx + b * wy * wz;
    e[6] = -a * wy + b * wx * wz; e[7] = a * wx + b * wy * wz; e[8] = 1.0 - b * (wx * wx + wy * wy);
}

/* legs: 6 rows (a_x, a_y, a_z, b_x, b_y, b_z); lengths: n x 6; p (3), r (9, row-major):
 * the start, updated; poses: n x 12 (p, R); returns the total number of iterations,
 * or -1 - k when reading k did not converge. */
int solve_stream(const double *legs, const double *lengths, int n, double *p, double *r,
                 double tol, int max_iterations, double *poses) {
    int total = 0;
    for (int k = 0; k < n; k++) {
        const double *l = lengths + 6 * k;
        int done = 0;
        for (int it = 0; it <= max_iterations; it++) {
            double res[6], jinv[6][6], jac[6][6], worst = 0.0;
            for (int i = 0; i < 6; i++) {
                const double *g = legs + 6 * i;
                double rbx = r[0] * g[3] + r[1] * g[4] + r[2] * g[5];
                double rby = r[3] * g[3] + r[4] * g[4] + r[5] * g[5];
                double rbz = r[6] * g[3] + r[7] * g[4] + r[8] * g[5];
                double ex = p[0] + rbx - g[0], ey = p[1] + rby - g[1], ez = p[2] + rbz - g[2];
                double len = sqrt(ex * ex + ey * ey + ez * ez);
                res[i] = len - l[i];
                if (fabs(res[i]) > worst) worst = fabs(res[i]);
                double ux = ex / len, uy = ey / len, uz = ez / len;
                jinv[i][0] = ux; jinv[i][1] = uy; jinv[i][2] = uz;
                jinv[i][3] = rby * uz - rbz * uy; jinv[i][4] = rbz * ux - rbx * uz; jinv[i][5] = rbx * uy - rby * ux;
            }
            if (worst <= tol) { done = 1; total += it; break; }
            if (it == max_iterations || !invert6(jinv, jac)) break;
            double s[6];
            for (int i = 0; i < 6; i++) {
                s[i] = 0.0;
                for (int j = 0; j < 6; j++) s[i] -= jac[i][j] * res[j];
            }
            p[0] += s[0]; p[1] += s[1]; p[2] += s[2];
            double e[9], nr[9];
            exp_so3(s[3], s[4], s[5], e);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    nr[3 * i + j] = e[3 * i] * r[j] + e[3 * i + 1] * r[3 + j] + e[3 * i + 2] * r[6 + j];
            for (int i = 0; i < 9; i++) r[i] = nr[i];
        }
        if (!done) return -1 - k;
        for (int i = 0; i < 3; i++) poses[12 * k + i] = p[i];
        for (int i = 0; i < 9; i++) poses[12 * k + 3 + i] = r[i];
    }
    return total;
}
