/* Compiled inner loop of the sawtooth upper bound: see torchhrc/solvers/sawtooth_kernel.py,
 * which documents the formula, the two exact bounds that let the loop stop early, and the
 * arguments; _corrections there is the same loop in Python (the reference of the tests).
 *
 * corrections(beliefs, rows, order, idx, inv, off, wid, gain, key, local, sig, out) -> None
 *   beliefs (B, C) float64, rows (R,) int64, order (P',) int64, idx (E,) int64 and
 *   inv (E,) float64 the points' supports end to end (point j: entries off[j] to
 *   off[j] + wid[j]), off (cap,) int64, wid (cap,) int64, gain (cap,) float64,
 *   key (P',) float64, local (Y,) int64 or empty, sig (cap,) int64 the points' support
 *   signatures (_kernel_util.h) or empty, out (R,) float64 (written). All C-contiguous.
 */
#include "_kernel_util.h"

static PyObject *corrections(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    static const char *names[12] = {"beliefs", "rows", "order", "idx",   "inv", "off",
                                    "wid",     "gain", "key",   "local", "sig", "out"};
    static const int dims[12] = {2, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1};
    static const char kinds[12] = {'d', 'q', 'q', 'q', 'd', 'q', 'q', 'd', 'd', 'q', 'q', 'd'};
    Py_buffer v[12];
    int got = 0;
    (void)self;
    if (nargs != 12) {
        PyErr_Format(PyExc_TypeError, "corrections() takes 12 arguments (%zd given)", nargs);
        return NULL;
    }
    for (; got < 12; got++)
        if (get_buffer(args[got], &v[got], dims[got], kinds[got], names[got], got == 11) < 0)
            goto fail;
    {
        const double *beliefs = v[0].buf;
        const int64_t *rows = v[1].buf, *order = v[2].buf, *idx = v[3].buf;
        const double *inv = v[4].buf;
        const int64_t *off = v[5].buf, *wid = v[6].buf;
        const double *gain = v[7].buf, *key = v[8].buf;
        const int64_t *local = v[9].buf;
        const int64_t *sig = v[10].shape[0] > 0 ? v[10].buf : NULL;
        double *out = v[11].buf;
        const Py_ssize_t B = v[0].shape[0], C = v[0].shape[1];
        const Py_ssize_t R = v[1].shape[0], P = v[2].shape[0];
        const Py_ssize_t E = v[3].shape[0], cap = v[5].shape[0];
        const Py_ssize_t Y = v[9].shape[0];
        const int mapped = Y > 0;
        if (v[11].shape[0] != R || v[8].shape[0] != P || v[4].shape[0] != E ||
            v[6].shape[0] != cap || v[7].shape[0] != cap ||
            (v[10].shape[0] != 0 && v[10].shape[0] != cap)) {
            PyErr_SetString(PyExc_ValueError, "corrections(): inconsistent array shapes");
            goto fail;
        }
        /* bounds of every index, checked once, so the loop below reads no stray memory */
        for (Py_ssize_t q = 0; q < R; q++)
            if (rows[q] < 0 || rows[q] >= B) {
                PyErr_SetString(PyExc_IndexError, "corrections(): a row is out of range");
                goto fail;
            }
        if (!points_in_range(order, P, off, wid, cap, E)) {
            PyErr_SetString(PyExc_IndexError, "corrections(): a point is out of range");
            goto fail;
        }
        /* support indices are checked where they are read (a predictable branch) */
        const uint64_t limit = (uint64_t)(mapped ? Y : C);
        int stray = 0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t q = 0; q < R; q++) {
            const double *b = beliefs + rows[q] * C;
            double mass = 0.0;
            for (Py_ssize_t c = 0; c < C; c++) mass += b[c];
            /* mapped columns: no signature (a column is not its hidden value) */
            const uint64_t row_sig = (sig == NULL || mapped) ? ~(uint64_t)0 : row_signature(b, C);
            out[q] = sawtooth_row(b, C, mass, order, P, key, idx, inv, off, wid, gain, local,
                                  sig, row_sig, limit, mapped, &stray);
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
