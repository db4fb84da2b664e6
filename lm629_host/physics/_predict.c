/* The tuner's predictor loop in C: a line-by-line transcription of py_simulate() in predict.py
 * (with pid.py's holds and skip_held written inline; its pid_step and plant.py's motor_step
 * are sample_c.h's, shared with the chip model's loop), which
 * stays the readable source of truth; tests/physics/test_predict_fast.py runs both side by side.
 *
 * Integers are int64.  run() first checks that every integer it is handed lies where no sum or
 * product below can overflow (gains and filter memory under 2^40, ki and kd under 2^22,
 * positions under 2^61); an argument outside that, a float position beyond 2^61 or a NaN, or a
 * float operation at which Python would raise (log of a non-positive number, a division by
 * zero) makes it return None before it has changed anything, and predict.py then runs the
 * Python loop, which gives Python's answer (or its error).  Python's >> floors; so does
 * shr() here, written out for negative numbers rather than left to the compiler.  Python's %
 * takes the divisor's sign; so does pymod().  Floats follow the Python code's operation order
 * (built with -ffp-contract=off so that nothing is fused); floor and log are libm's, as
 * Python's math module's. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#include "sample_c.h"

#define BIG ((i64)1 << 40)   /* gains, il, ds and the filter's memory: |v| < BIG */
#define GAIN ((i64)1 << 22)  /* ki, kd: |v| < GAIN (ki * (sum >> 8) < 2^62) */
#define POS ((i64)1 << 61)   /* desired positions and encoder counts: |v| < POS */

/* Python's a % m (m != 0): the result takes the sign of m */
static i64 pymod(i64 a, i64 m) {
    i64 r = a % m;
    return (r != 0 && ((r < 0) != (m < 0))) ? r + m : r;
}

static int within(i64 v, i64 limit) { return v > -limit && v < limit; }

/* run(desired, ints, floats) -> (counts, outs, state) or None (outside the envelope above)
 *   ints: kp ki kd il ds shift skip_ahead error_sum last_error derivative countdown integral output
 *   floats: g d c a decay gain x w (drive per output code, load, dry friction, rate, the
 *   sample's decay and gain, position, speed)
 *   state: the PIDState fields in order: error_sum last_error derivative countdown integral output */
static PyObject *run(PyObject *self, PyObject *args) {
    PyObject *desired_obj;
    long long kp, ki, kd, il, ds, shift_ll, skip_ahead, esum, elast, dterm, countdown, iterm, u;
    double g, d, c, a, decay, gain, x, w;
    if (!PyArg_ParseTuple(args, "O(LLLLLLLLLLLLL)(dddddddd)", &desired_obj, &kp, &ki, &kd, &il,
                          &ds, &shift_ll, &skip_ahead, &esum, &elast, &dterm, &countdown, &iterm,
                          &u, &g, &d, &c, &a, &decay, &gain, &x, &w)) {
        if (PyErr_ExceptionMatches(PyExc_OverflowError) ||
            PyErr_ExceptionMatches(PyExc_TypeError)) {
            PyErr_Clear();
            Py_RETURN_NONE;  /* an int beyond 64 bits or not an int: the Python loop's case */
        }
        return NULL;
    }
    if (!(within(kp, BIG) && within(ki, GAIN) && within(kd, GAIN) && within(il, BIG) &&
          within(ds, BIG) && within(esum, BIG) && within(elast, BIG) && within(dterm, BIG) &&
          within(countdown, BIG) && within(iterm, BIG) && within(u, BIG) &&
          (shift_ll == 4 || shift_ll == 8)))
        Py_RETURN_NONE;
    int shift = (int)shift_ll;

    PyObject *seq = PySequence_Fast(desired_obj, "desired must be a sequence");
    if (!seq) return NULL;
    Py_ssize_t total_n = PySequence_Fast_GET_SIZE(seq);
    PyObject **items = PySequence_Fast_ITEMS(seq);
    i64 *want = PyMem_Malloc(sizeof(i64) * (size_t)(total_n ? total_n : 1));
    PyObject *counts = PyList_New(total_n), *outs = PyList_New(total_n);
    PyObject *result = NULL;
    if (!want || !counts || !outs) {
        if (!want) PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t k = 0; k < total_n; k++) {
        if (!PyLong_CheckExact(items[k])) goto fallback;  /* bool, float...: Python's case */
        int overflow;
        long long v = PyLong_AsLongLongAndOverflow(items[k], &overflow);
        if (overflow || !within(v, POS)) goto fallback;
        want[k] = v;
    }

    i64 out = shr(u, shift);
    PyObject *out_obj = NULL;  /* the last output code as a Python int, shared while it holds */
    i64 out_of_obj = 0;
    Py_ssize_t i = -1;
    while (i + 1 < total_n) {
        i++;
        i64 target = want[i];
        /* motor_step(x, w, out * g - d, c, a, decay, gain, 1.0) */
        int was_still = w == 0.0;
        if (motor_step(&x, &w, (double)out * g - d, c, a, decay, gain, 1.0) != 0)
            goto fallback;  /* Python: ZeroDivisionError or a math domain error */
        int stuck = was_still && w == 0.0;
        if (!(x > -(double)POS && x < (double)POS)) goto fallback;  /* NaN, inf, far away */
        i64 n = (i64)floor(x);
        /* the filter: pid_step(st, sat16(target - n), kp, ki, kd, il, ds) */
        i64 e = sat16(target - n);
        i64 held_out = out;
        u = pid_step(&esum, &elast, &dterm, &countdown, &iterm, e, kp, ki, kd, il, ds);
        out = shr(u, shift);

        PyObject *n_obj = PyLong_FromLongLong(n);
        if (!n_obj) goto done;
        PyList_SET_ITEM(counts, i, n_obj);
        if (!out_obj || out_of_obj != out) {
            out_obj = PyLong_FromLongLong(out);  /* the list holds the reference */
            if (!out_obj) goto done;
            out_of_obj = out;
        } else {
            Py_INCREF(out_obj);
        }
        PyList_SET_ITEM(outs, i, out_obj);

        /* holds(st, e, ki, il) */
        int holding = dterm == 0 && elast == e &&
                      !(e && il == 0 && esum && ((esum > 0) != (e > 0))) && (e == 0 || ki == 0);
        if (skip_ahead && stuck && out == held_out && holding) {
            /* the next change of the desired position (or the end) */
            Py_ssize_t next = i + 1;
            while (next < total_n && want[next] == want[next - 1]) next++;
            Py_ssize_t skip = next - i - 1;
            if (ds == 0) goto fallback;  /* Python: ZeroDivisionError in skip_held */
            for (Py_ssize_t k = 1; k <= skip; k++) {
                Py_INCREF(n_obj);
                PyList_SET_ITEM(counts, i + k, n_obj);
                Py_INCREF(out_obj);
                PyList_SET_ITEM(outs, i + k, out_obj);
            }
            /* skip_held(st, skip, e, il, ds) */
            if (e && il > 0) {
                i64 s = esum + (i64)skip * e;
                esum = s > SUM_MAX ? SUM_MAX : (s < SUM_MIN ? SUM_MIN : s);
            }
            countdown = pymod(countdown - (i64)skip, ds);
            i += skip;
        }
    }
    result = Py_BuildValue("(OO(LLLLLL))", counts, outs, (long long)esum, (long long)elast,
                           (long long)dterm, (long long)countdown, (long long)iterm, (long long)u);
    goto done;
fallback:
    Py_INCREF(Py_None);
    result = Py_None;
done:
    /* lists partly filled (a fallback or an error) hold NULL slots: PyList's dealloc skips them */
    Py_XDECREF(counts);
    Py_XDECREF(outs);
    PyMem_Free(want);
    Py_DECREF(seq);
    return result;
}

static PyMethodDef methods[] = {
    {"run", run, METH_VARARGS,
     "run(desired, ints, floats) -> (counts, outs, state) or None: predict.py_simulate in C"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_predict",
                                    "The tuner's predictor loop in C (see predict.py).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__predict(void) { return PyModule_Create(&module); }
