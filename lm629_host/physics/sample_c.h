/* The arithmetic of one sample that both compiled loops share, the chip model's
 * (sim/model/_fastloop.c) and the tuner's predictor (physics/_predict.c): the chip's filter
 * (physics/pid.py's pid_step) and the DC motor with dry friction (physics/plant.py's
 * motor_step).  One home in C; the Python functions stay the readable source of truth, and
 * both loops are checked against them bit for bit and float for float
 * (tests/sim/test_model_fastloop.py, tests/physics/test_plant.py,
 * tests/physics/test_predict_fast.py).  Built with -ffp-contract=off; log is libm's, as
 * Python's math's.  Python's >> floors; so does shr() here, written out for negative numbers
 * rather than left to the compiler. */
#ifndef LM629_SAMPLE_C_H
#define LM629_SAMPLE_C_H

#include <math.h>

/* long long: what PyArg_ParseTuple's "L" fills in, so the loops' locals pass straight in */
typedef long long i64;

#define SUM_MAX (((i64)1 << 23) - 1)  /* the filter's 24-bit error sum */
#define SUM_MIN (-((i64)1 << 23))

static inline i64 sat16(i64 x) { return x > 32767 ? 32767 : (x < -32768 ? -32768 : x); }

/* Python's a >> s for s >= 0: a floor, also for negative a */
static inline i64 shr(i64 a, int s) { return a >= 0 ? a >> s : -((-a - 1) >> s) - 1; }

static inline i64 iabs(i64 a) { return a < 0 ? -a : a; }

/* pid.py's pid_step: one sample of the filter for the error e; its memory (the 24-bit sum,
 * the error at the last derivative sample, the held kd term, the samples until the next
 * derivative sample, the limited ki term) is updated in place; returns u(n), 16-bit. */
static inline i64 pid_step(i64 *esum, i64 *elast, i64 *dterm, i64 *countdown, i64 *iterm,
                           i64 e, i64 kp, i64 ki, i64 kd, i64 il, i64 ds)
{
    e = sat16(e);
    i64 total = *esum + e;
    total = total > SUM_MAX ? SUM_MAX : (total < SUM_MIN ? SUM_MIN : total);
    i64 held = ki * shr(*esum, 8);
    if ((held >= il || held <= -il) && iabs(total) > iabs(*esum))
        total = *esum;  /* already at the limit: an error pushing further is not summed */
    *esum = total;
    i64 term = ki * shr(total, 8);
    *iterm = term > il ? il : (term < -il ? -il : term);
    if (*countdown == 0) {  /* derivative: sampled every ds samples, held in between */
        *dterm = sat16(kd * sat16(e - *elast));
        *elast = e;
        *countdown = ds - 1;
    } else {
        *countdown -= 1;
    }
    return sat16(sat16(kp * e) + *iterm + *dterm);
}

/* plant.py's motor_step: the motor over one sample.
 * Returns 0, or -1 where Python's math would raise (a division by zero or a log of a
 * non-positive number in the stop within the sample), with *x and *w unchanged: the predictor
 * then hands the whole prediction to Python.  The chip model cannot meet it: a speed that
 * changes sign within a sample has its final speed w_inf of the other sign, so the
 * denominator and the log's argument are both positive. */
static inline int motor_step(double *x, double *w, double drive, double coulomb, double rate,
                             double decay, double gain, double dt)
{
    double force;
    if (*w == 0.0) {
        if (-coulomb <= drive && drive <= coulomb)
            return 0;  /* stuck: the drive does not break the dry friction */
        force = drive > 0 ? drive - coulomb : drive + coulomb;
    } else {
        force = *w > 0 ? drive - coulomb : drive + coulomb;
    }
    double w_inf = force / rate;
    double w1 = w_inf + (*w - w_inf) * decay;
    if (*w != 0.0 && ((w1 > 0) != (*w > 0))) {
        /* the dry friction stops the shaft within this sample: it sticks there */
        double den = *w - w_inf;
        if (den == 0.0)
            return -1;
        double q = -w_inf / den;
        if (q <= 0.0)
            return -1;
        *x = *x + (w_inf * (-log(q) / rate) + *w / rate);
        *w = 0.0;
    } else {
        *x = *x + (w_inf * dt + (*w - w_inf) * gain);
        *w = w1;
    }
    return 0;
}

#endif
