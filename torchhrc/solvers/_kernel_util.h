/* Shared by torchhrc's C extensions (_sawtooth.c, _backup.c): the argument check of a
 * buffer and the sawtooth correction of one row. See torchhrc/solvers/sawtooth_kernel.py for
 * the formula and the two exact bounds that stop the loop early; _corrections there is the
 * same loop in Python (the reference of the tests).
 */
#ifndef TORCHHRC_KERNEL_UTIL_H
#define TORCHHRC_KERNEL_UTIL_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#define SLACK (1.0 + 1e-12)

/* Get a C-contiguous buffer of ndim dims whose items are 8 bytes of the given kind ('d':
 * float64, 'q': int64). On failure a TypeError names the argument and what was given. */
static int get_buffer(PyObject *obj, Py_buffer *view, int ndim, char kind, const char *name,
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

/* The support signature of a belief: bit y % 64 set for every hidden value y it covers. A
 * point whose signature has a bit outside a row's covers a hidden value the row does not
 * (b(y) = 0 there), so its term g_i * min_y b(y) / b_i(y) is 0 and cannot lower the bound. */
#define SIG_BIT(y) ((uint64_t)1 << ((uint64_t)(y) & 63u))

/* The signature of a dense row b (C,): hidden value y at column y. */
static inline uint64_t row_signature(const double *b, Py_ssize_t C) {
    uint64_t s = 0;
    for (Py_ssize_t y = 0; y < C; y++)
        if (b[y] != 0.0) s |= SIG_BIT(y);
    return s;
}

/* The sawtooth correction min(0, min_i g_i min_y b(y) / b_i(y)) of one row b (C,) of mass
 * ``mass``, over the points ``order`` (P,) by increasing ``key``. Support indices at or above
 * ``limit`` set *stray (the caller raises); with ``mapped``, a hidden value y is read at
 * column local[y] (C or more: b = 0 there). With ``sig`` (the points' signatures, or NULL),
 * a point that covers a hidden value outside ``row_sig`` is skipped: its term is 0, so the
 * result is the same float. The caller has checked order, off and wid. */
static inline double sawtooth_row(const double *b, Py_ssize_t C, double mass,
                                  const int64_t *order, Py_ssize_t P, const double *key,
                                  const int64_t *idx, const double *inv, const int64_t *off,
                                  const int64_t *wid, const double *gain, const int64_t *local,
                                  const int64_t *sig, uint64_t row_sig, uint64_t limit,
                                  int mapped, int *stray) {
    double best = 0.0;
    for (Py_ssize_t t = 0; t < P; t++) {
        const int64_t j = order[t];
        if (key[t] * mass * SLACK >= best) break; /* no later point can win */
        if (sig != NULL && ((uint64_t)sig[j] & ~row_sig) != 0) continue; /* its term is 0 */
        const double g = gain[j];
        const int64_t *yj = idx + off[j];
        const double *wj = inv + off[j];
        double r = INFINITY;
        for (int64_t k = 0; k < wid[j]; k++) {
            int64_t y = yj[k];
            if ((uint64_t)y >= limit) {
                *stray = 1;
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
    return best;
}

/* Whether every point of ``order`` (P,) lies inside the storage (cap points, E entries). */
static int points_in_range(const int64_t *order, Py_ssize_t P, const int64_t *off,
                           const int64_t *wid, Py_ssize_t cap, Py_ssize_t E) {
    for (Py_ssize_t t = 0; t < P; t++) {
        int64_t j = order[t];
        if (j < 0 || j >= cap || wid[j] < 0 || off[j] < 0 || off[j] > E - wid[j]) return 0;
    }
    return 1;
}

#endif
