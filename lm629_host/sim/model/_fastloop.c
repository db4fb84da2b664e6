/* The chip model's sample loop in C: a line-by-line transcription of py_loop() in
 * fastloop.py (the readable source of truth is motion.py; fastloop.py says why this exists).
 * tests/test_model_fastloop.py checks it against both, register by register.
 * Integers are int64 (every quantity of the chip model fits: positions are 2^47 in fixed
 * point, products at most 2^60); Python's floor division and modulo are reproduced where
 * an operand can be negative.  Floats follow the same operation order as the Python code
 * (build with -ffp-contract=off so that nothing is fused). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#include "../../physics/sample_c.h"


#define HALF ((i64)1 << 46)
#define SPAN ((i64)1 << 47)

/* The status bits the loop raises.  Their one definition is lm629_host/bus/opcodes.py (Status);
 * PyInit__fastloop reads them from there, so this file holds no copy of them. */
static i64 B_COMPLETE, B_INDEX, B_WRAP, B_PERR, B_BP;

static i64 pymod(i64 a, i64 m) { i64 r = a % m; return r < 0 ? r + m : r; }
static i64 wrap31(i64 x) { return ((x + 0x40000000) & 0x7FFFFFFF) - 0x40000000; }

static i64 stop_distance(i64 v, i64 a) {
    if (v <= a) return 0;
    i64 n = (v - 1) / a;
    return n * v - a * n * (n + 1) / 2;
}

static i64 landing_velocity(i64 r, i64 a) {
    if (r <= a) return r;
    i64 m = ((i64)sqrt((double)(1 + 8 * r / a)) - 1) / 2;
    if (m < 1) m = 1;
    while (a * m * (m + 1) < 2 * r) m++;
    while (m > 1 && a * (m - 1) * m >= 2 * r) m--;
    return (r + a * m * (m - 1) / 2) / m;
}

static PyObject *run(PyObject *self, PyObject *args) {
    long long n, kp, ki, kd, il, ds, shift, stall, cpr, index_k, count, home, out, p, v, a, vmax,
        target, done, vmode, fwd, stopping, esum, elast, dterm, countdown, iterm, u, motor_off,
        bp, threshold, stop_on_error, flags, armed, rp, rv;
    double vpc, apv, load, coul, rate, decay, gain, ts, angle, speed;
    if (!PyArg_ParseTuple(args,
            "(LLLLLLLLLLLLLLLLLLLLLLLLLLLLLLLLLLLL)(dddddddddd)",
            &n, &kp, &ki, &kd, &il, &ds, &shift, &stall, &cpr, &index_k, &count, &home, &out,
            &p, &v, &a, &vmax, &target, &done, &vmode, &fwd, &stopping, &esum, &elast, &dterm,
            &countdown, &iterm, &u, &motor_off, &bp, &threshold, &stop_on_error, &flags, &armed,
            &rp, &rv, &vpc, &apv, &load, &coul, &rate, &decay, &gain, &ts, &angle, &speed))
        return NULL;
    i64 ran = 0, lpes_trip = 0, index_hit = 0, index_pos = 0, e = 0;
    while (ran < n) {
        ran++;
        i64 events = 0;
        /* motor */
        if (stall) {
            speed = 0.0;
        } else {
            /* never -1 here (sample_c.h says why) */
            (void)motor_step(&angle, &speed, (double)out * vpc * apv - load, coul, rate, decay,
                             gain, ts);
        }
        /* encoder */
        i64 c1 = (i64)floor(angle);
        rv = c1 - count;
        rp = wrap31(c1 - home);
        if (armed) {
            i64 k; int hit;
            if (c1 >= count) { k = count + pymod(index_k - count, cpr); hit = k <= c1; }
            else { k = count - pymod(count - index_k, cpr); hit = k >= c1; }
            if (hit) { index_pos = wrap31(k - home); index_hit = 1; armed = 0; events |= B_INDEX; }
        }
        count = c1;
        i64 before = p >> 16;
        if (motor_off) {
            p = rp * 65536;
            v = 0;
            out = 0;
        } else {
            if (!done) {
                if (vmode || stopping) {
                    i64 goal = stopping ? 0 : (fwd ? vmax : -vmax);
                    if (v < goal) v = v + a < goal ? v + a : goal;
                    else v = v - a > goal ? v - a : goal;
                    p += v;
                    if (stopping && v == 0) { done = 1; events |= B_COMPLETE; }
                } else {
                    i64 r = pymod(target * 65536 - p + HALF, SPAN) - HALF;
                    if (v == 0 && r == 0) {
                        done = 1; events |= B_COMPLETE;
                    } else {
                        i64 sign = v ? (v > 0 ? 1 : -1) : (r > 0 ? 1 : -1);
                        i64 ahead = r * sign, spd = v * sign, up;
                        if (ahead <= 0) {
                            spd = spd > a ? spd - a : 0;
                            v = spd * sign;
                            p += v;
                        } else {
                            if (spd <= vmax) up = spd + a < vmax ? spd + a : vmax;
                            else up = spd - a > vmax ? spd - a : vmax;
                            if (a == 0) {
                                up = spd;
                            } else if (up + (up <= a ? 0 : stop_distance(up, a)) > ahead) {
                                up = landing_velocity(ahead, a);
                                if (up < spd - a) up = spd - a;
                            }
                            if (up >= ahead && spd - a <= ahead) {
                                v = 0; p += ahead * sign; done = 1; events |= B_COMPLETE;
                            } else {
                                v = up * sign; p += v;
                            }
                        }
                    }
                }
                if (!(-HALF <= p && p < HALF)) { p = pymod(p + HALF, SPAN) - HALF; events |= B_WRAP; }
            }
            /* PID */
            e = sat16(wrap31((p >> 16) - rp));
            u = pid_step(&esum, &elast, &dterm, &countdown, &iterm, e, kp, ki, kd, il, ds);
            out = u >> shift;
        }
        i64 after = p >> 16;
        i64 step = wrap31(after - before), to_bp = wrap31(bp - before);
        if ((0 <= to_bp && to_bp <= step) || (step <= to_bp && to_bp <= 0)) events |= B_BP;
        if (!motor_off) {
            i64 err = wrap31(after - rp);
            if (err > threshold || -err > threshold) {
                events |= B_PERR;
                if (stop_on_error) lpes_trip = 1;
            }
        }
        flags |= events;
        if (lpes_trip) break;
        if (speed == 0.0 && rv == 0 && v == 0 &&
            (motor_off || (done && dterm == 0 && elast == e && (e == 0 || ki == 0)))) {
            double d = (double)out * vpc * apv - load;
            if (stall || (-coul <= d && d <= coul)) break;
        }
    }
    return Py_BuildValue("(LLLLLLLLLLLLLLLLLLdd)", (long long)ran, (long long)lpes_trip,
                         (long long)index_hit, (long long)index_pos, count, out, p, v, done,
                         esum, elast, dterm, countdown, iterm, u, flags, rp, rv, angle, speed);
}

static PyMethodDef methods[] = {
    {"run", run, METH_VARARGS, "run(ints, floats) -> results: fastloop.py_loop in C"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fastloop",
                                    "The chip model's sample loop in C (see fastloop.py).", -1,
                                    methods};

/* *out = int(lm629_host.bus.opcodes.Status.<name>); -1 with an exception set on failure */
static int status_bit(PyObject *status, const char *name, i64 *out) {
    PyObject *bit = PyObject_GetAttrString(status, name);
    if (!bit) return -1;
    long long value = PyLong_AsLongLong(bit);
    Py_DECREF(bit);
    if (value == -1 && PyErr_Occurred()) return -1;
    *out = value;
    return 0;
}

PyMODINIT_FUNC PyInit__fastloop(void) {
    PyObject *opcodes = PyImport_ImportModule("lm629_host.bus.opcodes");
    if (!opcodes) return NULL;
    PyObject *status = PyObject_GetAttrString(opcodes, "Status");
    Py_DECREF(opcodes);
    if (!status) return NULL;
    int failed = status_bit(status, "TRAJECTORY_COMPLETE", &B_COMPLETE) ||
                 status_bit(status, "INDEX_PULSE", &B_INDEX) ||
                 status_bit(status, "WRAPAROUND", &B_WRAP) ||
                 status_bit(status, "POSITION_ERROR", &B_PERR) ||
                 status_bit(status, "BREAKPOINT", &B_BP);
    Py_DECREF(status);
    if (failed) return NULL;
    return PyModule_Create(&module);
}
