/* The conductance -> force recursion of models.sls_kernels.inverse, line for line, in C.
 *
 * Why a C twin of the numba kernel: loading numba's cached code costs ~0.65 s per process (numba's import and its
 * CPU target's start-up), which made `sensnake estimate --model sls` 2.3x the linear model on a 36-sensor x 370 s
 * record while the recursion itself takes ~0.1 s. This file is compiled once per machine by the system C compiler
 * into the user's cache (models/sls_ckernel.py) and loaded with ctypes (~1 ms). Where no compiler is found the numba
 * kernel runs, and without numba the numpy reference: all three give the same numbers (tests/models/test_sls_kernels.py).
 *
 * Every array is sensor-major (S, N), C-contiguous; oma and ramp may each be (1, N) (shared tau; ramp per sensor
 * when only some sensors' steps need the linear fallback). Status codes are the integers
 * of models.sls.ForceStatus / models.physics.StrainStatus, as in models/sls_kernels.py.
 */
#include <math.h>
#include <stdint.h>

enum { OK = 0, NAN_INPUT = 1, OPEN_CIRCUIT = 2, NEGATIVE = 3, BELOW_BASELINE = 4, SATURATED = 5, NOT_CONVERGED = 6 };
enum { STRAIN_NEAR_ONE_CODE = 5, STRAIN_NOT_CONVERGED_CODE = 7 };
#define STRAIN_NEAR_ONE 0.9
#define NEWTON_MAX_ITER 100
#define ACCEPT_STEP_HALLEY 1e-6
#define BELOW_BASELINE_FLAG_N 1e-9

/* One step's force with the contact term (the root of C*(K/sqrt(F) + R0*(1-eps)*exp(-k*eps)) - 1, eps = p + w*F):
 * Halley's method in F inside a shrinking bracket, as models.sls_kernels.solve_contact. Returns the status. */
static int solve_contact(double cond, double p, double w, double f_guess, double k, double r0, double kc,
                         double *f_out)
{
    double f_max = (1.0 - p) / w;
    if (!(f_max > 0.0)) { *f_out = 0.0; return SATURATED; }
    double f_lo = kc * cond * kc * cond;
    if (f_lo >= f_max) { *f_out = f_max; return SATURATED; }
    if (r0 * cond < 1e-17) { *f_out = f_lo; return OK; }
    double f_hi = f_max;
    double f;
    if (f_lo < f_guess && f_guess < f_hi) f = f_guess;
    else f = f_lo > 0.0 ? sqrt(f_lo * f_hi) : 0.5 * f_hi;
    for (int it = 0; it < NEWTON_MAX_ITER; ++it) {
        double inv_f = 1.0 / f;
        double contact = kc * sqrt(inv_f);
        double eps = p + w * f;
        double one_minus = 1.0 - eps;
        double g, slope, curve;
        if (one_minus > 0.0) {
            double decay = r0 * exp(-k * eps);
            g = cond * (contact + one_minus * decay) - 1.0;
            slope = cond * (-0.5 * contact * inv_f - decay * (1.0 + k * one_minus) * w);
            curve = cond * (0.75 * contact * inv_f * inv_f + w * w * decay * k * (2.0 + k * one_minus));
        } else {
            g = cond * contact - 1.0;
            slope = cond * (-0.5 * contact * inv_f);
            curve = cond * (0.75 * contact * inv_f * inv_f);
        }
        if (g == 0.0) { *f_out = f; return OK; }
        if (g > 0.0) f_lo = f; else f_hi = f;
        double step = g / slope;
        step = step / (1.0 - 0.5 * step * curve / slope);
        double f_new = f - step;
        int inside = f_lo <= f_new && f_new <= f_hi;
        if (inside && fabs(step) <= ACCEPT_STEP_HALLEY * f) { *f_out = f_new; return OK; }
        if (!inside) f_new = f_lo > 0.0 ? sqrt(f_lo * f_hi) : 0.5 * f_hi;
        f = f_new;
        if (f_hi - f_lo <= 4e-16 * f) { *f_out = f; return OK; }
    }
    *f_out = f;
    return NOT_CONVERGED;
}

void sls_inverse(int64_t s, int64_t n, const double *cond, const double *oma, const double *ramp, int64_t oma_shared,
                 int64_t ramp_shared, int64_t use_ramp, const double *e0, const double *e1, const double *area, int64_t contact,
                 double k, double r0, double kc, const double *strain, const int64_t *strain_status,
                 double *q_state, double *sig_state, double *f_state, double *force, int8_t *status)
{
    for (int64_t j = 0; j < s; ++j) {
        const double *oma_j = oma + (oma_shared ? 0 : j * n);
        const double *ramp_j = ramp + (ramp_shared ? 0 : j * n);
        const double *cond_j = cond + j * n;
        double inv_e0 = 1.0 / e0[j], inv_e1 = 1.0 / e1[j], a = area[j];
        double q = q_state[j], sig_prev = sig_state[j], f_prev = f_state[j];
        for (int64_t i = 0; i < n; ++i) {
            double c = cond_j[i];
            double p = q + oma_j[i] * (sig_prev * inv_e1 - q);
            double r_i = use_ramp ? ramp_j[i] : 0.0;
            p -= r_i * sig_prev * inv_e1;
            double inv_eff = inv_e0 + r_i * inv_e1;
            int code = OK;
            double sig, f_out;
            if (c != c) {
                code = NAN_INPUT;
                sig = sig_prev;
                f_out = NAN;
            } else if (c <= 0.0) {
                code = c == 0.0 ? OPEN_CIRCUIT : NEGATIVE;
                sig = 0.0;
                f_out = 0.0;
            } else if (c == INFINITY) {
                code = SATURATED;
                sig = (1.0 - p) / inv_eff;
                if (sig < 0.0) sig = 0.0;  /* as max(sig, 0.0) */
                f_out = sig * a;
            } else if (contact) {
                code = solve_contact(c, p, inv_eff / a, f_prev, k, r0, kc, &f_out);
                if (code == OK && p + inv_eff / a * f_out >= STRAIN_NEAR_ONE) code = SATURATED;
                sig = f_out / a;
            } else {
                sig = (strain[j * n + i] - p) / inv_eff;
                int64_t ss = strain_status[j * n + i];
                if (ss == STRAIN_NEAR_ONE_CODE) code = SATURATED;
                else if (ss == STRAIN_NOT_CONVERGED_CODE) code = NOT_CONVERGED;
                if (sig < 0.0) {
                    if (code == OK && sig * a < -BELOW_BASELINE_FLAG_N) code = BELOW_BASELINE;
                    sig = 0.0;
                }
                f_out = sig * a;
            }
            force[j * n + i] = f_out;
            if (status[j * n + i] == 0) status[j * n + i] = (int8_t)code;
            q = p + r_i * sig * inv_e1;
            sig_prev = sig;
            if (f_out > 0.0) f_prev = f_out;
        }
        q_state[j] = q;
        sig_state[j] = sig_prev;
        f_state[j] = f_prev;
    }
}
