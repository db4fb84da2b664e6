/* The DC motor with dry friction over one sample, for both compiled loops: the chip model's
 * (sim/model/_fastloop.c) and the tuner's predictor (physics/_predict.c).  One home: it is
 * physics/plant.py's motor_step (the readable source of truth), float for float in Python's
 * order of operations (built with -ffp-contract=off; log is libm's, as Python's math's).
 *
 * Returns 0, or -1 where Python's math would raise (a division by zero or a log of a
 * non-positive number in the stop within the sample), with *x and *w unchanged: the predictor
 * then hands the whole prediction to Python.  The chip model cannot meet it: a speed that
 * changes sign within a sample has its final speed w_inf of the other sign, so the
 * denominator and the log's argument are both positive. */
#ifndef LM629_MOTOR_STEP_H
#define LM629_MOTOR_STEP_H

#include <math.h>

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
