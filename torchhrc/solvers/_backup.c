/* Compiled steps of SARSOP's one-belief evaluation on the CPU: see
 * torchhrc/solvers/backup_kernel.py, which documents every function and its numpy
 * reference (SolverModel.children_np, _SARSOP._lower_np and _upper_np,
 * SawtoothUpperBound.value_np); the functions check their arguments' dtypes and shapes.
 * The per-call work is small (tens of states and actions): what this saves is the forty-odd
 * numpy calls of a few microseconds each.
 *
 * children(b, tx, tyk, z, RT, cx, rows, rows_x, prob, nz, reward, x) -> m
 *   b (Y,), tx (A, Y, K) and/or tyk (A, K, Y, Y) (the other empty), z (A, K, O, Y),
 *   RT (Y, A) float64, cx (A K O,) int64 the children's observed values; written:
 *   rows (A K O + 1, Y), rows_x (A K O + 1,), prob (A K O,), nz (A K O,) int64,
 *   reward (A,). Returns the number m of possible children (rows m is b, at x).
 *
 * bound_children(rows, rows_x, nz, low_r, best_r, reward, stale_q, stale_up, corner,
 *                sorted, idx, inv, off, wid, gain, sig, low, best, q_low, up, q_up, gamma)
 *                -> cu
 *   rows (m + 1, S), rows_x (m + 1,) int64 their observed values, nz (m,) int64,
 *   low_r (m + 1,), best_r (m + 1,) int64, reward (A,), stale_q (A,) and stale_up (C,) or
 *   both empty, then the upper bound as group_upper reads it (corner (X, S), sorted, idx,
 *   inv, off, wid, gain, sig); written: low (C,), best (C,) int64, q_low (A,), up (C,),
 *   q_up (A,); gamma a float. Returns V_up(b).
 *
 * group_scores(rows, rows_x, V, cols, gid, gn, val, best) -> None
 *   rows (B, W) or (1, W) float64 (one row: scored at each x of rows_x), rows_x (B,) int64
 *   each row's observed value, V (N, Y) float64 the alpha vectors (the one store: rows),
 *   cols (W,) int64 the columns of V the rows are given on, or empty (W = Y: all), gid a
 *   list of (at least) X arrays: gid[x] (cap_x,) int64 the indices of x's vectors in V; gn
 *   (X,) int64 how many of each are in use. Written: val (B,) the best score of each row
 *   among its own x's vectors, best (B,) int64 that vector's index (the first maximum in
 *   group order, as numpy's argmax).
 *
 * gather_columns(V, cols, out) -> None
 *   V (N, Y) float64, cols (c,) int64, out (c, n) float64 written: out[q, j] = V[j, cols[q]]
 *   for the first n rows (the columns a sparse belief lives on, as one BLAS operand).
 *
 * group_upper(rows, rows_x, corner, sorted, idx, inv, off, wid, gain, sig, out) -> None
 *   rows (B, Y) float64, rows_x (B,) int64, corner (X, Y) float64, sorted a list of X
 *   (order (P_x,) int64, key (P_x,) float64) pairs (each row's x built), then the sawtooth
 *   storage (idx, inv, off, wid, gain, sig) as in _sawtooth.c. Written: out (B,) the sawtooth
 *   upper bound of each row at its own x, corner[x] . b + the correction of x's points.
 *
 * backup_one(b, tx, tyk, z, RT, cx, rows, rows_x, nz, V, gid, gn, corner, sorted, idx, inv,
 *            off, wid, gain, sig, stale, record, best, out, x, gamma)
 *            -> (m, V_low(b), its vector, V_up(b), a, out . b)
 *   children(), the rows' lower bounds against each row's own x's vectors (V, gid, gn as
 *   group_scores), bound_children() over them, and, where out (Y,) is given (not empty), the
 *   new vector of the action a of highest Q_low into out (backup_vector(), the impossible
 *   children taking the best vector of their x2 at b); a = -1 and out . b = NaN otherwise.
 *   The evaluation is written as one record (2 A + 3 A K O,): q_low (A), q_up (A), then
 *   prob, low and up (A K O each, in (a, k, o) order); stale is the belief's last record, or
 *   empty (bound_children's stale_q and stale_up are its q_up and up). best (A K O,) int64.
 *   One call per backup of a dense model's belief.
 *
 * add_point(b, corner, idx, inv, px, v, gain, wid, mass, off, sig, members, order, key,
 *           x, value, n, start, m, p) -> (w, pos)
 *   One point (x, b, value) of the sawtooth upper bound stored as point n:
 *   SawtoothUpperBound.add_np's numpy steps. b (Y,) float64 a normalised belief, corner
 *   (X, Y), then the storage: idx (E,) int64 and inv (E,) the supports end to end (b's
 *   written from entry start), px, wid, off, sig (cap,) int64 and v, gain, mass (cap,)
 *   float64 (entry n written); members (cap_x,) int64 x's point indices (n written at m);
 *   order (cap_o,) int64 and key (cap_o,) x's points of negative gain by increasing key
 *   g / s, the first p in use (p = -1: not built, left alone), n put at its place (after
 *   equal keys) when its gain is negative. The caller leaves room: n < cap, start + Y <= E,
 *   m < cap_x, p < cap_o. Returns b's support width w and n's place in order (-1: not
 *   put). A belief of one hidden value y (w = 1) is not stored: w = 1 and nothing written
 *   (the caller lowers the corner instead).
 *
 * trial_step(record, A, O, target) -> (max Q_low, a, ties, k, o, P, low, up)
 *   A trial's choice at a node from its cached evaluation, a record (2 A + 3 A K O,) float64
 *   as backup_one writes it. a is the first action whose Q_up is within 1e-12 (relative) of
 *   the largest, ties how many are; of a's children, (k, o) the possible one (P > 0) of
 *   largest excess gap (up - low) - target * P, the first of equal ones ((0, 0) if none),
 *   with its P, low and up (_SARSOP._argmax_tie and _child_choice, on Python floats).
 *
 * propagate_inactive(parent, active) -> None
 *   parent (N,) int64 (-1 at a root; a parent's index below its child's), active (>= N,)
 *   bool, written: active[i] &= active[parent[i]] in index order (a tree's pruning reaches
 *   every descendant; BeliefTree.refresh_active).
 *
 * dominated(V, ids, groups, keep, atol) -> None
 *   V (N, Y) float64 the alpha vectors (their one store), ids (n,) int64 the candidates'
 *   rows, grouped: groups (n,) int64 their observed values, non-decreasing (equal values
 *   contiguous), or empty: one group. Written: keep (n,) int64, 0 where another candidate j
 *   of the same group dominates candidate i (V[ids[j]] >= V[ids[i]] - atol at every entry)
 *   and either i does not dominate j back or j comes first (of equal vectors the first is
 *   kept); 1 elsewhere (pruning.prune_dominated's rule, the order of ids the tie order).
 *
 * backup_vector(tx, tyk, z, r, V, use, a, gamma, out) -> None
 *   tx (A, Y, K) and/or tyk (A, K, Y, Y) as for children (tx empty: K = 1 and Tx = 1; tyk
 *   empty: Ty the identity), z (A, K, O, Y), r (Y,) = R[a, x], V (N, Y) alpha vectors,
 *   use (K O,) int64 the vector of each child (x2_k, o); written: out (Y,) the new vector
 *   r + gamma sum_k Tx[a, y, k] sum_y2 Ty[a, k, y, y2] sum_o Z[a, k, o, y2] V[use[k, o], y2]
 *   (a flat model: tx empty, tyk = T as (A, 1, S, S)).
 */
#include "_kernel_util.h"

#include <string.h>

typedef struct {
    const char *name;
    int ndim;
    char kind;
    int writable;
} spec_t;

/* Get buffers for args[0..n) by spec; on failure release what was taken and return -1. */
static int get_all(PyObject *const *args, Py_buffer *v, const spec_t *spec, int n) {
    for (int i = 0; i < n; i++)
        if (get_buffer(args[i], &v[i], spec[i].ndim, spec[i].kind, spec[i].name,
                       spec[i].writable) < 0) {
            for (int j = 0; j < i; j++) PyBuffer_Release(&v[j]);
            return -1;
        }
    return 0;
}

static void release_all(Py_buffer *v, int n) {
    for (int i = 0; i < n; i++) PyBuffer_Release(&v[i]);
}

/* children()'s buffers (then its x); backup_one() takes the same first eleven. */
static const spec_t children_spec[11] = {
    {"b", 1, 'd', 0},    {"tx", 3, 'd', 0},     {"tyk", 4, 'd', 0},  {"z", 4, 'd', 0},
    {"RT", 2, 'd', 0},   {"cx", 1, 'q', 0},     {"rows", 2, 'd', 1}, {"rows_x", 1, 'q', 1},
    {"prob", 1, 'd', 1}, {"nz", 1, 'q', 1},     {"reward", 1, 'd', 1},
};

/* Two buffers per observed value x (a group's arrays), taken on the group's first row and
 * released together. */
typedef struct {
    Py_buffer *buf; /* (2 X,): buf[2 x], buf[2 x + 1] */
    char *got;      /* (X,) */
    Py_ssize_t X;
} groups_t;

static int groups_init(groups_t *g, Py_ssize_t X) {
    g->X = X;
    g->buf = PyMem_Calloc((size_t)(X > 0 ? X : 1), 2 * sizeof(Py_buffer));
    g->got = PyMem_Calloc((size_t)(X > 0 ? X : 1), 1);
    if (g->buf == NULL || g->got == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    return 0;
}

static void groups_release(groups_t *g) {
    for (Py_ssize_t x = 0; g->buf != NULL && g->got != NULL && x < g->X; x++)
        if (g->got[x]) {
            PyBuffer_Release(&g->buf[2 * x]);
            PyBuffer_Release(&g->buf[2 * x + 1]);
        }
    PyMem_Free(g->buf);
    PyMem_Free(g->got);
}

/* Whether row i's observed value x lies in [0, X); an IndexError names the function if not. */
static int row_x_ok(const char *fn, Py_ssize_t i, int64_t x, Py_ssize_t X) {
    if (x >= 0 && x < X) return 1;
    PyErr_Format(PyExc_IndexError, "%s(): row %zd has observed value %lld, outside [0, %zd)", fn,
                 i, (long long)x, X);
    return 0;
}

/* The shapes of the tables and scratch v[0..8) (b, tx, tyk, z, RT, cx, rows, rows_x, as
 * children() takes them) and the lengths of prob, nz and reward, or NULL if they agree (A, K,
 * O, Y from z). */
static const char *children_shapes(const Py_buffer *v, Py_ssize_t n_prob, Py_ssize_t n_nz,
                                   Py_ssize_t n_reward) {
    const Py_ssize_t A = v[3].shape[0], K = v[3].shape[1], O = v[3].shape[2], Y = v[3].shape[3];
    const Py_ssize_t C = A * K * O;
    const int has_tx = v[1].shape[0] > 0, has_ty = v[2].shape[0] > 0;
    if (v[0].shape[0] != Y || (!has_tx && !has_ty) ||
        (has_tx && (v[1].shape[0] != A || v[1].shape[1] != Y || v[1].shape[2] != K)) ||
        (has_ty && (v[2].shape[0] != A || v[2].shape[1] != K || v[2].shape[2] != Y ||
                    v[2].shape[3] != Y)) ||
        v[4].shape[0] != Y || v[4].shape[1] != A || v[5].shape[0] != C ||
        v[6].shape[0] != C + 1 || v[6].shape[1] != Y || v[7].shape[0] != C + 1 ||
        n_prob != C || n_nz != C || n_reward != A)
        return "b (Y,), tx (A, Y, K) and/or tyk (A, K, Y, Y), z (A, K, O, Y), RT (Y, A), cx "
               "(A K O,), rows (A K O + 1, Y), rows_x (A K O + 1,), prob and nz (A K O,), "
               "reward (A,)";
    return NULL;
}

/* The ValueError of fn() whose buffers v (children()'s first eleven) disagree as bad says. */
static void children_shape_error(const char *fn, const Py_buffer *v, const char *bad) {
    PyErr_Format(PyExc_ValueError,
                 "%s(): inconsistent shapes for A=%zd actions, K=%zd next observed values, "
                 "O=%zd observations, Y=%zd hidden values: expected %s",
                 fn, v[3].shape[0], v[3].shape[1], v[3].shape[2], v[3].shape[3], bad);
}

/* The dense model's tables at one observed value x (children()'s b to cx). */
typedef struct {
    const double *tx, *tyk, *z, *RT; /* tx or tyk NULL: absent */
    const int64_t *cx;
    Py_ssize_t A, K, O, Y;
} tables_t;

static tables_t tables_of(const Py_buffer *v) {
    tables_t t = {v[1].shape[0] > 0 ? v[1].buf : NULL, v[2].shape[0] > 0 ? v[2].buf : NULL,
                  v[3].buf, v[4].buf, v[5].buf, v[3].shape[0], v[3].shape[1], v[3].shape[2],
                  v[3].shape[3]};
    return t;
}

/* The children of b at x (see children() above), written into rows, rows_x, prob, nz and
 * reward; pred and supp are (Y,) scratch. Returns m, the number of possible children. */
static Py_ssize_t children_core(const tables_t *t, const double *b, Py_ssize_t x, double *rows,
                                int64_t *rows_x, double *prob, int64_t *nz, double *reward,
                                double *pred, Py_ssize_t *supp) {
    const Py_ssize_t A = t->A, K = t->K, O = t->O, Y = t->Y;
    const double *tx = t->tx, *tyk = t->tyk, *z = t->z, *RT = t->RT;
    Py_ssize_t m = 0;
    for (Py_ssize_t a = 0; a < A; a++) {
        for (Py_ssize_t k = 0; k < K; k++) {
            /* pred[y2] = sum_y b[y] tx[a, y, k] tyk[a, k, y, y2] (a flat model: tx = 1, tyk = T;
             * a static hidden value: tyk = identity), over the support of b in state order */
            if (tyk != NULL) {
                memset(pred, 0, (size_t)Y * sizeof(double));
                for (Py_ssize_t y = 0; y < Y; y++) {
                    const double w = tx != NULL ? b[y] * tx[(a * Y + y) * K + k] : b[y];
                    if (w == 0.0) continue;
                    const double *row = tyk + ((a * K + k) * Y + y) * Y;
                    for (Py_ssize_t y2 = 0; y2 < Y; y2++) pred[y2] += w * row[y2];
                }
            } else {
                for (Py_ssize_t y = 0; y < Y; y++) pred[y] = b[y] * tx[(a * Y + y) * K + k];
            }
            /* the children pred * Z[a, x2_k, :, o] over the support of pred (TagAvoid as a
             * flat POMDP: 870 observations, a handful of predicted states; every row written
             * in full was 30 MB of stores per belief) */
            Py_ssize_t n = 0;
            for (Py_ssize_t y = 0; y < Y; y++)
                if (pred[y] != 0.0) supp[n++] = y;
            for (Py_ssize_t o = 0; o < O; o++) {
                const Py_ssize_t c = (a * K + k) * O + o;
                const double *zo = z + c * Y;
                double p = 0.0; /* the same sum, in the same order, as over every state */
                for (Py_ssize_t q = 0; q < n; q++) p += pred[supp[q]] * zo[supp[q]];
                prob[c] = p;
                if (!(p > 0.0)) continue;
                double *out = rows + m * Y; /* the m-th possible child */
                memset(out, 0, (size_t)Y * sizeof(double));
                for (Py_ssize_t q = 0; q < n; q++) out[supp[q]] = pred[supp[q]] * zo[supp[q]];
                rows_x[m] = t->cx[c];
                nz[m++] = c;
            }
        }
        double r = 0.0;
        for (Py_ssize_t y = 0; y < Y; y++) r += b[y] * RT[y * A + a];
        reward[a] = r;
    }
    memcpy(rows + m * Y, b, (size_t)Y * sizeof(double));
    rows_x[m] = x;
    return m;
}

static PyObject *children(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 11 };
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB + 1) {
        PyErr_Format(PyExc_TypeError, "children() takes %d arguments (%zd given)", NB + 1, nargs);
        return NULL;
    }
    const Py_ssize_t x = PyNumber_AsSsize_t(args[NB], PyExc_OverflowError);
    if (x == -1 && PyErr_Occurred()) return NULL;
    if (get_all(args, v, children_spec, NB) < 0) return NULL;
    const char *bad = children_shapes(v, v[8].shape[0], v[9].shape[0], v[10].shape[0]);
    if (bad != NULL) {
        children_shape_error("children", v, bad);
        release_all(v, NB);
        return NULL;
    }
    const tables_t t = tables_of(v);
    double *pred = PyMem_Malloc((size_t)(t.Y > 0 ? t.Y : 1) * sizeof(double));
    Py_ssize_t *supp = PyMem_Malloc((size_t)(t.Y > 0 ? t.Y : 1) * sizeof(Py_ssize_t));
    if (pred == NULL || supp == NULL) {
        PyMem_Free(pred);
        PyMem_Free(supp);
        release_all(v, NB);
        return PyErr_NoMemory();
    }
    const Py_ssize_t m = children_core(&t, v[0].buf, x, v[6].buf, v[7].buf, v[8].buf, v[9].buf,
                                       v[10].buf, pred, supp);
    PyMem_Free(pred);
    PyMem_Free(supp);
    release_all(v, NB);
    return PyLong_FromSsize_t(m);
}

/* The sawtooth upper bound of rows of several observed values, each at its own x (rows_x):
 * corner[x] . b plus the correction of x's points (one observed value: X = 1). */
typedef struct {
    const double *rows, *corner, *inv, *gain;
    const int64_t *rows_x, *idx, *off, *wid, *sig; /* sig: NULL, or the points' signatures */
    Py_ssize_t Y;
    groups_t g; /* per x: its points' order and keys */
    int stray;
} saw_t;

/* Take the (order, key) pair of every x among rows_x[0..B) from the list sorted, checked
 * against the storage (cap points, E entries). -1 with an exception set on failure; the
 * caller releases u->g either way. */
static int saw_take(saw_t *u, PyObject *sorted, Py_ssize_t X, Py_ssize_t B, Py_ssize_t cap,
                    Py_ssize_t E, const char *fn) {
    if (groups_init(&u->g, X) < 0) return -1;
    if (!PyList_Check(sorted) || PyList_GET_SIZE(sorted) < X) {
        PyErr_Format(PyExc_TypeError,
                     "%s(): expected sorted to be a list of X=%zd (order, key) pairs, got %s", fn,
                     X, Py_TYPE(sorted)->tp_name);
        return -1;
    }
    for (Py_ssize_t i = 0; i < B; i++) {
        const int64_t x = u->rows_x[i];
        if (!row_x_ok(fn, i, x, X)) return -1;
        if (u->g.got[x]) continue;
        Py_buffer *order = &u->g.buf[2 * x], *key = &u->g.buf[2 * x + 1];
        PyObject *pair = PyList_GET_ITEM(sorted, x);
        if (!PyTuple_Check(pair) || PyTuple_GET_SIZE(pair) != 2) {
            PyErr_Format(PyExc_TypeError,
                         "%s(): expected sorted[%lld] to be an (order, key) pair, got %s", fn,
                         (long long)x, Py_TYPE(pair)->tp_name);
            return -1;
        }
        if (get_buffer(PyTuple_GET_ITEM(pair, 0), order, 1, 'q', "order", 0) < 0) return -1;
        if (get_buffer(PyTuple_GET_ITEM(pair, 1), key, 1, 'd', "key", 0) < 0) {
            PyBuffer_Release(order);
            return -1;
        }
        u->g.got[x] = 1;
        if (key->shape[0] != order->shape[0] ||
            !points_in_range(order->buf, order->shape[0], u->off, u->wid, cap, E)) {
            PyErr_Format(PyExc_IndexError,
                         "%s(): observed value %lld: a point is out of range, or order and key "
                         "differ in length",
                         fn, (long long)x);
            return -1;
        }
    }
    return 0;
}

/* V_up of row i at its own x. */
static double saw_value(saw_t *u, Py_ssize_t i) {
    const int64_t x = u->rows_x[i];
    const double *b = u->rows + i * u->Y, *c = u->corner + x * u->Y;
    double base = 0.0, mass = 0.0;
    uint64_t row_sig = 0;
    for (Py_ssize_t y = 0; y < u->Y; y++) {
        base += b[y] * c[y];
        mass += b[y];
        if (b[y] != 0.0) row_sig |= SIG_BIT(y);
    }
    const Py_buffer *order = &u->g.buf[2 * x], *key = &u->g.buf[2 * x + 1];
    const Py_ssize_t P = order->shape[0];
    if (P == 0) return base;
    return base + sawtooth_row(b, u->Y, mass, order->buf, P, key->buf, u->idx, u->inv, u->off,
                               u->wid, u->gain, NULL, u->sig, row_sig, (uint64_t)u->Y, 0,
                               &u->stray);
}

/* Re-bound action a's possible children (rows lo..hi of nz) into up, return its Q_up. */
static double refresh(saw_t *u, const int64_t *nz, Py_ssize_t lo, Py_ssize_t hi,
                      Py_ssize_t a, Py_ssize_t n, double *up, double reward, double gamma) {
    double *blk = up + a * n;
    memset(blk, 0, (size_t)n * sizeof(double));
    for (Py_ssize_t i = lo; i < hi; i++) up[nz[i]] = saw_value(u, i);
    double s = 0.0;
    for (Py_ssize_t j = 0; j < n; j++) s += blk[j];
    return reward + gamma * s;
}

/* bound_children()'s work (see the header): from the m possible children's lower bounds
 * (low_r, best_r; row m is b), every child's bounds, Q_low and Q_up, the sawtooth read
 * through u lazily when stale_q is given (stale_up then (C,)). ends (A + 1,) and fresh (A,)
 * are scratch. Returns V_up(b). */
static double bound_core(saw_t *u, const int64_t *nz, Py_ssize_t m, const double *low_r,
                         const int64_t *best_r, const double *reward, const double *stale_q,
                         const double *stale_up, Py_ssize_t A, Py_ssize_t C, double *low,
                         int64_t *best, double *q_low, double *up, double *q_up, double gamma,
                         Py_ssize_t *ends, char *fresh) {
    const Py_ssize_t n = C / A;
    /* the lower bounds of every child (0 where impossible) and Q_low */
    memset(low, 0, (size_t)C * sizeof(double));
    memset(best, 0, (size_t)C * sizeof(int64_t));
    for (Py_ssize_t i = 0; i < m; i++) {
        low[nz[i]] = low_r[i];
        best[nz[i]] = best_r[i];
    }
    for (Py_ssize_t a = 0; a < A; a++) {
        double s = 0.0;
        for (Py_ssize_t j = 0; j < n; j++) s += low[a * n + j];
        q_low[a] = reward[a] + gamma * s;
    }
    /* action a's possible children: entries ends[a] to ends[a + 1] of nz (nz increases) */
    Py_ssize_t i = 0;
    for (Py_ssize_t a = 0; a <= A; a++) {
        while (i < m && nz[i] < a * n) i++;
        ends[a] = i;
    }
    double cu;
    if (stale_q == NULL) {
        for (Py_ssize_t a = 0; a < A; a++)
            q_up[a] = refresh(u, nz, ends[a], ends[a + 1], a, n, up, reward[a], gamma);
        cu = saw_value(u, m);
    } else {
        /* the lazy loop of _SARSOP._upper_np: refresh the best stale action while it beats
         * every fresh one (ties within 1e-12 relative go to the lowest index) */
        memmove(q_up, stale_q, (size_t)A * sizeof(double)); /* (the same record: in place) */
        memmove(up, stale_up, (size_t)C * sizeof(double));
        for (Py_ssize_t a = 0; a < A; a++) fresh[a] = 0;
        int have_top = 0;
        double top = 0.0;
        cu = saw_value(u, m); /* V_up(b) itself, whatever the loop refreshes */
        for (;;) {
            double over = 0.0, hi = -INFINITY;
            int any = 0;
            if (have_top) over = top + 1e-12 * fmax(1.0, fabs(top));
            for (Py_ssize_t a = 0; a < A; a++)
                if (!have_top || (!fresh[a] && q_up[a] > over)) {
                    if (!any || q_up[a] > hi) hi = q_up[a];
                    any = 1;
                }
            if (!any) break;
            const double floor_ = hi - 1e-12 * fmax(1.0, fabs(hi));
            Py_ssize_t pick = -1;
            for (Py_ssize_t a = 0; a < A && pick < 0; a++)
                if ((!have_top || (!fresh[a] && q_up[a] > over)) && q_up[a] >= floor_) pick = a;
            if (pick < 0) break; /* NaN values: nothing compares */
            q_up[pick] = refresh(u, nz, ends[pick], ends[pick + 1], pick, n, up, reward[pick],
                                 gamma);
            fresh[pick] = 1;
            top = have_top ? fmax(top, q_up[pick]) : q_up[pick];
            have_top = 1;
        }
    }
    return cu;
}

static PyObject *bound_children(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 20 };
    static const spec_t spec[NB] = {
        {"rows", 2, 'd', 0},     {"rows_x", 1, 'q', 0},  {"nz", 1, 'q', 0},
        {"low_r", 1, 'd', 0},    {"best_r", 1, 'q', 0},  {"reward", 1, 'd', 0},
        {"stale_q", 1, 'd', 0},  {"stale_up", 1, 'd', 0}, {"corner", 2, 'd', 0},
        {"idx", 1, 'q', 0},      {"inv", 1, 'd', 0},     {"off", 1, 'q', 0},
        {"wid", 1, 'q', 0},      {"gain", 1, 'd', 0},    {"sig", 1, 'q', 0},
        {"low", 1, 'd', 1},      {"best", 1, 'q', 1},    {"q_low", 1, 'd', 1},
        {"up", 1, 'd', 1},       {"q_up", 1, 'd', 1},
    };
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB + 2) {
        PyErr_Format(PyExc_TypeError, "bound_children() takes %d arguments (%zd given)", NB + 2,
                     nargs);
        return NULL;
    }
    const double gamma = PyFloat_AsDouble(args[NB + 1]);
    if (gamma == -1.0 && PyErr_Occurred()) return NULL;
    PyObject *arrays[NB];
    for (int k = 0; k < NB; k++) arrays[k] = args[k < 9 ? k : k + 1]; /* args[9]: sorted */
    PyObject *sorted = args[9];
    if (get_all(arrays, v, spec, NB) < 0) return NULL;
    const Py_ssize_t m = v[2].shape[0], S = v[0].shape[1], A = v[5].shape[0];
    const Py_ssize_t C = v[15].shape[0], X = v[8].shape[0], E = v[9].shape[0];
    const Py_ssize_t cap = v[11].shape[0];
    const int stale = v[6].shape[0] > 0;
    const char *bad = NULL;
    if (A == 0 || C % A != 0 || m > C)
        bad = "C children (low's length), a multiple of A actions (reward's), at least m";
    else if (v[0].shape[0] != m + 1 || v[1].shape[0] != m + 1 || v[3].shape[0] != m + 1 ||
             v[4].shape[0] != m + 1)
        bad = "m + 1 rows, rows_x, low_r and best_r for m possible children (nz's length)";
    else if (v[16].shape[0] != C || v[18].shape[0] != C || v[17].shape[0] != A ||
             v[19].shape[0] != A)
        bad = "best and up of C entries, q_low and q_up of A";
    else if (stale ? (v[6].shape[0] != A || v[7].shape[0] != C) : v[7].shape[0] != 0)
        bad = "stale_q (A,) and stale_up (C,), or both empty";
    else if (v[8].shape[1] != S)
        bad = "corner of (X, S) entries (S the rows' width)";
    else if (v[10].shape[0] != E || v[12].shape[0] != cap || v[13].shape[0] != cap ||
             (v[14].shape[0] != 0 && v[14].shape[0] != cap))
        bad = "the sawtooth storage of _sawtooth.corrections";
    if (bad != NULL) {
        PyErr_Format(PyExc_ValueError, "bound_children(): inconsistent shapes: expected %s", bad);
        release_all(v, NB);
        return NULL;
    }
    const int64_t *nz = v[2].buf;
    for (Py_ssize_t i = 0; i < m; i++)
        if (nz[i] < 0 || nz[i] >= C || (i > 0 && nz[i] <= nz[i - 1])) {
            PyErr_SetString(PyExc_IndexError,
                            "bound_children(): nz must increase strictly within [0, C)");
            release_all(v, NB);
            return NULL;
        }
    saw_t u = {v[0].buf, v[8].buf, v[10].buf, v[13].buf, v[1].buf, v[9].buf, v[11].buf,
               v[12].buf, v[14].shape[0] > 0 ? v[14].buf : NULL, S, {NULL, NULL, 0}, 0};
    if (saw_take(&u, sorted, X, m + 1, cap, E, "bound_children") < 0) {
        groups_release(&u.g);
        release_all(v, NB);
        return NULL;
    }
    Py_ssize_t *ends = PyMem_Malloc((size_t)(A + 1) * sizeof(Py_ssize_t));
    char *fresh = PyMem_Malloc((size_t)A);
    if (ends == NULL || fresh == NULL) {
        PyMem_Free(ends);
        PyMem_Free(fresh);
        groups_release(&u.g);
        release_all(v, NB);
        return PyErr_NoMemory();
    }
    const double cu = bound_core(&u, nz, m, v[3].buf, v[4].buf, v[5].buf,
                                 stale ? v[6].buf : NULL, v[7].buf, A, C, v[15].buf, v[16].buf,
                                 v[17].buf, v[18].buf, v[19].buf, gamma, ends, fresh);
    PyMem_Free(ends);
    PyMem_Free(fresh);
    groups_release(&u.g);
    release_all(v, NB);
    if (u.stray) {
        PyErr_SetString(PyExc_IndexError, "bound_children(): a support index is out of range");
        return NULL;
    }
    return PyFloat_FromDouble(cu);
}


/* The new vector of action a (see backup_vector() above) into out (Y,): the reward r[y] is
 * t->RT[y * r_stride] (backup_vector: r itself, stride 1; backup_one: RT's column a, stride
 * A). vals is (K Y,) scratch. */
static void vector_core(const tables_t *t, Py_ssize_t a, Py_ssize_t r_stride, const double *V,
                        const int64_t *use, double gamma, double *out, double *vals) {
    const Py_ssize_t K = t->K, O = t->O, Y = t->Y;
    const double *tx = t->tx, *ty = t->tyk, *z = t->z, *r = t->RT;
    /* vals[k, y2] = sum_o Z[a, k, o, y2] alpha_{k, o}[y2] */
    memset(vals, 0, (size_t)(K * Y) * sizeof(double));
    for (Py_ssize_t k = 0; k < K; k++) {
        double *vk = vals + k * Y;
        for (Py_ssize_t o = 0; o < O; o++) {
            const double *zo = z + ((a * K + k) * O + o) * Y, *w = V + use[k * O + o] * Y;
            for (Py_ssize_t y = 0; y < Y; y++) vk[y] += zo[y] * w[y];
        }
    }
    /* out[y] = r[y] + gamma sum_k Tx[a, y, k] (Ty[a, k, y] . vals[k]) (Tx: 1 without tx, Ty:
     * the identity without tyk) */
    for (Py_ssize_t y = 0; y < Y; y++) {
        double acc = 0.0;
        for (Py_ssize_t k = 0; k < K; k++) {
            const double *vk = vals + k * Y;
            double inner;
            if (ty != NULL) {
                const double *row = ty + ((a * K + k) * Y + y) * Y;
                inner = 0.0;
                for (Py_ssize_t y2 = 0; y2 < Y; y2++) inner += row[y2] * vk[y2];
            } else {
                inner = vk[y];
            }
            acc += tx != NULL ? tx[(a * Y + y) * K + k] * inner : inner;
        }
        out[y] = r[y * r_stride] + gamma * acc;
    }
}

static PyObject *backup_vector(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 7 };
    static const spec_t spec[NB] = {
        {"tx", 3, 'd', 0}, {"tyk", 4, 'd', 0}, {"z", 4, 'd', 0},   {"r", 1, 'd', 0},
        {"V", 2, 'd', 0},  {"use", 1, 'q', 0}, {"out", 1, 'd', 1},
    };
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB + 2) {
        PyErr_Format(PyExc_TypeError, "backup_vector() takes %d arguments (%zd given)", NB + 2,
                     nargs);
        return NULL;
    }
    const Py_ssize_t a = PyNumber_AsSsize_t(args[6], PyExc_OverflowError);
    if (a == -1 && PyErr_Occurred()) return NULL;
    const double gamma = PyFloat_AsDouble(args[7]);
    if (gamma == -1.0 && PyErr_Occurred()) return NULL;
    PyObject *const arrays[NB] = {args[0], args[1], args[2], args[3], args[4], args[5], args[8]};
    if (get_all(arrays, v, spec, NB) < 0) return NULL;
    const Py_ssize_t A = v[2].shape[0], K = v[2].shape[1], O = v[2].shape[2], Y = v[2].shape[3];
    const Py_ssize_t N = v[4].shape[0];
    const int has_tx = v[0].shape[0] > 0, has_ty = v[1].shape[0] > 0;
    const char *bad = NULL;
    if (has_tx && (v[0].shape[0] != A || v[0].shape[1] != Y || v[0].shape[2] != K))
        bad = "tx (A, Y, K) or empty";
    else if (!has_tx && K != 1)
        bad = "tx (A, Y, K) when K > 1";
    else if (has_ty && (v[1].shape[0] != A || v[1].shape[1] != K || v[1].shape[2] != Y ||
                        v[1].shape[3] != Y))
        bad = "tyk (A, K, Y, Y) or empty";
    else if (v[3].shape[0] != Y || v[4].shape[1] != Y || v[5].shape[0] != K * O ||
             v[6].shape[0] != Y)
        bad = "r (Y,), V (N, Y), use (K O,) and out (Y,)";
    if (bad != NULL) {
        PyErr_Format(PyExc_ValueError,
                     "backup_vector(): inconsistent shapes for z (A=%zd, K=%zd, O=%zd, Y=%zd): "
                     "expected %s",
                     A, K, O, Y, bad);
        release_all(v, NB);
        return NULL;
    }
    const int64_t *use = v[5].buf;
    if (a < 0 || a >= A) bad = "the action";
    for (Py_ssize_t i = 0; i < K * O && bad == NULL; i++)
        if (use[i] < 0 || use[i] >= N) bad = "a vector index in use";
    if (bad != NULL) {
        PyErr_Format(PyExc_IndexError, "backup_vector(): %s is out of range", bad);
        release_all(v, NB);
        return NULL;
    }
    double *vals = PyMem_Malloc((size_t)(K * Y > 0 ? K * Y : 1) * sizeof(double));
    if (vals == NULL) {
        release_all(v, NB);
        return PyErr_NoMemory();
    }
    const tables_t t = {has_tx ? v[0].buf : NULL, has_ty ? v[1].buf : NULL, v[2].buf, v[3].buf,
                        NULL, A, K, O, Y};
    vector_core(&t, a, 1, v[4].buf, use, gamma, v[6].buf, vals);
    PyMem_Free(vals);
    release_all(v, NB);
    Py_RETURN_NONE;
}

static PyObject *propagate_inactive(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Py_buffer par, act;
    (void)self;
    if (nargs != 2) {
        PyErr_Format(PyExc_TypeError, "propagate_inactive() takes 2 arguments (%zd given)",
                     nargs);
        return NULL;
    }
    if (get_buffer(args[0], &par, 1, 'q', "parent", 0) < 0) return NULL;
    if (PyObject_GetBuffer(args[1], &act, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_WRITABLE) <
        0) {
        PyErr_Clear();
        PyErr_Format(PyExc_TypeError, "expected active to be a writable C-contiguous 1-D bool "
                                      "array, got %s", Py_TYPE(args[1])->tp_name);
        PyBuffer_Release(&par);
        return NULL;
    }
    const Py_ssize_t n = par.shape[0];
    const char *f = act.format ? act.format : "B";
    if (act.ndim != 1 || act.itemsize != 1 || f[0] != '?' || f[1] != 0 || act.shape[0] < n) {
        PyErr_Format(PyExc_ValueError,
                     "propagate_inactive(): expected active a 1-D bool array of at least %zd "
                     "entries (parent's), got format '%s', %d dims",
                     n, f, act.ndim);
        PyBuffer_Release(&par);
        PyBuffer_Release(&act);
        return NULL;
    }
    const int64_t *parent = par.buf;
    char *active = act.buf;
    for (Py_ssize_t i = 0; i < n; i++) {
        const int64_t p = parent[i];
        if (p >= i) {
            PyErr_Format(PyExc_ValueError,
                         "propagate_inactive(): node %zd has parent %lld: a parent must come "
                         "before its children",
                         i, (long long)p);
            PyBuffer_Release(&par);
            PyBuffer_Release(&act);
            return NULL;
        }
        if (p >= 0 && !active[p]) active[i] = 0;
    }
    PyBuffer_Release(&par);
    PyBuffer_Release(&act);
    Py_RETURN_NONE;
}

/* Take x's index array from the list gid into g (once; the caller releases g), checked: at
 * least n >= 1 indices in [0, N). -1 with a ValueError naming fn otherwise. */
static int take_group(groups_t *g, PyObject *gid, int64_t x, int64_t n, Py_ssize_t N,
                      const char *fn) {
    Py_buffer *ids = &g->buf[2 * x];
    if (g->got[x]) return 0;
    if (get_buffer(PyList_GET_ITEM(gid, x), ids, 1, 'q', "gid[x]", 0) < 0) return -1;
    g->got[x] = 1;
    int ok = ids->shape[0] >= n && n >= 1;
    for (int64_t j = 0; j < n && ok; j++) {
        const int64_t id = ((const int64_t *)ids->buf)[j];
        ok = id >= 0 && id < N;
    }
    if (ok) return 0;
    PyErr_Format(PyExc_ValueError,
                 "%s(): observed value %lld: expected gid[x] of at least n=%lld >= 1 vector "
                 "indices in [0, %zd), got %zd entries",
                 fn, (long long)x, (long long)n, N, ids->shape[0]);
    return -1;
}

/* The best score max_j b . V[id[j]] over the n vectors id (n >= 1), and its position *arg
 * (the first maximum, as numpy's argmax; a NaN score wins as there). b (W,) is given on the
 * columns cols of V (N, Y) (NULL: W = Y, every column); supp is (W,) scratch. */
static double score_row(const double *b, Py_ssize_t W, const int64_t *cols, const double *V,
                        Py_ssize_t Y, const int64_t *id, int64_t n, Py_ssize_t *supp,
                        int64_t *arg) {
    /* the row's support, in column order: each vector's score is the sum over it, in that
     * order (the same floats as the column-by-column sum of the former per-x column blocks) */
    Py_ssize_t m = 0;
    for (Py_ssize_t q = 0; q < W; q++)
        if (b[q] != 0.0) supp[m++] = q;
    double top = 0.0;
    *arg = 0;
    for (int64_t j0 = 0; j0 < n; j0 += 4) {
        /* four vectors at a time: four independent sums (each in support order) */
        double s4[4] = {0.0, 0.0, 0.0, 0.0};
        const int64_t nj = n - j0 < 4 ? n - j0 : 4;
        const double *r0 = V + id[j0] * Y, *r1 = nj > 1 ? V + id[j0 + 1] * Y : r0;
        const double *r2 = nj > 2 ? V + id[j0 + 2] * Y : r0;
        const double *r3 = nj > 3 ? V + id[j0 + 3] * Y : r0;
        for (Py_ssize_t k = 0; k < m; k++) {
            const Py_ssize_t q = supp[k], c = cols != NULL ? cols[q] : q;
            const double w = b[q];
            s4[0] += w * r0[c];
            s4[1] += w * r1[c];
            s4[2] += w * r2[c];
            s4[3] += w * r3[c];
        }
        for (int64_t t = 0; t < nj; t++) {
            const double sc = s4[t];
            const int64_t j = j0 + t;
            if (j == 0) {
                top = sc;
                if (top != top) return top; /* NaN: numpy's argmax takes the first */
            } else if (sc != sc) {
                *arg = j;
                return sc;
            } else if (sc > top) {
                top = sc;
                *arg = j;
            }
        }
    }
    return top;
}

static PyObject *group_scores(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 7 };
    static const spec_t spec[NB] = {
        {"rows", 2, 'd', 0}, {"rows_x", 1, 'q', 0}, {"V", 2, 'd', 0}, {"cols", 1, 'q', 0},
        {"gn", 1, 'q', 0},   {"val", 1, 'd', 1},    {"best", 1, 'q', 1},
    };
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB + 1) {
        PyErr_Format(PyExc_TypeError, "group_scores() takes %d arguments (%zd given)", NB + 1,
                     nargs);
        return NULL;
    }
    PyObject *const arrays[NB] = {args[0], args[1], args[2], args[3], args[5], args[6], args[7]};
    PyObject *gid = args[4];
    if (!PyList_Check(gid)) {
        PyErr_Format(PyExc_TypeError, "group_scores(): expected gid to be a list of arrays, got %s",
                     Py_TYPE(gid)->tp_name);
        return NULL;
    }
    if (get_all(arrays, v, spec, NB) < 0) return NULL;
    const Py_ssize_t B = v[1].shape[0], W = v[0].shape[1], X = v[4].shape[0];
    const Py_ssize_t N = v[2].shape[0], Y = v[2].shape[1], ncols = v[3].shape[0];
    const Py_ssize_t step = v[0].shape[0] == 1 ? 0 : W; /* one row: scored at every x */
    const int64_t *cols = v[3].buf;
    const char *bad = NULL;
    if ((v[0].shape[0] != B && v[0].shape[0] != 1) || v[5].shape[0] != B || v[6].shape[0] != B)
        bad = "rows of B rows (rows_x's length) or one, val and best of B entries";
    else if (ncols > 0 ? W != ncols : W != Y)
        bad = "rows of V's width, or of cols' length where cols is given";
    else if (PyList_GET_SIZE(gid) < X)
        bad = "gid of at least X entries (gn's length)";
    for (Py_ssize_t q = 0; q < ncols && bad == NULL; q++)
        if (cols[q] < 0 || cols[q] >= Y) bad = "cols within V's width";
    if (bad != NULL) {
        PyErr_Format(PyExc_ValueError,
                     "group_scores(): expected %s (B=%zd, rows (%zd, %zd), V (%zd, %zd), %zd "
                     "cols)",
                     bad, B, v[0].shape[0], W, N, Y, ncols);
        release_all(v, NB);
        return NULL;
    }
    groups_t g; /* each group's index array is taken once, on its first row (buf[2 x]) */
    Py_ssize_t *supp = PyMem_Malloc((size_t)(W > 0 ? W : 1) * sizeof(Py_ssize_t));
    int failed = supp == NULL ? (PyErr_NoMemory(), 1) : 0;
    if (!failed) failed = groups_init(&g, X) < 0;
    const double *rows = v[0].buf, *V = v[2].buf;
    const int64_t *rows_x = v[1].buf, *gn = v[4].buf;
    double *val = v[5].buf;
    int64_t *best = v[6].buf;
    for (Py_ssize_t i = 0; i < B && !failed; i++) {
        const int64_t x = rows_x[i];
        if (!row_x_ok("group_scores", i, x, X)) {
            failed = 1;
            break;
        }
        const int64_t n = gn[x];
        if (take_group(&g, gid, x, n, N, "group_scores") < 0) {
            failed = 1;
            break;
        }
        const int64_t *id = g.buf[2 * x].buf;
        int64_t arg = 0;
        const double top = score_row(rows + i * step, W, ncols > 0 ? cols : NULL, V, Y, id, n,
                                     supp, &arg);
        val[i] = top;
        best[i] = id[arg];
    }
    if (supp != NULL) groups_release(&g);
    PyMem_Free(supp);
    release_all(v, NB);
    if (failed) return NULL;
    Py_RETURN_NONE;
}

static PyObject *gather_columns(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 3 };
    static const spec_t spec[NB] = {{"V", 2, 'd', 0}, {"cols", 1, 'q', 0}, {"out", 2, 'd', 1}};
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB) {
        PyErr_Format(PyExc_TypeError, "gather_columns() takes %d arguments (%zd given)", NB,
                     nargs);
        return NULL;
    }
    if (get_all(args, v, spec, NB) < 0) return NULL;
    const Py_ssize_t N = v[0].shape[0], Y = v[0].shape[1], c = v[1].shape[0];
    const Py_ssize_t n = v[2].shape[1];
    const int64_t *cols = v[1].buf;
    const char *bad = NULL;
    if (v[2].shape[0] != c || n > N) bad = "out (len(cols), n) with n <= V's rows";
    for (Py_ssize_t q = 0; q < c && bad == NULL; q++)
        if (cols[q] < 0 || cols[q] >= Y) bad = "cols within V's width";
    if (bad != NULL) {
        PyErr_Format(PyExc_ValueError,
                     "gather_columns(): expected %s (V (%zd, %zd), %zd cols, out (%zd, %zd))",
                     bad, N, Y, c, v[2].shape[0], n);
        release_all(v, NB);
        return NULL;
    }
    const double *V = v[0].buf;
    double *out = v[2].buf;
    /* vector by vector (each row of V read once, along the columns asked for) */
    for (Py_ssize_t j = 0; j < n; j++) {
        const double *r = V + j * Y;
        for (Py_ssize_t q = 0; q < c; q++) out[q * n + j] = r[cols[q]];
    }
    release_all(v, NB);
    Py_RETURN_NONE;
}

static PyObject *group_upper(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 10 };
    static const spec_t spec[NB] = {
        {"rows", 2, 'd', 0}, {"rows_x", 1, 'q', 0}, {"corner", 2, 'd', 0}, {"idx", 1, 'q', 0},
        {"inv", 1, 'd', 0},  {"off", 1, 'q', 0},    {"wid", 1, 'q', 0},    {"gain", 1, 'd', 0},
        {"sig", 1, 'q', 0},  {"out", 1, 'd', 1},
    };
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB + 1) {
        PyErr_Format(PyExc_TypeError, "group_upper() takes %d arguments (%zd given)", NB + 1,
                     nargs);
        return NULL;
    }
    PyObject *const arrays[NB] = {args[0], args[1], args[2], args[4], args[5],
                                  args[6], args[7], args[8], args[9], args[10]};
    if (get_all(arrays, v, spec, NB) < 0) return NULL;
    const Py_ssize_t B = v[0].shape[0], Y = v[0].shape[1], X = v[2].shape[0];
    const Py_ssize_t E = v[3].shape[0], cap = v[5].shape[0];
    if (v[1].shape[0] != B || v[9].shape[0] != B || v[2].shape[1] != Y || v[4].shape[0] != E ||
        v[6].shape[0] != cap || v[7].shape[0] != cap ||
        (v[8].shape[0] != 0 && v[8].shape[0] != cap)) {
        PyErr_Format(PyExc_ValueError,
                     "group_upper(): inconsistent shapes: expected rows (B, Y), rows_x and out "
                     "(B,), corner (X, Y), the sawtooth storage of _sawtooth.corrections "
                     "(B=%zd, Y=%zd)",
                     B, Y);
        release_all(v, NB);
        return NULL;
    }
    saw_t u = {v[0].buf, v[2].buf, v[4].buf, v[7].buf, v[1].buf, v[3].buf, v[5].buf,
               v[6].buf, v[8].shape[0] > 0 ? v[8].buf : NULL, Y, {NULL, NULL, 0}, 0};
    const int failed = saw_take(&u, args[3], X, B, cap, E, "group_upper") < 0;
    double *out = v[9].buf;
    for (Py_ssize_t i = 0; i < B && !failed; i++) out[i] = saw_value(&u, i);
    groups_release(&u.g);
    release_all(v, NB);
    if (failed) return NULL;
    if (u.stray) {
        PyErr_SetString(PyExc_IndexError, "group_upper(): a support index is out of range");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* backup_one(): children(), the rows' lower bounds (score_row against each row's own x's
 * vectors), bound_children() and, where out is given, the new vector of the action of highest
 * Q_low: one call per backup of a dense model's belief (see backup_kernel.backup_one). */
static PyObject *backup_one(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 22 };
    static const spec_t spec[NB] = {
        {"b", 1, 'd', 0},      {"tx", 3, 'd', 0},     {"tyk", 4, 'd', 0},    {"z", 4, 'd', 0},
        {"RT", 2, 'd', 0},     {"cx", 1, 'q', 0},     {"rows", 2, 'd', 1},   {"rows_x", 1, 'q', 1},
        {"nz", 1, 'q', 1},     {"V", 2, 'd', 0},      {"gn", 1, 'q', 0},     {"corner", 2, 'd', 0},
        {"idx", 1, 'q', 0},    {"inv", 1, 'd', 0},    {"off", 1, 'q', 0},    {"wid", 1, 'q', 0},
        {"gain", 1, 'd', 0},   {"sig", 1, 'q', 0},    {"stale", 1, 'd', 0},  {"record", 1, 'd', 1},
        {"best", 1, 'q', 1},   {"out", 1, 'd', 1},
    };
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB + 4) {
        PyErr_Format(PyExc_TypeError, "backup_one() takes %d arguments (%zd given)", NB + 4,
                     nargs);
        return NULL;
    }
    /* args: b, tx, tyk, z, RT, cx, rows, rows_x, nz, V, gid, gn, corner, sorted, idx .. sig,
     * stale, record, best, out, x, gamma */
    PyObject *arrays[NB];
    for (int k = 0; k < NB; k++) arrays[k] = args[k < 10 ? k : (k < 12 ? k + 1 : k + 2)];
    PyObject *gid = args[10], *sorted = args[13];
    const Py_ssize_t x = PyNumber_AsSsize_t(args[NB + 2], PyExc_OverflowError);
    if (x == -1 && PyErr_Occurred()) return NULL;
    const double gamma = PyFloat_AsDouble(args[NB + 3]);
    if (gamma == -1.0 && PyErr_Occurred()) return NULL;
    if (!PyList_Check(gid)) {
        PyErr_Format(PyExc_TypeError, "backup_one(): expected gid to be a list of arrays, got %s",
                     Py_TYPE(gid)->tp_name);
        return NULL;
    }
    if (get_all(arrays, v, spec, NB) < 0) return NULL;
    const tables_t t = tables_of(v);
    const Py_ssize_t A = t.A, K = t.K, O = t.O, Y = t.Y, C = A * K * O, R = 2 * A + 3 * C;
    const Py_ssize_t N = v[9].shape[0], X = v[10].shape[0], E = v[12].shape[0];
    const Py_ssize_t cap = v[14].shape[0];
    const int stale = v[18].shape[0] > 0, vector = v[21].shape[0] > 0;
    const char *bad = children_shapes(v, C, v[8].shape[0], A);
    if (bad == NULL && A == 0)
        bad = "at least one action";
    else if (bad == NULL && (v[9].shape[1] != Y || v[11].shape[0] != X || v[11].shape[1] != Y))
        bad = "V (N, Y) and corner (X, Y), X gn's length";
    else if (bad == NULL && PyList_GET_SIZE(gid) < X)
        bad = "gid of at least X entries (gn's length)";
    else if (bad == NULL && (v[13].shape[0] != E || v[15].shape[0] != cap ||
                             v[16].shape[0] != cap || (v[17].shape[0] != 0 && v[17].shape[0] != cap)))
        bad = "the sawtooth storage of _sawtooth.corrections";
    else if (bad == NULL && stale && v[18].shape[0] != R)
        bad = "stale, a record (2 A + 3 A K O,), or empty";
    else if (bad == NULL && (v[19].shape[0] != R || v[20].shape[0] != C ||
                             (vector && v[21].shape[0] != Y)))
        bad = "record (2 A + 3 A K O,), best (A K O,), out (Y,) or empty";
    if (bad != NULL) {
        children_shape_error("backup_one", v, bad);
        release_all(v, NB);
        return NULL;
    }
    if (x < 0 || x >= X) {
        PyErr_Format(PyExc_IndexError, "backup_one(): x=%zd is outside [0, %zd)", x, X);
        release_all(v, NB);
        return NULL;
    }
    const size_t Y1 = (size_t)(Y > 0 ? Y : 1);
    double *pred = PyMem_Malloc(Y1 * sizeof(double));
    Py_ssize_t *supp = PyMem_Malloc(Y1 * sizeof(Py_ssize_t));
    double *low_r = PyMem_Malloc((size_t)(C + 1) * sizeof(double));
    int64_t *best_r = PyMem_Malloc((size_t)(C + 1) * sizeof(int64_t));
    Py_ssize_t *ends = PyMem_Malloc((size_t)(A + 1) * sizeof(Py_ssize_t));
    char *fresh = PyMem_Malloc((size_t)A);
    double *vals = PyMem_Malloc((size_t)(K * Y > 0 ? K * Y : 1) * sizeof(double));
    int64_t *use = PyMem_Malloc((size_t)(K * O > 0 ? K * O : 1) * sizeof(int64_t));
    double *reward = PyMem_Malloc((size_t)A * sizeof(double));
    saw_t u = {v[6].buf, v[11].buf, v[13].buf, v[16].buf, v[7].buf, v[12].buf, v[14].buf,
               v[15].buf, v[17].shape[0] > 0 ? v[17].buf : NULL, Y, {NULL, NULL, 0}, 0};
    groups_t g = {NULL, NULL, 0};
    PyObject *result = NULL;
    if (pred == NULL || supp == NULL || low_r == NULL || best_r == NULL || ends == NULL ||
        fresh == NULL || vals == NULL || use == NULL || reward == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    if (groups_init(&g, X) < 0) goto done;
    /* the record: q_low (A), q_up (A), prob, low, up (A K O each) */
    double *rec = v[19].buf;
    double *q_low = rec, *q_up = rec + A, *prob = rec + 2 * A;
    double *low = prob + C, *up = prob + 2 * C;
    const double *st = v[18].buf;
    const double *b = v[0].buf, *V = v[9].buf;
    double *rows = v[6].buf;
    const int64_t *rows_x = v[7].buf, *gn = v[10].buf, *best = v[20].buf;
    const Py_ssize_t m = children_core(&t, b, x, rows, v[7].buf, prob, v[8].buf, reward, pred,
                                       supp);
    /* each row's lower bound among its own x's vectors (row m: b itself) */
    for (Py_ssize_t i = 0; i <= m; i++) {
        const int64_t xi = rows_x[i];
        if (!row_x_ok("backup_one", i, xi, X) || take_group(&g, gid, xi, gn[xi], N, "backup_one") < 0)
            goto done;
        const int64_t *id = g.buf[2 * xi].buf;
        int64_t arg;
        low_r[i] = score_row(rows + i * Y, Y, NULL, V, Y, id, gn[xi], supp, &arg);
        best_r[i] = id[arg];
    }
    if (saw_take(&u, sorted, X, m + 1, cap, E, "backup_one") < 0) goto done;
    const double cu = bound_core(&u, v[8].buf, m, low_r, best_r, reward,
                                 stale ? st + A : NULL, stale ? st + 2 * A + 2 * C : NULL, A, C,
                                 low, v[20].buf, q_low, up, q_up, gamma, ends, fresh);
    if (u.stray) {
        PyErr_SetString(PyExc_IndexError, "backup_one(): a support index is out of range");
        goto done;
    }
    Py_ssize_t a = -1;
    double nl = NAN;
    if (vector) {
        /* the action of highest Q_low (the first, as numpy's argmax) */
        a = 0;
        for (Py_ssize_t j = 1; j < A; j++)
            if (q_low[j] > q_low[a] || (q_low[j] != q_low[j] && q_low[a] == q_low[a])) a = j;
        /* each child's vector: its best where possible; at an impossible child, the best of
         * its x2's vectors at b itself (APPL's getBestAlphaPlane of b under x2; b's own where
         * x2 = x), one score per x2 */
        for (Py_ssize_t k = 0; k < K; k++) {
            int64_t fill = -1;
            for (Py_ssize_t o = 0; o < O; o++) {
                const Py_ssize_t c = (a * K + k) * O + o;
                if (prob[c] > 0.0) {
                    use[k * O + o] = best[c];
                    continue;
                }
                if (fill < 0) {
                    const int64_t x2 = t.cx[c];
                    if (x2 == x) {
                        fill = best_r[m];
                    } else {
                        if (!row_x_ok("backup_one", c, x2, X) ||
                            take_group(&g, gid, x2, gn[x2], N, "backup_one") < 0)
                            goto done;
                        const int64_t *id = g.buf[2 * x2].buf;
                        int64_t arg;
                        score_row(b, Y, NULL, V, Y, id, gn[x2], supp, &arg);
                        fill = id[arg];
                    }
                }
                use[k * O + o] = fill;
            }
        }
        double *out = v[21].buf;
        const tables_t ta = {t.tx, t.tyk, t.z, t.RT + a, t.cx, A, K, O, Y};
        vector_core(&ta, a, A, V, use, gamma, out, vals);
        nl = 0.0;
        for (Py_ssize_t y = 0; y < Y; y++) nl += out[y] * b[y];
    }
    result = Py_BuildValue("(ndndnd)", m, low_r[m], (Py_ssize_t)best_r[m], cu, a, nl);
done:
    PyMem_Free(pred);
    PyMem_Free(supp);
    PyMem_Free(low_r);
    PyMem_Free(best_r);
    PyMem_Free(ends);
    PyMem_Free(fresh);
    PyMem_Free(vals);
    PyMem_Free(use);
    PyMem_Free(reward);
    groups_release(&u.g);
    groups_release(&g);
    release_all(v, NB);
    return result;
}

static PyObject *add_point(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 14 };
    static const spec_t spec[NB] = {
        {"b", 1, 'd', 0},     {"corner", 2, 'd', 0}, {"idx", 1, 'q', 1},     {"inv", 1, 'd', 1},
        {"px", 1, 'q', 1},    {"v", 1, 'd', 1},      {"gain", 1, 'd', 1},    {"wid", 1, 'q', 1},
        {"mass", 1, 'd', 1},  {"off", 1, 'q', 1},    {"sig", 1, 'q', 1},     {"members", 1, 'q', 1},
        {"order", 1, 'q', 1}, {"key", 1, 'd', 1},
    };
    Py_buffer v[NB];
    Py_ssize_t sc[6];
    double value;
    (void)self;
    if (nargs != NB + 6) {
        PyErr_Format(PyExc_TypeError, "add_point() takes %d arguments (%zd given)", NB + 6, nargs);
        return NULL;
    }
    for (int k = 0; k < 6; k++) {
        if (k == 1) continue;
        sc[k] = PyNumber_AsSsize_t(args[NB + k], PyExc_OverflowError);
        if (sc[k] == -1 && PyErr_Occurred()) return NULL;
    }
    value = PyFloat_AsDouble(args[NB + 1]);
    if (value == -1.0 && PyErr_Occurred()) return NULL;
    const Py_ssize_t x = sc[0], n = sc[2], start = sc[3], m = sc[4], p = sc[5];
    if (get_all(args, v, spec, NB) < 0) return NULL;
    const Py_ssize_t Y = v[0].shape[0], X = v[1].shape[0], E = v[2].shape[0];
    const Py_ssize_t cap = v[4].shape[0], cap_o = v[12].shape[0];
    const char *bad = NULL;
    if (v[1].shape[1] != Y)
        bad = "corner (X, Y) with b (Y,)";
    else if (v[3].shape[0] != E)
        bad = "inv as long as idx";
    else if (v[5].shape[0] != cap || v[6].shape[0] != cap || v[7].shape[0] != cap ||
             v[8].shape[0] != cap || v[9].shape[0] != cap || v[10].shape[0] != cap)
        bad = "px, v, gain, wid, mass, off and sig of one length";
    else if (v[13].shape[0] != cap_o)
        bad = "key as long as order";
    else if (x < 0 || x >= X)
        bad = "x in [0, X)";
    else if (n < 0 || n >= cap || start < 0 || start + Y > E)
        bad = "room for the point: n < cap and start + Y <= len(idx)";
    else if (m < 0 || m >= v[11].shape[0])
        bad = "room in members: m < its length";
    else if (p < -1 || p >= cap_o)
        bad = "room in order: -1 <= p < its length";
    if (bad != NULL) {
        PyErr_Format(PyExc_ValueError,
                     "add_point(): expected %s; got b (%zd,), corner (%zd, %zd), idx (%zd,), "
                     "px (%zd,), members (%zd,), order (%zd,), x=%zd, n=%zd, start=%zd, m=%zd, "
                     "p=%zd",
                     bad, Y, X, v[1].shape[1], E, cap, v[11].shape[0], cap_o, x, n, start, m, p);
        release_all(v, NB);
        return NULL;
    }
    const double *b = v[0].buf, *c = (const double *)v[1].buf + x * Y;
    int64_t *idx = (int64_t *)v[2].buf + start;
    double *inv = (double *)v[3].buf + start;
    Py_ssize_t w = 0, pos = -1;
    double dot = 0.0, mass = 0.0;
    uint64_t sig = 0;
    for (Py_ssize_t y = 0; y < Y; y++) {
        const double by = b[y];
        if (by == 0.0) continue;
        idx[w] = y;
        inv[w] = 1.0 / by;
        dot += c[y] * by;
        mass += by;
        sig |= SIG_BIT(y);
        w++;
    }
    if (w > 1) {
        const double g = value - dot;
        ((int64_t *)v[4].buf)[n] = x;
        ((double *)v[5].buf)[n] = value;
        ((double *)v[6].buf)[n] = g;
        ((int64_t *)v[7].buf)[n] = w;
        ((double *)v[8].buf)[n] = mass;
        ((int64_t *)v[9].buf)[n] = start;
        ((int64_t *)v[10].buf)[n] = (int64_t)sig;
        ((int64_t *)v[11].buf)[m] = n;
        if (p >= 0 && g < 0.0) {
            int64_t *order = v[12].buf;
            double *key = v[13].buf;
            const double k = g / mass;
            Py_ssize_t lo = 0, hi = p; /* the first key above k (searchsorted, side right) */
            while (lo < hi) {
                const Py_ssize_t mid = lo + (hi - lo) / 2;
                if (key[mid] <= k) lo = mid + 1;
                else hi = mid;
            }
            pos = lo;
            memmove(order + pos + 1, order + pos, (size_t)(p - pos) * sizeof(int64_t));
            memmove(key + pos + 1, key + pos, (size_t)(p - pos) * sizeof(double));
            order[pos] = n;
            key[pos] = k;
        }
    }
    release_all(v, NB);
    return Py_BuildValue("(nn)", w, pos);
}

static PyObject *trial_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Py_buffer rec;
    (void)self;
    if (nargs != 4) {
        PyErr_Format(PyExc_TypeError, "trial_step() takes 4 arguments (%zd given)", nargs);
        return NULL;
    }
    const Py_ssize_t A = PyNumber_AsSsize_t(args[1], PyExc_OverflowError);
    if (A == -1 && PyErr_Occurred()) return NULL;
    const Py_ssize_t O = PyNumber_AsSsize_t(args[2], PyExc_OverflowError);
    if (O == -1 && PyErr_Occurred()) return NULL;
    const double target = PyFloat_AsDouble(args[3]);
    if (target == -1.0 && PyErr_Occurred()) return NULL;
    if (get_buffer(args[0], &rec, 1, 'd', "record", 0) < 0) return NULL;
    const Py_ssize_t n = rec.shape[0];
    const Py_ssize_t K = (A > 0 && O > 0 && n > 2 * A) ? (n - 2 * A) / (3 * A * O) : 0;
    if (A < 1 || O < 1 || K < 1 || n != 2 * A + 3 * A * K * O) {
        PyErr_Format(PyExc_ValueError,
                     "trial_step(): expected a record of 2 A + 3 A K O entries with A >= 1, "
                     "O >= 1 and K >= 1; got %zd entries for A=%zd, O=%zd", n, A, O);
        PyBuffer_Release(&rec);
        return NULL;
    }
    const double *q_low = rec.buf, *q_up = q_low + A;
    double low_max = q_low[0], top = q_up[0];
    for (Py_ssize_t i = 1; i < A; i++) {
        if (q_low[i] > low_max) low_max = q_low[i];
        if (q_up[i] > top) top = q_up[i];
    }
    const double floor = top - 1e-12 * (fabs(top) > 1.0 ? fabs(top) : 1.0);
    Py_ssize_t a = -1, ties = 0;
    for (Py_ssize_t i = 0; i < A; i++)
        if (q_up[i] >= floor) {
            if (a < 0) a = i;
            ties++;
        }
    if (a < 0) a = 0; /* (NaN values: none compares) */
    const Py_ssize_t KO = K * O, C = A * KO;
    const double *p = q_low + 2 * A + a * KO, *lo = p + C, *up = p + 2 * C;
    Py_ssize_t j = 0;
    double best = -INFINITY;
    for (Py_ssize_t i = 0; i < KO; i++)
        if (p[i] > 0.0) {
            const double e = (up[i] - lo[i]) - target * p[i];
            if (e > best) {
                best = e;
                j = i;
            }
        }
    PyObject *out = Py_BuildValue("(dnnnnddd)", low_max, a, ties, j / O, j % O, p[j], lo[j],
                                  up[j]);
    PyBuffer_Release(&rec);
    return out;
}

/* Whether u >= v - atol at each of the Y entries (a NaN entry fails). */
static int covers(const double *u, const double *v, Py_ssize_t Y, double atol) {
    for (Py_ssize_t y = 0; y < Y; y++)
        if (!(u[y] >= v[y] - atol)) return 0;
    return 1;
}

static PyObject *dominated(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    enum { NB = 4 };
    static const spec_t spec[NB] = {
        {"V", 2, 'd', 0}, {"ids", 1, 'q', 0}, {"groups", 1, 'q', 0}, {"keep", 1, 'q', 1}};
    Py_buffer v[NB];
    (void)self;
    if (nargs != NB + 1) {
        PyErr_Format(PyExc_TypeError, "dominated() takes %d arguments (%zd given)", NB + 1,
                     nargs);
        return NULL;
    }
    const double atol = PyFloat_AsDouble(args[NB]);
    if (atol == -1.0 && PyErr_Occurred()) return NULL;
    if (get_all(args, v, spec, NB) < 0) return NULL;
    const Py_ssize_t N = v[0].shape[0], Y = v[0].shape[1], n = v[1].shape[0];
    const double *V = v[0].buf;
    const int64_t *ids = v[1].buf, *groups = v[2].buf;
    int64_t *keep = v[3].buf;
    const int grouped = v[2].shape[0] > 0;
    const char *bad = NULL;
    if (v[3].shape[0] != n || (grouped && v[2].shape[0] != n))
        bad = "keep, and groups where given, of ids' length";
    for (Py_ssize_t i = 0; i < n && bad == NULL; i++) {
        if (ids[i] < 0 || ids[i] >= N)
            bad = "ids within V's rows";
        else if (i > 0 && grouped && groups[i] < groups[i - 1])
            bad = "groups non-decreasing";
    }
    if (bad != NULL) {
        PyErr_Format(PyExc_ValueError,
                     "dominated(): expected %s (V (%zd, %zd), %zd ids, %zd groups, %zd keep)",
                     bad, N, Y, n, v[2].shape[0], v[3].shape[0]);
        release_all(v, NB);
        return NULL;
    }
    for (Py_ssize_t lo = 0; lo < n;) {
        Py_ssize_t hi = lo + 1; /* [lo, hi): one group */
        while (hi < n && (!grouped || groups[hi] == groups[lo])) hi++;
        for (Py_ssize_t i = lo; i < hi; i++) {
            const double *vi = V + ids[i] * Y;
            keep[i] = 1;
            for (Py_ssize_t j = lo; j < hi; j++) {
                if (j == i) continue;
                const double *vj = V + ids[j] * Y;
                if (covers(vj, vi, Y, atol) && (j < i || !covers(vi, vj, Y, atol))) {
                    keep[i] = 0;
                    break;
                }
            }
        }
        lo = hi;
    }
    release_all(v, NB);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"backup_one", (PyCFunction)(void (*)(void))backup_one, METH_FASTCALL,
     "A dense model's belief: children, bounds and new vector in one call (see backup_kernel)."},
    {"children", (PyCFunction)(void (*)(void))children, METH_FASTCALL,
     "Children of one belief of a dense model (see torchhrc.solvers.backup_kernel)."},
    {"bound_children", (PyCFunction)(void (*)(void))bound_children, METH_FASTCALL,
     "Bounds of one belief's children, lazily (see torchhrc.solvers.backup_kernel)."},
    {"group_scores", (PyCFunction)(void (*)(void))group_scores, METH_FASTCALL,
     "Best alpha vector of each row among its observed value's (see backup_kernel)."},
    {"gather_columns", (PyCFunction)(void (*)(void))gather_columns, METH_FASTCALL,
     "Columns of the first rows of the alpha vectors, transposed (see backup_kernel)."},
    {"group_upper", (PyCFunction)(void (*)(void))group_upper, METH_FASTCALL,
     "Sawtooth upper bound of each row at its own observed value (see backup_kernel)."},
    {"backup_vector", (PyCFunction)(void (*)(void))backup_vector, METH_FASTCALL,
     "The backed-up alpha vector of one action (see torchhrc.solvers.backup_kernel)."},
    {"add_point", (PyCFunction)(void (*)(void))add_point, METH_FASTCALL,
     "Store one sawtooth upper-bound point (see torchhrc.solvers.backup_kernel)."},
    {"trial_step", (PyCFunction)(void (*)(void))trial_step, METH_FASTCALL,
     "A trial's action and child at a node (see torchhrc.solvers.backup_kernel)."},
    {"dominated", (PyCFunction)(void (*)(void))dominated, METH_FASTCALL,
     "Alpha vectors that another of their group dominates pointwise (see backup_kernel)."},
    {"propagate_inactive", (PyCFunction)(void (*)(void))propagate_inactive, METH_FASTCALL,
     "propagate_inactive(parent, active): a node is inactive when its parent is"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_backup",
    "Compiled steps of torchhrc's one-belief SARSOP evaluation.", -1, methods,
};

PyMODINIT_FUNC PyInit__backup(void) { return PyModule_Create(&module); }
