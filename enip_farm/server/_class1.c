/* The per-packet work of established class-1 connections (CIP Networks Library Vol. 2, 3-2 and 3-3;
 * Vol. 1, 3-4.4.9), native: the cyclic I/O thread's hot path for the devices in "native mode"
 * (server/native.py decides which, and loads and stores their state: Python stays authoritative for
 * everything else).
 *
 * For each native device the engine holds its I/O connections (O->T id, originator, pinned port,
 * last sequence, supervision deadline, run/idle, the consumed assembly's bytearray and the
 * originator measurement of cip/o_t_measure.py), its T->O streams (absolute deadlines, sequence,
 * destination, the produced bytearray) and its counters as deltas. It mirrors cip/io_packets.py's
 * `receive` and `produce` and cip/io_schedule.py's `produce` exactly; whatever it does not do (an
 * unknown connection id, a malformed packet, a run/idle change, a supervision deadline reached, a
 * device not in native mode) it hands back to Python, before changing anything.
 *
 * The images are the assemblies' own bytearrays (read and written in place under the GIL, never
 * exported, so Python may still resize them). Time is passed in (CLOCK_MONOTONIC ns). */
#define _GNU_SOURCE
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>

#include "_receive.h"

#define NBOUNDS 34 /* cip/o_t_measure.py BUCKETS_PERMILLE */
#define HEADER 20  /* item count, sequenced address item, connected data item header, sequence count */
#define IMAGE 24   /* + the 32-bit run/idle header */
#define HALF 0x80000000LL
#define MAX_BATCH 256
#define MAX_PACKET 600

typedef struct {
    uint32_t id, host;
    long long port, last_sequence, last_received, deadline, timeout_ns, received;
    int run, has_last_received, heartbeat; /* heartbeat: O->T carries no data (an input-only or listen-only one) */
    int observed; /* its image is the device's output image and someone observes it: each change reported */
    PyObject *conn, *measure, *image; /* owned references */
    /* the measurement (cip/o_t_measure.py), when the connection has one */
    long long bounds[NBOUNDS], counts[NBOUNDS + 1], written[NBOUNDS + 1]; /* written: as Python last has them */
    long long total, min, max, last_at, first_at, m_last_sequence, last_count, packets, lost, gaps, repeats,
        stale, cip_same, cip_skipped;
    int has_min, has_first;
} Conn;

typedef struct {
    uint32_t id;
    struct sockaddr_in to;
    int unicast, header_len;
    unsigned char header[4];
    long long period, start, count, due, late, sequence;
    PyObject *production, *data; /* data: the produced bytearray, NULL for a heartbeat */
} Stream;

enum { C_OT, C_TO, C_ORIGINATOR, C_PORT, C_STALE, C_SIZE, C_SEND_ERRORS, NCOUNTERS };
static const char *counter_names[NCOUNTERS] = {"o_t_packets", "t_o_packets", "o_t_dropped_wrong_originator",
                                               "o_t_dropped_wrong_port", "o_t_dropped_stale",
                                               "o_t_dropped_wrong_size", "t_o_send_errors"};
enum { T_IN_OCTETS, T_IN_UCAST, T_IN_DISCARDS, T_OUT_OCTETS, T_OUT_UCAST, T_OUT_NUCAST, T_OUT_ERRORS, NTRAFFIC };
static PyObject *counter_keys[NCOUNTERS], *traffic_keys[NTRAFFIC]; /* interned at import */
static const char *traffic_names[NTRAFFIC] = {"in_octets", "in_ucast", "in_discards", "out_octets",
                                              "out_ucast", "out_nucast", "out_errors"};

typedef struct {
    int fd, native, dirty, off_on_idle, kept; /* kept: released to Python with its state kept (`resume`) */
    int slot;
    uint32_t source;
    PyObject *counters, *traffic;
    PyObject *changes; /* the engine's `changes` list (borrowed: the engine owns it, and outlives its devices) */
    Conn *conns;
    Stream *streams;
    int nconns, nstreams;
    long long watch; /* the earliest supervision deadline of the connections Python keeps (class 3) */
    int watched;     /* the watch handed the device to Python: `load` it again (a newer deadline), never `resume` */
    long long counter[NCOUNTERS], traffic_delta[NTRAFFIC];
} Dev;

typedef struct {
    PyObject_HEAD
    PyObject *changes; /* (slot, now, before, after) of each output image change of an observed connection */
    Dev *devs;
    int ndevs, cap;
    int *by_fd, nfd;
    int sender;
    int next_sync;   /* the device the next sync slice starts at */
    long long turns; /* produce calls: a device loaded again after one ran without it must be rescheduled */
    /* the T->O of one produce call, sent together */
    struct mmsghdr headers[MAX_BATCH];
    struct iovec vectors[MAX_BATCH];
    struct sockaddr_in to[MAX_BATCH];
    union {
        char buffer[CMSG_SPACE(sizeof(struct in_pktinfo))];
        struct cmsghdr align;
    } controls[MAX_BATCH];
    unsigned char packets[MAX_BATCH][MAX_PACKET];
    int from[MAX_BATCH], queued;
    /* the datagrams of one `receive` call: the engine's own (its thread's), never the module's, since
     * a collection while it builds its results may run another engine's `receive` */
    char buffers[MAX_RECEIVE][MAX_DATAGRAM];
} Engine;

/* -- loading and storing a device's state (server/native.py) --------------------------------------- */

static int get_ll(PyObject *o, const char *name, long long *out, long long none) {
    PyObject *v = PyObject_GetAttrString(o, name);
    if (v == NULL)
        return -1;
    if (v == Py_None) {
        *out = none;
    } else {
        int overflow = 0;
        *out = PyLong_AsLongLongAndOverflow(v, &overflow);
        if (overflow) /* _NO_MIN (1 << 63): no interval yet */
            *out = none;
        if (*out == -1 && PyErr_Occurred()) {
            Py_DECREF(v);
            return -1;
        }
    }
    Py_DECREF(v);
    return 0;
}

static int set_ll(PyObject *o, const char *name, long long value) {
    PyObject *v = PyLong_FromLongLong(value);
    if (v == NULL)
        return -1;
    int r = PyObject_SetAttrString(o, name, v);
    Py_DECREF(v);
    return r;
}

static int set_opt(PyObject *o, const char *name, long long value, int present) {
    return present ? set_ll(o, name, value) : PyObject_SetAttrString(o, name, Py_None);
}

static void clear_dev(Dev *d) {
    for (int i = 0; i < d->nconns; i++) {
        Py_XDECREF(d->conns[i].conn);
        Py_XDECREF(d->conns[i].measure);
        Py_XDECREF(d->conns[i].image);
    }
    for (int i = 0; i < d->nstreams; i++) {
        Py_XDECREF(d->streams[i].production);
        Py_XDECREF(d->streams[i].data);
    }
    PyMem_Free(d->conns);
    PyMem_Free(d->streams);
    d->conns = NULL;
    d->streams = NULL;
    d->nconns = d->nstreams = 0;
    d->native = d->kept = d->watched = 0;
}

static int load_measure(Conn *c, PyObject *m) {
    PyObject *bounds = PyObject_GetAttrString(m, "_bounds_ns"), *counts = PyObject_GetAttrString(m, "counts");
    int ok = bounds && counts && PyTuple_Check(bounds) && PyTuple_GET_SIZE(bounds) == NBOUNDS && PyList_Check(counts) &&
             PyList_GET_SIZE(counts) == NBOUNDS + 1;
    for (int i = 0; ok && i < NBOUNDS; i++)
        c->bounds[i] = PyLong_AsLongLong(PyTuple_GET_ITEM(bounds, i));
    for (int i = 0; ok && i <= NBOUNDS; i++)
        c->written[i] = c->counts[i] = PyLong_AsLongLong(PyList_GET_ITEM(counts, i));
    Py_XDECREF(bounds);
    Py_XDECREF(counts);
    if (!ok) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_ValueError, "a measurement of another shape");
        return -1;
    }
    if (PyErr_Occurred())
        return -1;
    long long first;
    if (get_ll(m, "total_ns", &c->total, 0) || get_ll(m, "_min_ns", &c->min, -1) || get_ll(m, "max_ns", &c->max, 0) ||
        get_ll(m, "last_at", &c->last_at, 0) || get_ll(m, "first_at", &first, LLONG_MIN) ||
        get_ll(m, "last_sequence", &c->m_last_sequence, -1) || get_ll(m, "last_count", &c->last_count, 0) ||
        get_ll(m, "packets", &c->packets, 0) || get_ll(m, "lost", &c->lost, 0) || get_ll(m, "gaps", &c->gaps, 0) ||
        get_ll(m, "repeats", &c->repeats, 0) || get_ll(m, "stale", &c->stale, 0) ||
        get_ll(m, "cip_same", &c->cip_same, 0) || get_ll(m, "cip_skipped", &c->cip_skipped, 0))
        return -1;
    c->has_min = c->min != -1;
    c->has_first = first != LLONG_MIN;
    c->first_at = c->has_first ? first : 0;
    return 0;
}

static int store_measure(Conn *c) {
    PyObject *m = c->measure, *counts = PyObject_GetAttrString(m, "counts");
    if (counts == NULL)
        return -1;
    for (int i = 0; i <= NBOUNDS && i < PyList_GET_SIZE(counts); i++) {
        if (c->written[i] == c->counts[i])
            continue;
        PyObject *v = PyLong_FromLongLong(c->counts[i]);
        if (v == NULL || PyList_SetItem(counts, i, v) < 0) {
            Py_DECREF(counts);
            return -1;
        }
        c->written[i] = c->counts[i];
    }
    Py_DECREF(counts);
    int r = set_ll(m, "total_ns", c->total) || set_ll(m, "max_ns", c->max) || set_ll(m, "last_at", c->last_at) ||
            set_opt(m, "first_at", c->first_at, c->has_first) ||
            set_opt(m, "last_sequence", c->m_last_sequence, c->m_last_sequence >= 0) ||
            set_ll(m, "last_count", c->last_count) || set_ll(m, "packets", c->packets) || set_ll(m, "lost", c->lost) ||
            set_ll(m, "gaps", c->gaps) || set_ll(m, "repeats", c->repeats) || set_ll(m, "stale", c->stale) ||
            set_ll(m, "cip_same", c->cip_same) || set_ll(m, "cip_skipped", c->cip_skipped);
    if (r)
        return -1;
    if (c->has_min)
        return set_ll(m, "_min_ns", c->min);
    PyObject *none = PyLong_FromUnsignedLongLong(1ULL << 63); /* o_t_measure's _NO_MIN */
    if (none == NULL)
        return -1;
    r = PyObject_SetAttrString(m, "_min_ns", none);
    Py_DECREF(none);
    return r;
}

/* target[name] += delta (mapping) or target.name += delta. */
static int add_to(PyObject *target, int mapping, PyObject *key, long long delta) {
    PyObject *old = mapping ? PyObject_GetItem(target, key) : PyObject_GetAttr(target, key);
    if (old == NULL && mapping && PyErr_ExceptionMatches(PyExc_KeyError)) {
        PyErr_Clear();
        old = PyLong_FromLong(0);
    }
    PyObject *d = old ? PyLong_FromLongLong(delta) : NULL, *sum = d ? PyNumber_Add(old, d) : NULL;
    int r = sum ? (mapping ? PyObject_SetItem(target, key, sum) : PyObject_SetAttr(target, key, sum)) : -1;
    Py_XDECREF(old);
    Py_XDECREF(d);
    Py_XDECREF(sum);
    return r;
}

/* Write what the engine counted and changed back into the Python objects (it keeps them). */
static int store_dev(Dev *d) {
    /* Each delta is taken (and zeroed) before any Python code runs: whatever the engine counts
     * meanwhile (another thread may run between two calls into Python) is the next store's. */
    for (int i = 0; i < NCOUNTERS; i++) {
        long long delta = d->counter[i];
        d->counter[i] = 0;
        if (delta && add_to(d->counters, 1, counter_keys[i], delta) < 0)
            return -1;
    }
    for (int i = 0; i < NTRAFFIC; i++) {
        long long delta = d->traffic_delta[i];
        d->traffic_delta[i] = 0;
        if (delta && add_to(d->traffic, 0, traffic_keys[i], delta) < 0)
            return -1;
    }
    if (!d->dirty)
        return 0;
    d->dirty = 0; /* a change made while this writes marks it again */
    for (int i = 0; i < d->nconns; i++) {
        Conn *c = &d->conns[i];
        PyObject *o = c->conn;
        if (set_opt(o, "last_sequence", c->last_sequence, c->last_sequence >= 0) ||
            set_opt(o, "o_t_port", c->port, c->port >= 0) ||
            set_opt(o, "last_received", c->last_received, c->has_last_received) || set_ll(o, "deadline", c->deadline) ||
            set_ll(o, "received", c->received) || PyObject_SetAttrString(o, "run", c->run ? Py_True : Py_False))
            return -1;
        if (c->measure != NULL && store_measure(c) < 0)
            return -1;
    }
    for (int i = 0; i < d->nstreams; i++) {
        Stream *s = &d->streams[i];
        PyObject *o = s->production;
        if (set_ll(o, "count", s->count) || set_ll(o, "due", s->due) || set_ll(o, "late", s->late) ||
            set_ll(o, "sequence", s->sequence))
            return -1;
    }
    return 0;
}

static Dev *dev_of(Engine *e, PyObject *args, const char *format, void *a, void *b, void *c, void *d_, void *f,
                   void *g) {
    int slot;
    if (!PyArg_ParseTuple(args, format, &slot, a, b, c, d_, f, g))
        return NULL;
    if (slot < 0 || slot >= e->ndevs) {
        PyErr_SetString(PyExc_IndexError, "no such device slot");
        return NULL;
    }
    return &e->devs[slot];
}

/* add(fd, source, counters, traffic) -> slot: a device's UDP 2222 socket (source: its 4-byte address). */
static PyObject *engine_add(Engine *e, PyObject *args) {
    int fd;
    Py_buffer source;
    PyObject *counters, *traffic;
    if (!PyArg_ParseTuple(args, "iy*OO", &fd, &source, &counters, &traffic))
        return NULL;
    if (source.len != 4 || fd < 0 || fd > 1 << 20) {
        PyBuffer_Release(&source);
        PyErr_SetString(PyExc_ValueError, "a 4-byte source address and a file descriptor");
        return NULL;
    }
    if (e->ndevs == e->cap) {
        int cap = e->cap ? e->cap * 2 : 64;
        Dev *devs = PyMem_Realloc(e->devs, sizeof(Dev) * (size_t)cap);
        if (devs == NULL) {
            PyBuffer_Release(&source);
            return PyErr_NoMemory();
        }
        e->devs = devs;
        e->cap = cap;
    }
    if (fd >= e->nfd) {
        int nfd = fd * 2 + 64;
        int *by_fd = PyMem_Realloc(e->by_fd, sizeof(int) * (size_t)nfd);
        if (by_fd == NULL) {
            PyBuffer_Release(&source);
            return PyErr_NoMemory();
        }
        for (int i = e->nfd; i < nfd; i++)
            by_fd[i] = -1;
        e->by_fd = by_fd;
        e->nfd = nfd;
    }
    Dev *d = &e->devs[e->ndevs];
    memset(d, 0, sizeof(*d));
    d->fd = fd;
    d->slot = e->ndevs;
    d->changes = e->changes;
    memcpy(&d->source, source.buf, 4);
    PyBuffer_Release(&source);
    Py_INCREF(counters);
    Py_INCREF(traffic);
    d->counters = counters;
    d->traffic = traffic;
    e->by_fd[fd] = e->ndevs;
    if (e->sender < 0)
        e->sender = fd;
    return PyLong_FromLong(e->ndevs++);
}

/* load(slot, conns, streams, outputs_off_on_idle, watch=None): the device in native mode with these
 * connections, each (connection, measure or None, consumed bytearray, originator's 4-byte address[,
 * heartbeat: its O->T carries no data, the header-less heartbeat of an input-only or listen-only one[,
 * observed: each change of its image reported in `changes`]]), and streams, each (production, 6-byte
 * destination, bytearray or None, header bytes, unicast; a T->O of at most MAX_PACKET bytes, else
 * ValueError); watch: the earliest supervision deadline of its other connections (class 3), which hands
 * it to Python when reached. */
static PyObject *engine_load(Engine *e, PyObject *args) {
    PyObject *conns, *streams, *watch = Py_None;
    int off;
    Dev *d = dev_of(e, args, "iO!O!p|O", &PyList_Type, &conns, &PyList_Type, &streams, &off, &watch);
    if (d == NULL)
        return NULL;
    if (d->native && store_dev(d) < 0)
        return NULL;
    clear_dev(d);
    d->watch = watch == Py_None ? LLONG_MAX : PyLong_AsLongLong(watch);
    if (d->watch == -1 && PyErr_Occurred())
        return NULL;
    Py_ssize_t nc = PyList_GET_SIZE(conns), ns = PyList_GET_SIZE(streams);
    d->conns = PyMem_Calloc((size_t)nc + 1, sizeof(Conn));
    d->streams = PyMem_Calloc((size_t)ns + 1, sizeof(Stream));
    if (d->conns == NULL || d->streams == NULL) {
        clear_dev(d);
        return PyErr_NoMemory();
    }
    d->off_on_idle = off;
    for (Py_ssize_t i = 0; i < nc; i++) {
        Conn *c = &d->conns[i];
        PyObject *conn, *measure, *image;
        Py_buffer host;
        int heartbeat = 0, observed = 0;
        if (!PyArg_ParseTuple(PyList_GET_ITEM(conns, i), "OOO!y*|pp", &conn, &measure, &PyByteArray_Type, &image, &host,
                              &heartbeat, &observed))
            goto fail;
        int good = host.len == 4;
        if (good)
            memcpy(&c->host, host.buf, 4);
        c->heartbeat = heartbeat;
        c->observed = observed;
        PyBuffer_Release(&host);
        d->nconns = (int)i + 1;
        Py_INCREF(conn);
        Py_INCREF(image);
        c->conn = conn;
        c->image = image;
        if (measure != Py_None) {
            Py_INCREF(measure);
            c->measure = measure;
        }
        long long id, run, last_received;
        if (!good || get_ll(conn, "o_t_id", &id, 0) || get_ll(conn, "o_t_port", &c->port, -1) ||
            get_ll(conn, "last_sequence", &c->last_sequence, -1) || get_ll(conn, "deadline", &c->deadline, 0) ||
            get_ll(conn, "timeout_ns", &c->timeout_ns, 0) || get_ll(conn, "received", &c->received, 0) ||
            get_ll(conn, "run", &run, 0) || get_ll(conn, "last_received", &last_received, LLONG_MIN) ||
            (c->measure != NULL && load_measure(c, measure) < 0)) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "a 4-byte originator address");
            goto fail;
        }
        c->id = (uint32_t)id;
        c->run = run != 0;
        c->has_last_received = last_received != LLONG_MIN;
        c->last_received = c->has_last_received ? last_received : 0;
    }
    for (Py_ssize_t i = 0; i < ns; i++) {
        Stream *s = &d->streams[i];
        PyObject *production, *data;
        Py_buffer to, header;
        int unicast;
        if (!PyArg_ParseTuple(PyList_GET_ITEM(streams, i), "Oy*Oy*p", &production, &to, &data, &header, &unicast))
            goto fail;
        int good = to.len == 6 && header.len <= 4 && (data == Py_None || PyByteArray_Check(data)) &&
                   HEADER + header.len + (data == Py_None ? 0 : PyByteArray_GET_SIZE(data)) <= MAX_PACKET;
        if (good) {
            s->to.sin_family = AF_INET;
            memcpy(&s->to.sin_addr, to.buf, 4);
            memcpy(&s->to.sin_port, (char *)to.buf + 4, 2);
            memcpy(s->header, header.buf, (size_t)header.len);
            s->header_len = (int)header.len;
        }
        PyBuffer_Release(&to);
        PyBuffer_Release(&header);
        d->nstreams = (int)i + 1;
        Py_INCREF(production);
        s->production = production;
        if (data != Py_None) {
            Py_INCREF(data);
            s->data = data;
        }
        s->unicast = unicast;
        long long id;
        if (!good || get_ll(production, "connection_id", &id, 0) || get_ll(production, "period_ns", &s->period, 1) ||
            get_ll(production, "start", &s->start, 0) || get_ll(production, "count", &s->count, 0) ||
            get_ll(production, "due", &s->due, 0) || get_ll(production, "late", &s->late, 0) ||
            get_ll(production, "sequence", &s->sequence, 0)) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "a stream of another shape, or a T->O over MAX_PACKET bytes");
            goto fail;
        }
        if (s->period <= 0)
            s->period = 1;
        s->id = (uint32_t)id;
    }
    d->native = 1;
    d->dirty = 0;
    Py_RETURN_NONE;
fail:
    clear_dev(d);
    return NULL;
}

/* store(slot, release): the engine's state of the device written into its Python objects (the
 * counters added); release: the device leaves native mode (Python runs it until the next load). */
static PyObject *engine_store(Engine *e, PyObject *args) {
    int release = 0;
    Dev *d = dev_of(e, args, "i|p", &release, NULL, NULL, NULL, NULL, NULL);
    if (d == NULL)
        return NULL;
    if (!d->native)
        Py_RETURN_FALSE;
    if (store_dev(d) < 0) {
        clear_dev(d); /* Python takes over with what it has */
        return NULL;
    }
    if (release) { /* Python's now; what the engine held is kept for `resume` */
        d->native = 0;
        d->kept = 1;
    }
    Py_RETURN_TRUE;
}

static int same(PyObject *o, const char *name, long long value, long long none) {
    long long now;
    if (get_ll(o, name, &now, none) < 0) {
        PyErr_Clear();
        return 0;
    }
    return now == value;
}

/* Whether a produced image grew past what a packet of the engine holds (Python may resize it): the
 * device is Python's then (its T->O whole, never cut short). */
static int oversize(const Dev *d) {
    for (int i = 0; i < d->nstreams; i++)
        if (d->streams[i].data != NULL &&
            HEADER + d->streams[i].header_len + PyByteArray_GET_SIZE(d->streams[i].data) > MAX_PACKET)
            return 1;
    return 0;
}

/* resume(slot) -> bool: the device back in native mode with what the engine held when it was released,
 * if Python changed none of it meanwhile (a transaction that did not touch its connections: an
 * explicit request); False: `load` it again. */
static PyObject *engine_resume(Engine *e, PyObject *args) {
    Dev *d = dev_of(e, args, "i", NULL, NULL, NULL, NULL, NULL, NULL);
    if (d == NULL)
        return NULL;
    if (!d->kept || d->watched || oversize(d))
        Py_RETURN_FALSE;
    for (int i = 0; i < d->nconns; i++) {
        Conn *c = &d->conns[i];
        PyObject *o = c->conn, *m = c->measure;
        if (!same(o, "received", c->received, -1) || !same(o, "last_sequence", c->last_sequence, -1) ||
            !same(o, "deadline", c->deadline, LLONG_MIN) || !same(o, "run", c->run, -1) ||
            !same(o, "o_t_port", c->port, -1) || !same(o, "closed", 0, -1) ||
            (m != NULL && (!same(m, "packets", c->packets, -1) || !same(m, "stale", c->stale, -1) ||
                           !same(m, "repeats", c->repeats, -1))))
            Py_RETURN_FALSE;
    }
    for (int i = 0; i < d->nstreams; i++) {
        Stream *s = &d->streams[i];
        if (!same(s->production, "count", s->count, -1) || !same(s->production, "sequence", s->sequence, -1) ||
            !same(s->production, "due", s->due, LLONG_MIN) || !same(s->production, "users", 1, -1))
            Py_RETURN_FALSE;
    }
    d->native = 1;
    d->kept = 0;
    Py_RETURN_TRUE;
}

/* sync(count) -> devices written: the next `count` devices (in turn, round the engine) written into
 * their Python objects if they changed, the engine keeping them: the I/O thread's periodic refresh in
 * slices (a few devices a turn, so no turn stalls), so that a reader without the lock lags at most
 * one round. */
static PyObject *engine_sync(Engine *e, PyObject *args) {
    int count;
    if (!PyArg_ParseTuple(args, "i", &count))
        return NULL;
    long written = 0;
    for (int n = 0; n < count && n < e->ndevs; n++) {
        if (e->next_sync >= e->ndevs)
            e->next_sync = 0;
        Dev *d = &e->devs[e->next_sync++];
        if (!d->native || !d->dirty)
            continue;
        if (store_dev(d) < 0) {
            clear_dev(d);
            return NULL;
        }
        written++;
    }
    return PyLong_FromLong(written);
}

static PyObject *engine_turns(Engine *e, PyObject *noargs) { return PyLong_FromLongLong(e->turns); }

static PyObject *engine_native(Engine *e, PyObject *args) {
    Dev *d = dev_of(e, args, "i", NULL, NULL, NULL, NULL, NULL, NULL);
    if (d == NULL)
        return NULL;
    return PyBool_FromLong(d->native);
}

/* -- O->T (cip/io_packets.py `receive`, cip/o_t_measure.py `o_t`) --------------------------------- */

static void measure_o_t(Conn *c, long long at, uint32_t sequence, unsigned count) {
    if (c->m_last_sequence >= 0) {
        long long delta = ((long long)sequence - c->m_last_sequence) & 0xFFFFFFFFLL;
        if (delta != 1) {
            if (delta == 0) {
                c->repeats++;
                return;
            }
            if (delta >= HALF) {
                c->stale++;
                return;
            }
            c->lost += delta - 1;
            c->gaps++;
        }
        long long interval = at - c->last_at;
        if (interval < 0)
            interval = 0;
        int lo = 0, hi = NBOUNDS; /* bisect_left */
        while (lo < hi) {
            int mid = (lo + hi) / 2;
            if (c->bounds[mid] < interval)
                lo = mid + 1;
            else
                hi = mid;
        }
        c->counts[lo]++;
        c->total += interval;
        if (interval > c->max)
            c->max = interval;
        if (!c->has_min || interval < c->min) {
            c->min = interval;
            c->has_min = 1;
        }
        unsigned step = (count - (unsigned)c->last_count) & 0xFFFF;
        if (step != 1) {
            if (step == 0)
                c->cip_same++;
            else
                c->cip_skipped++;
        }
    } else {
        c->first_at = at;
        c->has_first = 1;
    }
    c->m_last_sequence = sequence;
    c->last_count = count;
    c->last_at = at;
    c->packets++;
}

static uint32_t le32(const unsigned char *p) { return p[0] | p[1] << 8 | p[2] << 16 | (uint32_t)p[3] << 24; }
static unsigned le16(const unsigned char *p) { return p[0] | p[1] << 8; }

static int zeros(const char *p, Py_ssize_t n) {
    for (Py_ssize_t i = 0; i < n; i++)
        if (p[i])
            return 0;
    return 1;
}

/* An observed connection's O->T about to be consumed: (slot, now, before, after) in the device's
 * `changes` when it changes the image (device/guard.py's ImageChanged of the Python path's
 * transaction), before anything changes; -1 (no exception left set) when that cannot be told. */
static int observe(Dev *d, Conn *c, const unsigned char *p, Py_ssize_t size, int run, long long now) {
    const char *image = PyByteArray_AS_STRING(c->image);
    if (run ? memcmp(image, p + IMAGE, (size_t)size) == 0 : !d->off_on_idle || zeros(image, size))
        return 0;
    PyObject *after = run ? PyBytes_FromStringAndSize((const char *)p + IMAGE, size) : PyBytes_FromStringAndSize(NULL, size);
    if (after != NULL && !run)
        memset(PyBytes_AS_STRING(after), 0, (size_t)size);
    PyObject *change = after == NULL ? NULL : Py_BuildValue("(iLy#O)", d->slot, now, image, size, after);
    int r = change == NULL || d->changes == NULL ? -1 : PyList_Append(d->changes, change);
    Py_XDECREF(after);
    Py_XDECREF(change);
    if (r < 0)
        PyErr_Clear();
    return r;
}

/* One O->T datagram of a native device: 1 if the engine took or dropped it (counted), 0 if it is
 * Python's (nothing changed). */
static int consume(Dev *d, const unsigned char *p, Py_ssize_t n, uint32_t host, long long port, long long now,
                   long long at) {
    if (!d->native || n < HEADER || le16(p) != 2 || le16(p + 2) != 0x8002 || le16(p + 4) != 8 ||
        le16(p + 14) != 0x00B1 || (Py_ssize_t)le16(p + 16) != n - 18)
        return 0; /* malformed, or another shape: Python's words for it */
    uint32_t id = le32(p + 6), sequence = le32(p + 10);
    unsigned count = le16(p + 18);
    Conn *c = NULL;
    for (int i = 0; i < d->nconns; i++)
        if (d->conns[i].id == id) {
            c = &d->conns[i];
            break;
        }
    if (c == NULL)
        return 0; /* unknown connection */
    int drop = -1;
    if (host != c->host)
        drop = C_ORIGINATOR;
    else if (c->port >= 0 && port != c->port)
        drop = C_PORT;
    Py_ssize_t size = PyByteArray_GET_SIZE(c->image);
    long long step = ((long long)sequence - c->last_sequence) & 0xFFFFFFFFLL;
    int stale = c->last_sequence >= 0 && !(step > 0 && step < HALF);
    int sized, run;
    if (c->heartbeat) { /* nothing, or the run/idle header alone */
        sized = n == HEADER || n == IMAGE;
        run = n == HEADER || (p[HEADER] & 1);
    } else {
        sized = n >= IMAGE && n - IMAGE == size;
        run = n >= IMAGE && (p[HEADER] & 1);
    }
    if (drop < 0 && !stale && sized && run != c->run)
        return 0; /* a run/idle change: Python's (the measurement's transitions, maybe events) */
    if (c->observed && drop < 0 && !stale && sized && !c->heartbeat && observe(d, c, p, size, run, now) < 0)
        return 0; /* no memory to tell it: Python's (nothing changed) */
    d->dirty = 1;
    d->traffic_delta[T_IN_OCTETS] += n;
    d->traffic_delta[T_IN_UCAST]++;
    if (drop < 0) {
        if (c->measure != NULL)
            measure_o_t(c, at, sequence, count);
        drop = stale ? C_STALE : !sized ? C_SIZE : -1;
    }
    if (drop >= 0) {
        d->counter[drop]++;
        d->traffic_delta[T_IN_DISCARDS]++;
        return 1;
    }
    c->last_sequence = sequence;
    if (c->port < 0)
        c->port = port;
    c->last_received = now;
    c->has_last_received = 1;
    c->deadline = now + c->timeout_ns;
    c->received++;
    d->counter[C_OT]++;
    if (c->heartbeat)
        return 1;
    if (run)
        memcpy(PyByteArray_AS_STRING(c->image), p + IMAGE, (size_t)size);
    else if (d->off_on_idle)
        memset(PyByteArray_AS_STRING(c->image), 0, (size_t)size);
    return 1;
}

/* consume(slot, data, host, port, now, received_at) -> bool: the sans-IO entry (tests). */
static PyObject *engine_consume(Engine *e, PyObject *args) {
    Py_buffer data, host;
    int slot, port;
    long long now, at;
    if (!PyArg_ParseTuple(args, "iy*y*iLL", &slot, &data, &host, &port, &now, &at))
        return NULL;
    if (slot < 0 || slot >= e->ndevs) { /* the buffers given back: a bytearray stays resizable */
        PyBuffer_Release(&data);
        PyBuffer_Release(&host);
        PyErr_SetString(PyExc_IndexError, "no such device slot");
        return NULL;
    }
    Dev *d = &e->devs[slot];
    uint32_t address = 0;
    if (host.len == 4)
        memcpy(&address, host.buf, 4);
    int taken = consume(d, data.buf, data.len, address, port, now, at ? at : now);
    PyBuffer_Release(&data);
    PyBuffer_Release(&host);
    return PyBool_FromLong(taken);
}

/* receive(fds, limit, now) -> (rest, taken): up to `limit` datagrams from each socket (recvmmsg,
 * kernel receive times on the monotonic clock as server/_mmsg.c makes them); those of native
 * devices consumed here, the rest as server/batch.py's tuples (fd, payload, host, port, received_at). */
static PyObject *engine_receive(Engine *e, PyObject *args) {
    PyObject *fds;
    int limit;
    long long now;
    if (!PyArg_ParseTuple(args, "O!iL", &PyList_Type, &fds, &limit, &now))
        return NULL;
    if (limit < 1 || limit > MAX_RECEIVE)
        limit = MAX_RECEIVE;
    PyObject *rest = PyList_New(0);
    if (rest == NULL)
        return NULL;
    char (*buffers)[MAX_DATAGRAM] = e->buffers;
    Received r;
    long long taken = 0;
    for (Py_ssize_t f = 0; f < PyList_GET_SIZE(fds); f++) {
        int fd = (int)PyLong_AsLong(PyList_GET_ITEM(fds, f));
        if (fd == -1 && PyErr_Occurred()) {
            Py_DECREF(rest);
            return NULL;
        }
        int received = receive_batch(fd, &r, buffers, limit);
        Dev *d = fd < e->nfd && e->by_fd[fd] >= 0 ? &e->devs[e->by_fd[fd]] : NULL;
        for (int i = 0; i < received; i++) {
            long long at = received_at(&r, i);
            size_t length = received_length(&r, i);
            int port = ntohs(r.sources[i].sin_port);
            if (d != NULL && consume(d, (unsigned char *)buffers[i], (Py_ssize_t)length, r.sources[i].sin_addr.s_addr,
                                     port, now, at ? at : now)) {
                taken++;
                continue;
            }
            d = NULL; /* one datagram handed to Python: the rest of this socket's go after it, in order */
            char host[INET_ADDRSTRLEN];
            if (inet_ntop(AF_INET, &r.sources[i].sin_addr, host, sizeof(host)) == NULL)
                host[0] = '\0';
            PyObject *item = Py_BuildValue("(iy#siL)", fd, buffers[i], (Py_ssize_t)length, host, port, at);
            if (item == NULL || PyList_Append(rest, item) < 0) {
                Py_XDECREF(item);
                Py_DECREF(rest);
                return NULL;
            }
            Py_DECREF(item);
        }
    }
    return Py_BuildValue("(NL)", rest, taken);
}

/* -- T->O and supervision (cip/io_schedule.py `produce`, cip/io_packets.py `produce`) ------------- */

static int flush(Engine *e) {
    int n = e->queued, done = 0, failed = 0;
    while (done < n) {
        int sent = sendmmsg(e->sender, e->headers + done, (unsigned int)(n - done), MSG_DONTWAIT);
        if (sent < 0) {
            if (errno == EINTR)
                continue;
            Dev *d = &e->devs[e->from[done]];
            d->counter[C_SEND_ERRORS]++;
            d->traffic_delta[T_OUT_ERRORS]++;
            d->dirty = 1;
            failed++;
            done++;
        } else {
            done += sent;
        }
    }
    e->queued = 0;
    return failed;
}

/* One T->O packet (protocol/connection.py encode_io_packet) into the batch, or into `collect`. */
static int emit(Engine *e, int slot, Stream *s, PyObject *collect) {
    Dev *d = &e->devs[slot];
    Py_ssize_t data_len = s->data != NULL ? PyByteArray_GET_SIZE(s->data) : 0;
    Py_ssize_t payload = s->header_len + data_len, n = HEADER + payload;
    if (n > MAX_PACKET)
        n = MAX_PACKET, payload = n - HEADER, data_len = payload - s->header_len;
    unsigned char buffer[MAX_PACKET], *p = collect != NULL || e->sender < 0 ? buffer : e->packets[e->queued];
    s->sequence++;
    uint32_t seq = (uint32_t)s->sequence;
    unsigned char head[HEADER] = {2, 0, 0x02, 0x80, 8, 0, (unsigned char)s->id, (unsigned char)(s->id >> 8),
                                  (unsigned char)(s->id >> 16), (unsigned char)(s->id >> 24), (unsigned char)seq,
                                  (unsigned char)(seq >> 8), (unsigned char)(seq >> 16), (unsigned char)(seq >> 24),
                                  0xB1, 0, (unsigned char)(2 + payload), (unsigned char)((2 + payload) >> 8),
                                  (unsigned char)seq, (unsigned char)(seq >> 8)};
    memcpy(p, head, HEADER);
    memcpy(p + HEADER, s->header, (size_t)s->header_len);
    if (data_len > 0)
        memcpy(p + HEADER + s->header_len, PyByteArray_AS_STRING(s->data), (size_t)data_len);
    d->counter[C_TO]++;
    d->traffic_delta[T_OUT_OCTETS] += n;
    d->traffic_delta[s->unicast ? T_OUT_UCAST : T_OUT_NUCAST]++;
    if (collect != NULL) {
        char host[INET_ADDRSTRLEN];
        inet_ntop(AF_INET, &s->to.sin_addr, host, sizeof(host));
        PyObject *item = Py_BuildValue("(iy#(si))", slot, p, n, host, (int)ntohs(s->to.sin_port));
        int r = item == NULL ? -1 : PyList_Append(collect, item);
        Py_XDECREF(item);
        return r;
    }
    if (e->sender < 0)
        return 0;
    int q = e->queued;
    e->to[q] = s->to;
    e->vectors[q].iov_base = p;
    e->vectors[q].iov_len = (size_t)n;
    struct msghdr *h = &e->headers[q].msg_hdr;
    memset(h, 0, sizeof(*h));
    h->msg_name = &e->to[q];
    h->msg_namelen = sizeof(e->to[q]);
    h->msg_iov = &e->vectors[q];
    h->msg_iovlen = 1;
    memset(e->controls[q].buffer, 0, sizeof(e->controls[q].buffer));
    h->msg_control = e->controls[q].buffer;
    h->msg_controllen = sizeof(e->controls[q].buffer);
    struct cmsghdr *control = CMSG_FIRSTHDR(h);
    control->cmsg_level = IPPROTO_IP;
    control->cmsg_type = IP_PKTINFO;
    control->cmsg_len = CMSG_LEN(sizeof(struct in_pktinfo));
    struct in_pktinfo info;
    memset(&info, 0, sizeof(info));
    info.ipi_spec_dst.s_addr = d->source;
    memcpy(CMSG_DATA(control), &info, sizeof(info));
    e->from[q] = slot;
    if (++e->queued == MAX_BATCH)
        flush(e);
    return 0;
}

/* produce(now, horizon, collect=False, supervise=True) -> (python, timer, served, sent, packets): every native device
 * supervised at `now` (one whose deadline has come is Python's: its slot in `python`) and its T->O due
 * by `horizon` produced and sent (collect: returned in `packets` as (slot, bytes, (host, port)) instead);
 * `timer`: the earliest native deadline after them, `served`: the earliest deadline served (None: none).
 * supervise=False: a device whose deadline has come is neither produced nor handed over (the I/O
 * thread's turn that left sockets unread: their datagrams may feed that deadline). */
static PyObject *engine_produce(Engine *e, PyObject *args) {
    long long now, horizon;
    int collecting = 0, supervise = 1;
    if (!PyArg_ParseTuple(args, "LL|pp", &now, &horizon, &collecting, &supervise))
        return NULL;
    long long until = horizon < now ? now : horizon, timer = LLONG_MAX, served = LLONG_MAX, sent = 0;
    e->turns++;
    PyObject *python = PyList_New(0), *collect = collecting ? PyList_New(0) : NULL;
    if (python == NULL || (collecting && collect == NULL))
        goto fail;
    for (int slot = 0; slot < e->ndevs; slot++) {
        Dev *d = &e->devs[slot];
        if (!d->native)
            continue;
        int expired = d->watch <= now;
        if (expired)
            d->watched = 1;
        for (int i = 0; i < d->nconns; i++)
            if (d->conns[i].deadline <= now)
                expired = 1;
        if (expired && !supervise) /* datagrams may still wait unread: no verdict on it this turn */
            continue;
        if (expired || oversize(d)) { /* a timeout, or an image past a packet: Python's (pull, handle_timer, push) */
            PyObject *s = PyLong_FromLong(slot);
            if (s == NULL || PyList_Append(python, s) < 0) {
                Py_XDECREF(s);
                goto fail;
            }
            Py_DECREF(s);
            continue;
        }
        for (int i = 0; i < d->nstreams; i++) {
            Stream *s = &d->streams[i];
            long long due = s->due;
            if (due <= until) {
                if (due < served)
                    served = due;
                s->count++;
                long long behind = now - due - s->period;
                if (behind >= 0) {
                    long long skipped = behind / s->period + 1;
                    s->count += skipped;
                    s->late += skipped;
                }
                s->due = due = s->start + s->count * s->period;
                d->dirty = 1;
                if (emit(e, slot, s, collect) < 0)
                    goto fail;
                sent++;
            }
            if (due < timer)
                timer = due;
        }
        for (int i = 0; i < d->nconns; i++)
            if (d->conns[i].deadline < timer)
                timer = d->conns[i].deadline;
        if (d->watch < timer)
            timer = d->watch;
    }
    if (e->queued)
        flush(e);
    PyObject *t = timer == LLONG_MAX ? Py_NewRef(Py_None) : PyLong_FromLongLong(timer);
    PyObject *f = served == LLONG_MAX ? Py_NewRef(Py_None) : PyLong_FromLongLong(served);
    return Py_BuildValue("(NNNLN)", python, t, f, sent, collect != NULL ? collect : Py_NewRef(Py_None));
fail:
    e->queued = 0;
    Py_XDECREF(python);
    Py_XDECREF(collect);
    return NULL;
}

/* timer(slot) -> the device's next deadline (T->O or supervision), None when it has none or is not native. */
static PyObject *engine_timer(Engine *e, PyObject *args) {
    Dev *d = dev_of(e, args, "i", NULL, NULL, NULL, NULL, NULL, NULL);
    if (d == NULL)
        return NULL;
    long long timer = LLONG_MAX;
    for (int i = 0; d->native && i < d->nstreams; i++)
        if (d->streams[i].due < timer)
            timer = d->streams[i].due;
    for (int i = 0; d->native && i < d->nconns; i++)
        if (d->conns[i].deadline < timer)
            timer = d->conns[i].deadline;
    if (d->native && d->watch < timer)
        timer = d->watch;
    if (timer == LLONG_MAX)
        Py_RETURN_NONE;
    return PyLong_FromLongLong(timer);
}

/* -- the type --------------------------------------------------------------------------------------- */

static PyObject *engine_new(PyTypeObject *type, PyObject *args, PyObject *kwargs) {
    Engine *e = (Engine *)type->tp_alloc(type, 0);
    if (e == NULL)
        return NULL;
    e->sender = -1;
    if ((e->changes = PyList_New(0)) == NULL) {
        Py_DECREF(e);
        return NULL;
    }
    return (PyObject *)e;
}

static void engine_dealloc(Engine *e) {
    for (int i = 0; i < e->ndevs; i++) {
        clear_dev(&e->devs[i]);
        Py_XDECREF(e->devs[i].counters);
        Py_XDECREF(e->devs[i].traffic);
    }
    PyMem_Free(e->devs);
    PyMem_Free(e->by_fd);
    Py_XDECREF(e->changes);
    Py_TYPE(e)->tp_free((PyObject *)e);
}

static PyMethodDef engine_methods[] = {
    {"add", (PyCFunction)engine_add, METH_VARARGS, "add(fd, source, counters, traffic) -> slot"},
    {"load", (PyCFunction)engine_load, METH_VARARGS, "load(slot, conns, streams, outputs_off_on_idle, watch=None)"},
    {"store", (PyCFunction)engine_store, METH_VARARGS, "store(slot, release=False) -> was native"},
    {"sync", (PyCFunction)engine_sync, METH_VARARGS, "sync(count) -> devices written back"},
    {"turns", (PyCFunction)engine_turns, METH_NOARGS, "turns() -> produce calls so far"},
    {"resume", (PyCFunction)engine_resume, METH_VARARGS, "resume(slot) -> bool: native again, if nothing changed"},
    {"native", (PyCFunction)engine_native, METH_VARARGS, "native(slot) -> bool"},
    {"consume", (PyCFunction)engine_consume, METH_VARARGS, "consume(slot, data, host, port, now, received_at)"},
    {"receive", (PyCFunction)engine_receive, METH_VARARGS, "receive(fds, limit, now) -> (rest, taken)"},
    {"produce", (PyCFunction)engine_produce, METH_VARARGS, "produce(now, horizon, collect=False, supervise=True)"},
    {"timer", (PyCFunction)engine_timer, METH_VARARGS, "timer(slot) -> next deadline or None"},
    {NULL, NULL, 0, NULL},
};

static PyMemberDef engine_members[] = {
    {"changes", T_OBJECT_EX, offsetof(Engine, changes), READONLY,
     "[(slot, now, before, after)]: the output image changes of observed connections, in order (the "
     "caller takes and clears them)"},
    {NULL, 0, 0, 0, NULL},
};

static PyTypeObject EngineType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "enip_farm.server._class1.Engine",
    .tp_basicsize = sizeof(Engine),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = engine_new,
    .tp_dealloc = (destructor)engine_dealloc,
    .tp_methods = engine_methods,
    .tp_members = engine_members,
    .tp_doc = "The class-1 per-packet work of the native devices of one cyclic I/O thread.",
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_class1", NULL, -1, NULL};

PyMODINIT_FUNC PyInit__class1(void) {
    if (PyType_Ready(&EngineType) < 0)
        return NULL;
    for (int i = 0; i < NCOUNTERS; i++)
        if (counter_keys[i] == NULL && (counter_keys[i] = PyUnicode_InternFromString(counter_names[i])) == NULL)
            return NULL;
    for (int i = 0; i < NTRAFFIC; i++)
        if (traffic_keys[i] == NULL && (traffic_keys[i] = PyUnicode_InternFromString(traffic_names[i])) == NULL)
            return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    if (PyModule_AddIntConstant(m, "MAX_T_O_PAYLOAD", MAX_PACKET - HEADER) < 0) { /* run/idle header and data */
        Py_DECREF(m);
        return NULL;
    }
    Py_INCREF(&EngineType);
    if (PyModule_AddObject(m, "Engine", (PyObject *)&EngineType) < 0) {
        Py_DECREF(&EngineType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
