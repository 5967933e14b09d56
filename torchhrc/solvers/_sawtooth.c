/* Compiled inner loop of the sawtooth upper bound: see torchhrc/solvers/sawtooth_kernel.py,
 * which documents the formula, the two exact bounds that let the loop stop early, and the
 * arguments; _corrections there is the same loop in Python (the reference of the tests).
 *
 * corrections(beliefs, rows, order, idx, inv, off, wid, gain, key, local, out) -> None
 *   beliefs (B, C) float64, rows (R,) int64, order (P',) int64, idx (E,) int64 and
 *   inv (E,) float64 the points' supports end to end (point j: entries off[j] to
 *   off[j] + wid[j]), off (cap,) int64, wid (cap,) int64, gain (cap,) float64,
 *   key (P',) float64, local (Y,) int64 or empty, out (R,) float64 (written).
 *   All C-contiguous.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define SLACK (1.0 + 1e-12)

/* Get a C-contiguous buffer of ndim dims whose items are 8 bytes of the given kind. */
static int get(PyObject *obj, Py_buffer *view, int ndim, char kind, const char *name,
               int writable) {
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Clear();
        PyErr_Format(PyExc_TypeError, "expected %s to be a C-contiguous%s %d-D %s array, got %s",
                     name, writable ? " writable" : "", ndim, kind == 'd' ? "float64" : "int64",
                     Py_TYPE(obj)->tp_name);
        return -1;
    }
    const char *f = view->format ? view->format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    int ok = view->ndim == ndim && view->itemsize == 8 &&
             (kind == 'd' ? (f[0] == 'd' && f[1] == 0)
                          : ((f[0] == 'q' || f[0] == 'l') && f[1] == 0));
    if (!ok) {
        PyErr_Format(PyExc_TypeError,
                     "expected %s to be a C-contiguous %d-D %s array, got format '%s' with "
                     "%d dims",
                     name, ndim, kind == 'd' ? "float64" : "int64", f, view->ndim);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static PyObject *corrections(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    static const char *names[11] = {"beliefs", "rows", "order", "idx",   "inv", "off",
                                    "wid",     "gain", "key",   "local", "out"};
    static const int dims[11] = {2, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1};
    static const char kinds[11] = {'d', 'q', 'q', 'q', 'd', 'q', 'q', 'd', 'd', 'q', 'd'};
    Py_buffer v[11];
    int got = 0;
    (void)self;
    if (nargs != 11) {
        PyErr_Format(PyExc_TypeError, "corrections() takes 11 arguments (%zd given)", nargs);
        return NULL;
    }
    for (; got < 11; got++)
        if (get(args[got], &v[got], dims[got], kinds[got], names[got], got == 10) < 0) goto fail;
    {
        const double *beliefs = v[0].buf;
        const int64_t *rows = v[1].buf, *order = v[2].buf, *idx = v[3].buf;
        const double *inv = v[4].buf;
        const int64_t *off = v[5].buf, *wid = v[6].buf;
        const double *gain = v[7].buf, *key = v[8].buf;
        const int64_t *local = v[9].buf;
        double *out = v[10].buf;
        const Py_ssize_t B = v[0].shape[0], C = v[0].shape[1];
        const Py_ssize_t R = v[1].shape[0], P = v[2].shape[0];
        const Py_ssize_t E = v[3].shape[0], cap = v[5].shape[0];
        const Py_ssize_t Y = v[9].shape[0];
        const int mapped = Y > 0;
        if (v[10].shape[0] != R || v[8].shape[0] != P || v[4].shape[0] != E ||
            v[6].shape[0] != cap || v[7].shape[0] != cap) {
            PyErr_SetString(PyExc_ValueError, "corrections(): inconsistent array shapes");
            goto fail;
        }
        /* bounds of every index, checked once, so the loop below reads no stray memory */
        for (Py_ssize_t q = 0; q < R; q++)
            if (rows[q] < 0 || rows[q] >= B) {
                PyErr_SetString(PyExc_IndexError, "corrections(): a row is out of range");
                goto fail;
            }
        for (Py_ssize_t t = 0; t < P; t++) {
            int64_t j = order[t];
            if (j < 0 || j >= cap || wid[j] < 0 || off[j] < 0 || off[j] > E - wid[j]) {
                PyErr_SetString(PyExc_IndexError, "corrections(): a point is out of range");
                goto fail;
            }
        }
        /* support indices are checked where they are read (a predictable branch) */
        const uint64_t limit = (uint64_t)(mapped ? Y : C);
        int stray = 0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t q = 0; q < R; q++) {
            const double *b = beliefs + rows[q] * C;
            double mass = 0.0, best = 0.0;
            for (Py_ssize_t c = 0; c < C; c++) mass += b[c];
            for (Py_ssize_t t = 0; t < P; t++) {
                const int64_t j = order[t];
                if (key[t] * mass * SLACK >= best) break; /* no later point can win */
                const double g = gain[j];
                const int64_t *yj = idx + off[j];
                const double *wj = inv + off[j];
                double r = INFINITY;
                for (int64_t k = 0; k < wid[j]; k++) {
                    int64_t y = yj[k];
                    if ((uint64_t)y >= limit) {
                        stray = 1;
                        r = 0.0;
                        break;
                    }
                    if (mapped) {
                        y = local[y];
                        if ((uint64_t)y >= (uint64_t)C) { /* outside the given columns: b = 0 */
                            r = 0.0;
                            break;
                        }
                    }
                    const double ratio = b[y] * wj[k];
                    if (ratio < r) {
                        r = ratio;
                        if (g * r >= best) break; /* this point cannot win */
                    }
                }
                const double term = g * r;
                if (term < best) best = term;
            }
            out[q] = best;
        }
        Py_END_ALLOW_THREADS
        if (stray) {
            PyErr_SetString(PyExc_IndexError, "corrections(): a support index is out of range");
            goto fail;
        }
    }
    for (int i = 0; i < got; i++) PyBuffer_Release(&v[i]);
    Py_RETURN_NONE;
fail:
    for (int i = 0; i < got; i++) PyBuffer_Release(&v[i]);
    return NULL;
}

static PyMethodDef methods[] = {
    {"corrections", (PyCFunction)(void (*)(void))corrections, METH_FASTCALL,
     "Sawtooth corrections of some rows (see torchhrc.solvers.sawtooth_kernel)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_sawtooth",
    "Compiled inner loop of torchhrc's sawtooth upper bound.", -1, methods,
};

PyMODINIT_FUNC PyInit__sawtooth(void) { return PyModule_Create(&module); }
