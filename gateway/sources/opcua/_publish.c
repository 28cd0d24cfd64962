/* The compiled fast path for the OPC UA source: decodes a PublishResponse that carries only
 * DataChangeNotifications into what the source consumes from asyncua's objects, without building them.
 *
 * decode(data, start, size) reads data[start:start+size] (the body asyncua hands back for a Publish
 * request: the response's TypeId first) and returns
 *
 *     (ServiceResult, SubscriptionId, SequenceNumber, len(NotificationData), changes)
 *
 * where changes is a list of (ClientHandle, Variant.Value, SourceTimestamp or ServerTimestamp or None,
 * StatusCode value) tuples, one per MonitoredItemNotification, in wire order: exactly what
 * gateway.sources.opcua.publish_decode.from_response() derives from asyncua's own struct_from_binary.
 *
 * It returns None for anything it is not certain to read exactly as asyncua does: another notification
 * type (status change, events), an extension object in any other form, diagnostic infos, variants with
 * dimensions or of another type (NodeId, LocalizedText, ExtensionObject, ...), unusual lengths, a bit of an
 * encoding mask it does not know, truncated input. The caller then decodes the same bytes with asyncua,
 * which gives the answer or raises its error. It raises only MemoryError (and ValueError for a start or
 * size outside the buffer, a caller's bug), and never reads outside the buffer.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <datetime.h>
#include <stdint.h>
#include <string.h>

enum { OK = 0, FALLBACK = 1, ERROR = -1 };

typedef struct {
    const unsigned char *p;
    const unsigned char *end;
} Reader;

#define NEED(r, n)                                                     \
    do {                                                               \
        if ((uint64_t)((r)->end - (r)->p) < (uint64_t)(n)) {           \
            return FALLBACK;                                           \
        }                                                              \
    } while (0)

static uint16_t u16(const unsigned char *p) { return (uint16_t)(p[0] | (p[1] << 8)); }

static uint32_t u32(const unsigned char *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static uint64_t u64(const unsigned char *p) { return (uint64_t)u32(p) | ((uint64_t)u32(p + 4) << 32); }

static int32_t i32(const unsigned char *p) { return (int32_t)u32(p); }

/* asyncua (ua.uatypes.win_epoch_to_datetime): FILETIMEs at or after 9999-12-31 23:59:59 read as that
 * moment, negative ones as 1601-01-01, the rest as 1601-01-01 + epch // 10 microseconds, all in UTC. */
#define MAX_OPC_FILETIME 2650467743990000000LL
#define DAYS_1601_TO_1970 134774LL
#define US_PER_DAY 86400000000LL

static PyObject *utc;           /* datetime.timezone.utc */
static PyObject *earliest;      /* 1601-01-01 00:00:00+00:00 */
static PyObject *latest;        /* 9999-12-31 23:59:59+00:00 */

static PyObject *new_datetime(int y, int mo, int d, int h, int mi, int s, int us) {
    return PyDateTimeAPI->DateTime_FromDateAndTime(y, mo, d, h, mi, s, us, utc, PyDateTimeAPI->DateTimeType);
}

static PyObject *datetime_of(int64_t epch) {
    if (epch >= MAX_OPC_FILETIME) {
        return Py_NewRef(latest);
    }
    if (epch < 0) {
        return Py_NewRef(earliest);
    }
    int64_t us = epch / 10;
    int64_t z = us / US_PER_DAY - DAYS_1601_TO_1970; /* days since 1970-01-01 */
    int64_t rem = us % US_PER_DAY;
    /* Howard Hinnant's civil_from_days (proleptic Gregorian, exact for every day in range). */
    z += 719468;
    int64_t era = (z >= 0 ? z : z - 146096) / 146097;
    int64_t doe = z - era * 146097;
    int64_t yoe = (doe - doe / 1460 + doe / 36524 - doe / 146096) / 365;
    int64_t y = yoe + era * 400;
    int64_t doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    int64_t mp = (5 * doy + 2) / 153;
    int64_t d = doy - (153 * mp + 2) / 5 + 1;
    int64_t m = mp < 10 ? mp + 3 : mp - 9;
    y += (m <= 2);
    int64_t secs = rem / 1000000;
    return new_datetime((int)y, (int)m, (int)d, (int)(secs / 3600), (int)(secs / 60 % 60), (int)(secs % 60),
                        (int)(rem % 1000000));
}

/* One element of a variant's built-in type `t` (one of the types read_variant accepts). */
static int read_element(Reader *r, int t, PyObject **out) {
    switch (t) {
    case 0: /* Null */
        *out = Py_NewRef(Py_None);
        return OK;
    case 1: /* Boolean: struct '?' is True for any byte but 0 */
        NEED(r, 1);
        *out = PyBool_FromLong(r->p[0] != 0);
        r->p += 1;
        return OK;
    case 2: /* SByte */
        NEED(r, 1);
        *out = PyLong_FromLong((int8_t)r->p[0]);
        r->p += 1;
        break;
    case 3: /* Byte */
        NEED(r, 1);
        *out = PyLong_FromLong(r->p[0]);
        r->p += 1;
        break;
    case 4: /* Int16 */
        NEED(r, 2);
        *out = PyLong_FromLong((int16_t)u16(r->p));
        r->p += 2;
        break;
    case 5: /* UInt16 */
        NEED(r, 2);
        *out = PyLong_FromLong(u16(r->p));
        r->p += 2;
        break;
    case 6: /* Int32 */
        NEED(r, 4);
        *out = PyLong_FromLong(i32(r->p));
        r->p += 4;
        break;
    case 7: /* UInt32 */
        NEED(r, 4);
        *out = PyLong_FromUnsignedLong(u32(r->p));
        r->p += 4;
        break;
    case 8: /* Int64 */
        NEED(r, 8);
        *out = PyLong_FromLongLong((long long)(int64_t)u64(r->p));
        r->p += 8;
        break;
    case 9: /* UInt64 */
        NEED(r, 8);
        *out = PyLong_FromUnsignedLongLong(u64(r->p));
        r->p += 8;
        break;
    case 10: { /* Float: widened to a double, as struct '<f' does */
        NEED(r, 4);
        uint32_t bits = u32(r->p);
        float f;
        memcpy(&f, &bits, 4);
        *out = PyFloat_FromDouble((double)f);
        r->p += 4;
        break;
    }
    case 11: { /* Double */
        NEED(r, 8);
        uint64_t bits = u64(r->p);
        double f;
        memcpy(&f, &bits, 8);
        *out = PyFloat_FromDouble(f);
        r->p += 8;
        break;
    }
    case 12:   /* String: UTF-8 with surrogateescape (asyncua's default string encoding) */
    case 15: { /* ByteString */
        NEED(r, 4);
        int32_t n = i32(r->p);
        if (n == -1) {
            r->p += 4;
            *out = Py_NewRef(Py_None);
            return OK;
        }
        if (n < 0) {
            return FALLBACK; /* asyncua's Buffer.read moves backwards on these */
        }
        NEED(r, 4 + (uint64_t)n);
        const char *s = (const char *)r->p + 4;
        *out = t == 12 ? PyUnicode_DecodeUTF8(s, n, "surrogateescape") : PyBytes_FromStringAndSize(s, n);
        r->p += 4 + (uint64_t)n;
        break;
    }
    case 13: /* DateTime */
        NEED(r, 8);
        *out = datetime_of((int64_t)u64(r->p));
        r->p += 8;
        break;
    default:
        return FALLBACK;
    }
    return *out == NULL ? ERROR : OK;
}

/* The smallest encoding of one element of type t: bounds an array's length before allocating it. */
static int element_size(int t) {
    switch (t) {
    case 1: case 2: case 3: return 1;
    case 4: case 5: return 2;
    case 6: case 7: case 10: case 12: case 15: return 4;
    case 8: case 9: case 11: case 13: return 8;
    default: return 0; /* not read here */
    }
}

static int read_variant(Reader *r, PyObject **out) {
    NEED(r, 1);
    int encoding = r->p[0];
    int t = encoding & 0x3F;
    r->p += 1;
    if (encoding & 0x40) {
        return FALLBACK; /* ArrayDimensions: asyncua reshapes */
    }
    if (!(encoding & 0x80)) {
        if (t != 0 && element_size(t) == 0) {
            return FALLBACK;
        }
        return read_element(r, t, out);
    }
    int size = element_size(t);
    if (size == 0) {
        return FALLBACK; /* arrays of Null and of every other type */
    }
    NEED(r, 4);
    int32_t n = i32(r->p);
    r->p += 4;
    if (n == -1) {
        *out = Py_NewRef(Py_None);
        return OK;
    }
    if (n < 0) {
        return FALLBACK;
    }
    NEED(r, (uint64_t)n * (uint64_t)size);
    PyObject *list = PyList_New(n);
    if (list == NULL) {
        return ERROR;
    }
    for (int32_t i = 0; i < n; i++) {
        PyObject *item = NULL;
        int rc = read_element(r, t, &item);
        if (rc != OK) {
            Py_DECREF(list);
            return rc;
        }
        PyList_SET_ITEM(list, i, item);
    }
    *out = list;
    return OK;
}

/* One MonitoredItemNotification: ClientHandle, then a DataValue. Appends its change tuple. */
static int read_item(Reader *r, PyObject *changes) {
    NEED(r, 5);
    uint32_t handle = u32(r->p);
    int mask = r->p[4];
    r->p += 5;
    if (mask & 0xC0) {
        return FALLBACK; /* bits DataValue does not define */
    }
    PyObject *value = NULL;
    if (mask & 0x01) {
        int rc = read_variant(r, &value);
        if (rc != OK) {
            return rc;
        }
    } else {
        value = Py_NewRef(Py_None);
    }
    uint32_t code = 0;
    int64_t source = 0, server = 0;
    int rc = FALLBACK;
    const unsigned char *start = r->p;
    uint64_t need = ((mask & 0x02) ? 4 : 0) + ((mask & 0x04) ? 8 : 0) + ((mask & 0x08) ? 8 : 0) +
                    ((mask & 0x10) ? 2 : 0) + ((mask & 0x20) ? 2 : 0);
    if ((uint64_t)(r->end - start) < need) {
        Py_DECREF(value);
        return FALLBACK;
    }
    if (mask & 0x02) {
        code = u32(r->p);
        r->p += 4;
    }
    if (mask & 0x04) {
        source = (int64_t)u64(r->p);
        r->p += 8;
    }
    if (mask & 0x08) {
        server = (int64_t)u64(r->p);
        r->p += 8;
    }
    r->p += ((mask & 0x10) ? 2 : 0) + ((mask & 0x20) ? 2 : 0); /* picoseconds: not consumed */
    PyObject *ts;
    if (mask & 0x04) {
        ts = datetime_of(source);
    } else if (mask & 0x08) {
        ts = datetime_of(server);
    } else {
        ts = Py_NewRef(Py_None);
    }
    PyObject *h = PyLong_FromUnsignedLong(handle);
    PyObject *c = PyLong_FromUnsignedLong(code);
    PyObject *tuple = NULL;
    if (ts != NULL && h != NULL && c != NULL) {
        tuple = PyTuple_Pack(4, h, value, ts, c);
    }
    Py_XDECREF(h);
    Py_XDECREF(c);
    Py_XDECREF(ts);
    Py_DECREF(value);
    if (tuple == NULL) {
        return ERROR;
    }
    rc = PyList_Append(changes, tuple) < 0 ? ERROR : OK;
    Py_DECREF(tuple);
    return rc;
}

/* A list of structures of at most zero elements: -1 (null) and 0 read nothing. */
static int empty_list(Reader *r) {
    NEED(r, 4);
    int32_t n = i32(r->p);
    r->p += 4;
    return (n == -1 || n == 0) ? OK : FALLBACK;
}

/* A list of fixed-size elements (UInt32 counters, status codes): skipped. */
static int skip_list(Reader *r, int size) {
    NEED(r, 4);
    int32_t n = i32(r->p);
    r->p += 4;
    if (n == -1) {
        return OK;
    }
    if (n < 0) {
        return FALLBACK;
    }
    NEED(r, (uint64_t)n * (uint64_t)size);
    r->p += (uint64_t)n * (uint64_t)size;
    return OK;
}

/* One element of NotificationData: an ExtensionObject that must be a DataChangeNotification
 * (four-byte NodeId ns=0;i=811, binary body) whose DiagnosticInfos are empty. */
static int read_notification(Reader *r, PyObject *changes) {
    NEED(r, 9);
    if (r->p[0] != 0x01 || r->p[1] != 0x00 || u16(r->p + 2) != 811 || r->p[4] != 0x01) {
        return FALLBACK;
    }
    int32_t length = i32(r->p + 5);
    r->p += 9;
    if (length < 1) {
        return FALLBACK;
    }
    NEED(r, (uint64_t)length);
    Reader body = {r->p, r->p + length}; /* asyncua reads the body alone and skips what it leaves */
    r->p += length;
    NEED(&body, 4);
    int32_t n = i32(body.p);
    body.p += 4;
    if (n < -1) {
        return FALLBACK;
    }
    for (int32_t i = 0; i < n; i++) {
        int rc = read_item(&body, changes);
        if (rc != OK) {
            return rc;
        }
    }
    return empty_list(&body);
}

static int read_response(Reader *r, uint32_t *result, uint32_t *subscription, uint32_t *sequence,
                         int32_t *count, PyObject *changes) {
    /* TypeId: PublishResponse_Encoding_DefaultBinary as a four-byte NodeId. */
    NEED(r, 4 + 8 + 4 + 4 + 1);
    if (r->p[0] != 0x01 || r->p[1] != 0x00 || u16(r->p + 2) != 829) {
        return FALLBACK;
    }
    r->p += 4;
    /* ResponseHeader: Timestamp, RequestHandle, ServiceResult, ServiceDiagnostics (empty only). */
    r->p += 8 + 4;
    *result = u32(r->p);
    r->p += 4;
    if (r->p[0] != 0) {
        return FALLBACK;
    }
    r->p += 1;
    /* StringTable: strings skipped (decoding with surrogateescape cannot fail). */
    NEED(r, 4);
    int32_t strings = i32(r->p);
    r->p += 4;
    if (strings < -1) {
        return FALLBACK;
    }
    for (int32_t i = 0; i < strings; i++) {
        NEED(r, 4);
        int32_t n = i32(r->p);
        r->p += 4;
        if (n < -1) {
            return FALLBACK;
        }
        if (n > 0) {
            NEED(r, (uint64_t)n);
            r->p += n;
        }
    }
    /* AdditionalHeader: the null ExtensionObject only (two-byte NodeId 0, no body). */
    NEED(r, 3);
    if (r->p[0] != 0x00 || r->p[1] != 0x00 || r->p[2] != 0x00) {
        return FALLBACK;
    }
    r->p += 3;
    /* PublishResult: SubscriptionId, AvailableSequenceNumbers, MoreNotifications, NotificationMessage. */
    NEED(r, 4);
    *subscription = u32(r->p);
    r->p += 4;
    int rc = skip_list(r, 4);
    if (rc != OK) {
        return rc;
    }
    NEED(r, 1 + 4 + 8 + 4);
    r->p += 1;
    *sequence = u32(r->p);
    r->p += 4 + 8; /* and PublishTime */
    int32_t n = i32(r->p);
    r->p += 4;
    if (n < -1) {
        return FALLBACK;
    }
    *count = n < 0 ? 0 : n;
    for (int32_t i = 0; i < n; i++) {
        rc = read_notification(r, changes);
        if (rc != OK) {
            return rc;
        }
    }
    rc = skip_list(r, 4); /* Results */
    if (rc != OK) {
        return rc;
    }
    return empty_list(r); /* DiagnosticInfos */
}

static PyObject *decode(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer view;
    Py_ssize_t start, size;
    if (!PyArg_ParseTuple(args, "y*nn:decode", &view, &start, &size)) {
        return NULL;
    }
    if (start < 0 || size < 0 || start > view.len || size > view.len - start) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_ValueError, "start and size must lie within the data");
        return NULL;
    }
    Reader r = {(const unsigned char *)view.buf + start, (const unsigned char *)view.buf + start + size};
    PyObject *changes = PyList_New(0);
    if (changes == NULL) {
        PyBuffer_Release(&view);
        return NULL;
    }
    uint32_t result = 0, subscription = 0, sequence = 0;
    int32_t count = 0;
    int rc = read_response(&r, &result, &subscription, &sequence, &count, changes);
    PyBuffer_Release(&view);
    if (rc != OK) {
        Py_DECREF(changes);
        if (rc == ERROR) {
            return NULL;
        }
        Py_RETURN_NONE;
    }
    return Py_BuildValue("(kkkiN)", (unsigned long)result, (unsigned long)subscription,
                         (unsigned long)sequence, (int)count, changes);
}

static PyMethodDef methods[] = {
    {"decode", decode, METH_VARARGS,
     "decode(data, start, size) -> (ServiceResult, SubscriptionId, SequenceNumber, notifications, changes)"
     " or None: a PublishResponse of data changes only, or None for asyncua to decode."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_publish", "The OPC UA source's compiled PublishResponse reader.", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__publish(void) {
    PyDateTime_IMPORT;
    if (PyDateTimeAPI == NULL) {
        return NULL;
    }
    utc = PyDateTime_TimeZone_UTC;
    Py_INCREF(utc);
    earliest = new_datetime(1601, 1, 1, 0, 0, 0, 0);
    latest = new_datetime(9999, 12, 31, 23, 59, 59, 0);
    if (earliest == NULL || latest == NULL) {
        return NULL;
    }
    return PyModule_Create(&module);
}
