/*
 * The compiled twin of fast_read.py's plain-block reader: the same blocks, the same
 * arithmetic in the same order, about thirty times faster.
 *
 * A 50 MB nest is two and a half million blocks. In Python each one costs a regex
 * match and a dozen objects, which caps validation near 10 MB/s; here a block is a
 * few dozen instructions. Anything this reader is not certain to read exactly as
 * fast_read.py would, it leaves: it stops at the start of that line and returns,
 * and Python reads the line (the general path decides everything unusual).
 * The differential tests compare this reader, the Python fast path and the
 * general path over generated programs, so a difference cannot hide.
 *
 * Exactness: numbers are converted as float() converts them (correctly rounded;
 * the exact fast case below, Python's own converter otherwise), the arithmetic
 * mirrors gateway/codecs/arcs.py and fast_read.py operation by operation, and the build turns
 * off FMA contraction (setup.py) so that the compiler cannot fuse a multiply-add
 * that Python rounds twice. Non-finite results are never produced here: the line
 * goes to Python instead.
 *
 * Pure: text in, numbers out. No I/O. Both functions release the GIL while they
 * read, so that a large program validated in a worker thread does not hold up
 * the gateway's event loop.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define TAU (2.0 * M_PI)
#define SAME_POINT 1e-6
#define TOLERANCE 0.005
#define M_TABLE 100 /* M codes 0..99 are looked up; larger ones go to Python */
#define N_STATE 16

/* The state fast_read._FastReader.load() hands over, as doubles (None is NaN). */
enum { PX, PY, PZ, LOX, LOY, LOZ, HIX, HIY, HIZ, MOTION, FEED, CUT_MM, RAPID_MM, CUT_S, RAPID_S, TIMED };

typedef struct {
    const unsigned char *g_ok; /* 4 flags: G0..G3 neither end nor are forbidden */
    const unsigned char *m_ok; /* M_TABLE flags */
    double unit, ox, oy, oz, rapid;
    int clamp_noted;
    PyThreadState **released; /* the GIL is released while reading; Python's converter needs it back */
} Params;

static const double POW10[23] = {
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11,
    1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
};

/* cos and sin of k * pi / 2 (k = 0..3) as libm gives them, filled in once when the module loads. */
static double COS[4], SIN[4];

static inline int is_digit(unsigned char c) { return c >= '0' && c <= '9'; }

/*
 * A number of the lexer's form at p: -?(digits{1,30}(.digits*)? | .digits+).
 * Returns the end of it, or NULL where there is none (or where this reader would
 * not be certain, such as more than 30 integer digits: the line goes to Python).
 * The value is float()'s: a mantissa of at most 2**53 over a power of ten up to
 * 1e22 is one correctly rounded division of two exact doubles; anything longer
 * goes through PyOS_string_to_double, the converter float() itself uses.
 */
static const unsigned char *
number(const unsigned char *p, const unsigned char *end, double *out, PyThreadState **released)
{
    const unsigned char *start = p;
    int negative = p < end && *p == '-';
    p += negative;
    /* The digits go into one integer; past 19 of them it wraps, and the slow path below decides. */
    uint64_t mantissa = 0;
    const unsigned char *digits = p;
    while (p < end && is_digit(*p)) {
        mantissa = mantissa * 10 + (uint64_t)(*p++ - '0');
    }
    int whole = (int)(p - digits), fraction = 0;
    if (whole > 30) {
        return NULL;
    }
    if (p < end && *p == '.') {
        digits = ++p;
        while (p < end && is_digit(*p)) {
            mantissa = mantissa * 10 + (uint64_t)(*p++ - '0');
        }
        fraction = (int)(p - digits);
        if (!whole && !fraction) {
            return NULL; /* a lone "." */
        }
    } else if (!whole) {
        return NULL;
    }
    if (whole + fraction <= 19 && mantissa <= (UINT64_C(1) << 53) && fraction <= 22) {
        double value = (double)mantissa / POW10[fraction];
        *out = negative ? -value : value;
        return p;
    }
    char buffer[128];
    size_t size = (size_t)(p - start);
    if (size >= sizeof buffer) {
        return NULL;
    }
    memcpy(buffer, start, size);
    buffer[size] = '\0';
    char *stop = NULL;
    PyEval_RestoreThread(*released);
    double value = PyOS_string_to_double(buffer, &stop, NULL);
    int failed = value == -1.0 && PyErr_Occurred();
    if (failed) {
        PyErr_Clear();
    }
    *released = PyEval_SaveThread();
    if (failed || stop != buffer + size) {
        return NULL;
    }
    *out = value;
    return p;
}

/* One plain block's words. A letter absent from the line has its flag 0. */
typedef struct {
    int g;        /* -1: no G word */
    long m;       /* -1: no M word */
    int has[8];   /* X Y Z I J R F S */
    double v[8];
} Row;

enum { WX, WY, WZ, WI, WJ, WR, WF, WS };
static const char LETTERS[] = "XYZIJRF";

/* Where the value of word `letter` begins, if the block goes on with it at p (after one optional space). */
static inline const unsigned char *
word(const unsigned char *p, const unsigned char *end, char letter)
{
    if (p < end && *p == ' ') {
        p++;
    }
    return p < end && *p == (unsigned char)letter ? p + 1 : NULL;
}

/*
 * Whether [p, end) is a plain block as fast_read._ROW reads one: upper-case words in
 * the order G X Y Z I J R F M S, each at most once, single spaces between them at
 * most, G0 to G3, M of one to nine digits, an optional CR at the end. A blank line
 * is not plain (Python reads it).
 */
static int
parse_row(const unsigned char *p, const unsigned char *end, Row *row, PyThreadState **released)
{
    if (end > p && end[-1] == '\r') {
        end--;
    }
    int any = 0;
    row->g = -1;
    row->m = -1;
    memset(row->has, 0, sizeof row->has);
    if (p < end && *p == 'G') {
        if (p + 1 >= end || p[1] < '0' || p[1] > '3') {
            return 0;
        }
        row->g = p[1] - '0';
        p += 2;
        any = 1;
    }
    const unsigned char *q;
    for (int k = 0; k < 7; k++) {
        if ((q = word(p, end, LETTERS[k])) != NULL) {
            if ((p = number(q, end, &row->v[k], released)) == NULL) {
                return 0;
            }
            row->has[k] = any = 1;
        }
    }
    if ((q = word(p, end, 'M')) != NULL) {
        long m = 0;
        int count = 0;
        for (; q < end && is_digit(*q); q++) {
            if (++count > 9) {
                return 0;
            }
            m = m * 10 + (*q - '0');
        }
        if (!count) {
            return 0;
        }
        row->m = m;
        p = q;
        any = 1;
    }
    if ((q = word(p, end, 'S')) != NULL) {
        if ((p = number(q, end, &row->v[WS], released)) == NULL) {
            return 0;
        }
        row->has[WS] = any = 1;
    }
    return any && p == end;
}

/*
 * Python's float %: the result takes the divisor's sign. fmod's result is always
 * exactly representable, so where |x| < 2|y| it is x itself or x - sign(x)|y|,
 * computed exactly by one subtraction; fmod (slow) is left for the rest.
 */
static inline double
py_mod(double x, double y)
{
    double ax = fabs(x), ay = fabs(y), mod;
    if (ax < ay) {
        mod = x;
    } else if (ax < 2.0 * ay) {
        mod = x - copysign(ay, x);
    } else {
        mod = fmod(x, y);
    }
    if (mod) {
        if ((y < 0) != (mod < 0)) {
            mod += y;
        }
    } else {
        mod = copysign(0.0, y);
    }
    return mod;
}

/* arcs.distance (gateway/codecs/arcs.py): the plain Euclidean length, as it computes it. */
static inline double
distance(double du, double dv)
{
    return sqrt(du * du + dv * dv);
}

/* An arc as arcs.PlaneArc holds it. */
typedef struct {
    double cu, cv, a0, sweep, r0, r1, dw;
    int clockwise;
} Arc;

static inline void
sweep_of(double su, double sv, double eu, double ev, double cu, double cv, Arc *arc)
{
    double a0 = atan2(sv - cv, su - cu);
    double a1 = atan2(ev - cv, eu - cu);
    double sweep;
    if (distance(su - eu, sv - ev) < SAME_POINT) {
        sweep = TAU;
    } else {
        sweep = arc->clockwise ? py_mod(a0 - a1, TAU) : py_mod(a1 - a0, TAU);
    }
    arc->a0 = a0;
    arc->sweep = sweep + TAU * 0.0; /* turns=1: sweep + TAU * (turns - 1) */
}

/*
 * fast_read._arc: the arc of a G2/G3 block in G17 with relative centres, or 0 where
 * the Python path would note or skip something (the general path then reads it).
 */
static int
make_arc(double mo, double px, double py, double pz, double tx, double ty, double tz, const Row *row,
         double unit, Arc *arc)
{
    double dw = row->has[WZ] ? tz - pz : 0.0;
    arc->clockwise = mo == 2.0;
    arc->dw = dw;
    if (row->has[WR]) {
        double radius = row->v[WR] * unit;
        double du = tx - px, dv = ty - py;
        double chord = distance(du, dv);
        double r = fabs(radius);
        if (chord < SAME_POINT || r < SAME_POINT || chord > 2 * r + TOLERANCE) {
            return 0;
        }
        double half = chord / 2;
        double inside = r * r - pow(half, 2.0);
        double h = sqrt(0.0 > inside ? 0.0 : inside);
        double left_u = -dv / chord, left_v = du / chord;
        double side = arc->clockwise ? -1.0 : 1.0;
        if (radius < 0) {
            side = -side;
        }
        arc->cu = px + du / 2 + side * h * left_u;
        arc->cv = py + dv / 2 + side * h * left_v;
        sweep_of(px, py, tx, ty, arc->cu, arc->cv, arc);
        arc->r0 = r;
        arc->r1 = r;
    } else if (row->has[WI] || row->has[WJ]) {
        double cu = row->has[WI] ? row->v[WI] * unit : 0.0;
        double cv = row->has[WJ] ? row->v[WJ] * unit : 0.0;
        arc->cu = px + cu;
        arc->cv = py + cv;
        double r0 = distance(px - arc->cu, py - arc->cv);
        double r1 = distance(tx - arc->cu, ty - arc->cv);
        if (r0 < SAME_POINT) {
            return 0;
        }
        sweep_of(px, py, tx, ty, arc->cu, arc->cv, arc);
        arc->r0 = r0;
        arc->r1 = r1;
    } else {
        return 0;
    }
    double mismatch = fabs(arc->r1 - arc->r0);
    double limit = 0.001 * arc->r0;
    if (mismatch > (limit > TOLERANCE ? limit : TOLERANCE)) {
        return 0;
    }
    return 1;
}

/* The extents reach (x, y, z): fast_read's `lox = x if x < lox else lox` per axis, NaN and all. */
static inline void
extend(double *lo, double *hi, double x, double y, double z)
{
    const double point[3] = {x, y, z};
    for (int k = 0; k < 3; k++) {
        lo[k] = point[k] < lo[k] ? point[k] : lo[k];
        hi[k] = point[k] > hi[k] ? point[k] : hi[k];
    }
}

static inline double arc_length(const Arc *arc) { return distance(0.5 * (arc->r0 + arc->r1) * arc->sweep, arc->dw); }

static inline int all_finite(const double *v, int n)
{
    for (int k = 0; k < n; k++) {
        if (!isfinite(v[k])) {
            return 0;
        }
    }
    return 1;
}

/* Read plain blocks from `p` on; stop at the first line Python must read. */
static const unsigned char *
read_blocks(const unsigned char *p, const unsigned char *end, const Params *prm, double *s, long *line,
            long *n, long *first, long *last, int *moved)
{
    double px = s[PX], py = s[PY], pz = s[PZ];
    double lox = s[LOX], loy = s[LOY], loz = s[LOZ], hix = s[HIX], hiy = s[HIY], hiz = s[HIZ];
    double motion = s[MOTION], feed = s[FEED];
    double cut_mm = s[CUT_MM], rapid_mm = s[RAPID_MM], cut_s = s[CUT_S], rapid_s = s[RAPID_S];
    double timed = s[TIMED];
    const double unit = prm->unit, rapid = prm->rapid;
    Row row;
    while (p < end) {
        const unsigned char *eol = memchr(p, '\n', (size_t)(end - p));
        const unsigned char *next = eol ? eol + 1 : end;
        if (!eol) {
            eol = end;
        }
        if (!parse_row(p, eol, &row, prm->released)) {
            break;
        }
        if (row.g >= 0 && !prm->g_ok[row.g]) {
            break;
        }
        if (row.m >= 0 && (row.m >= M_TABLE || !prm->m_ok[row.m])) {
            break;
        }
        double mo = row.g >= 0 ? (double)row.g : motion;
        double fe = row.has[WF] ? row.v[WF] * unit : feed;
        int move = row.has[WX] || row.has[WY] || row.has[WZ];
        int centre = row.has[WI] || row.has[WJ] || row.has[WR];
        if (!move && (!centre || isnan(mo) || mo < 2.0)) {
            motion = mo;
            feed = fe;
        } else {
            if (isnan(mo) || !(mo <= 3.0)) {
                break;
            }
            double tx = row.has[WX] ? row.v[WX] * unit + prm->ox : px;
            double ty = row.has[WY] ? row.v[WY] * unit + prm->oy : py;
            double tz = row.has[WZ] ? row.v[WZ] * unit + prm->oz : pz;
            if (mo != 0.0) {
                if (isnan(fe) || fe == 0.0 || (fe > rapid && !prm->clamp_noted)) {
                    break;
                }
                if (fe > rapid) {
                    fe = rapid;
                }
            }
            double nlo[3] = {lox, loy, loz}, nhi[3] = {hix, hiy, hiz};
            double ncut_mm = cut_mm, nrapid_mm = rapid_mm, ncut_s = cut_s, nrapid_s = rapid_s;
            if (mo < 2.0) {
                double square = 0.0, d;
                if (row.has[WX]) {
                    d = tx - px;
                    square += d * d;
                }
                if (row.has[WY]) {
                    d = ty - py;
                    square += d * d;
                }
                if (row.has[WZ]) {
                    d = tz - pz;
                    square += d * d;
                }
                double length = sqrt(square);
                if (mo == 0.0) {
                    nrapid_mm += length;
                    nrapid_s += length / rapid * 60.0;
                } else {
                    ncut_mm += length;
                    ncut_s += length / fe * 60.0;
                }
            } else {
                Arc arc;
                if (!make_arc(mo, px, py, pz, tx, ty, tz, &row, unit, &arc)) {
                    break;
                }
                for (int k = 0; k < 4; k++) {
                    double angle = k * M_PI / 2;
                    double offset = arc.clockwise ? py_mod(arc.a0 - angle, TAU) : py_mod(angle - arc.a0, TAU);
                    if (offset <= arc.sweep) {
                        double f = arc.sweep ? offset / arc.sweep : 0.0;
                        double r = arc.r0 + (arc.r1 - arc.r0) * (1.0 < f ? 1.0 : f);
                        extend(nlo, nhi, arc.cu + r * COS[k], arc.cv + r * SIN[k], pz);
                    }
                }
                double length = arc_length(&arc);
                ncut_mm += length;
                ncut_s += length / fe * 60.0;
            }
            extend(nlo, nhi, tx, ty, tz);
            {
                double check[13] = {tx, ty, tz, nlo[0], nlo[1], nlo[2], nhi[0], nhi[1], nhi[2], ncut_mm, nrapid_mm, ncut_s, nrapid_s};
                if (!all_finite(check, 13)) {
                    break; /* Python says what overflowed */
                }
            }
            lox = nlo[0], loy = nlo[1], loz = nlo[2], hix = nhi[0], hiy = nhi[1], hiz = nhi[2];
            cut_mm = ncut_mm, rapid_mm = nrapid_mm, cut_s = ncut_s, rapid_s = nrapid_s;
            px = tx, py = ty, pz = tz;
            motion = mo;
            feed = fe;
            timed += 1.0;
            *moved = 1;
        }
        (*n)++;
        if (!*first) {
            *first = *line;
        }
        *last = *line;
        (*line)++;
        p = next;
    }
    s[PX] = px, s[PY] = py, s[PZ] = pz;
    s[LOX] = lox, s[LOY] = loy, s[LOZ] = loz, s[HIX] = hix, s[HIY] = hiy, s[HIZ] = hiz;
    s[MOTION] = motion, s[FEED] = feed;
    s[CUT_MM] = cut_mm, s[RAPID_MM] = rapid_mm, s[CUT_S] = cut_s, s[RAPID_S] = rapid_s;
    s[TIMED] = timed;
    return p;
}

static int
state_in(PyObject *list, double *s)
{
    if (!PyList_Check(list) || PyList_GET_SIZE(list) != N_STATE) {
        PyErr_SetString(PyExc_TypeError, "state must be a list of 16 items");
        return -1;
    }
    for (int k = 0; k < N_STATE; k++) {
        PyObject *item = PyList_GET_ITEM(list, k);
        if (item == Py_None && (k == MOTION || k == FEED)) {
            s[k] = NAN;
            continue;
        }
        s[k] = PyFloat_AsDouble(item);
        if (s[k] == -1.0 && PyErr_Occurred()) {
            return -1;
        }
        if (isnan(s[k])) {
            return 1; /* a NaN this reader did not make: Python reads on */
        }
    }
    return 0;
}

static int
state_out(PyObject *list, const double *s)
{
    for (int k = 0; k < N_STATE; k++) {
        PyObject *item;
        if (k == TIMED) {
            item = PyLong_FromDouble(s[k]);
        } else if (isnan(s[k])) {
            item = Py_NewRef(Py_None);
        } else {
            item = PyFloat_FromDouble(s[k]);
        }
        if (item == NULL) {
            return -1;
        }
        PyList_SetItem(list, k, item); /* steals the reference */
    }
    return 0;
}

PyDoc_STRVAR(read_rows_doc,
"read_rows(text, pos, line, params, state) -> (pos, line, n, first, last, moved)\n\n"
"Read plain blocks of `text` (an ASCII str, or ASCII bytes) from index `pos` (the start of line `line`)\n"
"until the first line Python must read, or the end. `params` is (g_ok: bytes[4],\n"
"m_ok: bytes[100], unit, ox, oy, oz, rapid, clamp_noted); `state` is the list of\n"
"_FastReader.load(), updated in place when n > 0. Returns where reading stopped,\n"
"that line's number, the blocks read, their first and last lines, and whether any moved.");

static PyObject *
read_rows(PyObject *module, PyObject *args)
{
    (void)module;
    PyObject *text, *params, *state;
    Py_ssize_t pos;
    long line;
    Py_buffer g_ok, m_ok, view = {0};
    Params prm;
    if (!PyArg_ParseTuple(args, "OnlO!O!", &text, &pos, &line, &PyTuple_Type, &params, &PyList_Type, &state)) {
        return NULL;
    }
    if (!PyArg_ParseTuple(params, "y*y*dddddp", &g_ok, &m_ok, &prm.unit, &prm.ox, &prm.oy, &prm.oz, &prm.rapid,
                          &prm.clamp_noted)) {
        return NULL;
    }
    PyObject *result = NULL;
    if (g_ok.len != 4 || m_ok.len != M_TABLE) {
        PyErr_SetString(PyExc_ValueError, "g_ok must be 4 bytes and m_ok 100");
        goto done;
    }
    const unsigned char *base;
    Py_ssize_t size;
    if (PyUnicode_Check(text)) {
        if (!PyUnicode_IS_ASCII(text)) {
            PyErr_SetString(PyExc_ValueError, "text must be ASCII");
            goto done;
        }
        base = PyUnicode_1BYTE_DATA(text);
        size = PyUnicode_GET_LENGTH(text);
    } else {
        if (PyObject_GetBuffer(text, &view, PyBUF_SIMPLE) < 0) {
            goto done;
        }
        base = view.buf;
        size = view.len;
    }
    if (pos < 0 || pos > size) {
        PyErr_SetString(PyExc_IndexError, "pos out of range");
        goto done;
    }
    prm.g_ok = g_ok.buf;
    prm.m_ok = m_ok.buf;
    double s[N_STATE];
    int bad = state_in(state, s);
    if (bad < 0) {
        goto done;
    }
    long n = 0, first = 0, last = 0;
    int moved = 0;
    const unsigned char *stop = base + pos;
    if (!bad) {
        /* Without the GIL: a large program is read in a worker thread while the event loop runs on. */
        PyThreadState *released = PyEval_SaveThread();
        prm.released = &released;
        stop = read_blocks(base + pos, base + size, &prm, s, &line, &n, &first, &last, &moved);
        PyEval_RestoreThread(released);
    }
    if (n && state_out(state, s) < 0) {
        goto done;
    }
    result = Py_BuildValue("nlllli", (Py_ssize_t)(stop - base), line, n, first, last, moved);
done:
    if (view.obj != NULL) {
        PyBuffer_Release(&view);
    }
    PyBuffer_Release(&g_ok);
    PyBuffer_Release(&m_ok);
    return result;
}

/* What text_stats makes of each byte value (filled in when the module loads). */
enum { PRINTABLE, LF, CR, OTHER };
static unsigned char TEXT_KIND[256];

PyDoc_STRVAR(text_stats_doc,
"text_stats(data) -> (longest, clean, newlines, nuls)\n\n"
"The longest line of `data` in bytes (a CR before LF counts, as in len(line)); whether\n"
"every byte is printable ASCII, TAB, LF or a CR that ends a line; the number of LF\n"
"bytes; and the number of NUL bytes.");

static PyObject *
text_stats(PyObject *module, PyObject *arg)
{
    (void)module;
    Py_buffer view;
    if (PyObject_GetBuffer(arg, &view, PyBUF_SIMPLE) < 0) {
        return NULL;
    }
    const unsigned char *p = view.buf, *end = p + view.len;
    Py_ssize_t longest = 0, newlines = 0, nuls = 0;
    int clean = 1;
    Py_BEGIN_ALLOW_THREADS
    const unsigned char *start = p; /* of the current line */
    const uint64_t ones = UINT64_C(0x0101010101010101), highs = UINT64_C(0x8080808080808080);
    while (p < end) {
        /* Eight bytes at a time while all are printable ASCII (0x20..0x7E): the usual case. */
        while (end - p >= 8) {
            uint64_t x;
            memcpy(&x, p, 8);
            uint64_t below = (x - ones * 0x20) & ~x & highs;       /* some byte < 0x20 */
            uint64_t above = ((x + ones * (0x7F - 0x7E)) | x) & highs; /* some byte > 0x7E */
            if (below | above) {
                break;
            }
            p += 8;
        }
        const unsigned char *stop = end - p >= 8 ? p + 8 : end;
        for (; p < stop; p++) {
            unsigned char kind = TEXT_KIND[*p];
            if (kind == PRINTABLE) {
                continue;
            }
            if (kind == LF) {
                if (p - start > longest) {
                    longest = p - start;
                }
                newlines++;
                start = p + 1;
            } else if (!(kind == CR && p + 1 < end && p[1] == '\n')) {
                clean = 0;
            }
        }
    }
    if (end - start > longest) {
        longest = end - start;
    }
    if (!clean) { /* a clean text has none */
        for (const unsigned char *q = view.buf; (q = memchr(q, 0, (size_t)(end - q))) != NULL; q++) {
            nuls++;
        }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&view);
    return Py_BuildValue("nOnn", longest, clean ? Py_True : Py_False, newlines, nuls);
}

static PyMethodDef methods[] = {
    {"read_rows", read_rows, METH_VARARGS, read_rows_doc},
    {"text_stats", text_stats, METH_O, text_stats_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "gateway.jobs.validation._plain",
    "The compiled plain-block reader of G-code validation (see fast_read.py).", -1, methods,
};

PyMODINIT_FUNC
PyInit__plain(void)
{
    for (int c = 0; c < 256; c++) {
        TEXT_KIND[c] = (c >= 0x20 && c <= 0x7E) || c == '\t' ? PRINTABLE : c == '\n' ? LF : c == '\r' ? CR : OTHER;
    }
    for (int k = 0; k < 4; k++) {
        double angle = k * M_PI / 2;
        COS[k] = cos(angle);
        SIN[k] = sin(angle);
    }
    return PyModule_Create(&module);
}
