/* The state moves between the native class-1 engine (_class1.h) and Python: server/native.py's side.
 * A device's connections (CIP Networks Library Vol. 2, 3-2: sequence, pinned port, run/idle; Vol. 1,
 * 3-4.4.9: the supervision deadline), its T->O streams (Vol. 2, 3-3) and its originator measurement
 * (cip/o_t_measure.py) loaded from their Python objects (`load`), written back into them (`store`,
 * `sync`, the counters added as deltas), handed back unchanged (`resume`) when Python touched none. */
#include "_class1.h"

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

void c1_clear_dev(Dev *d) {
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
        if (delta && add_to(d->counters, 1, c1_counter_keys[i], delta) < 0)
            return -1;
    }
    for (int i = 0; i < NTRAFFIC; i++) {
        long long delta = d->traffic_delta[i];
        d->traffic_delta[i] = 0;
        if (delta && add_to(d->traffic, 0, c1_traffic_keys[i], delta) < 0)
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

/* The device of the slot that `args` (`format`, the slot first) names, the rest parsed into a..g. */
Dev *c1_dev_of(Engine *e, PyObject *args, const char *format, void *a, void *b, void *c, void *d_, void *f,
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
/* load(slot, conns, streams, outputs_off_on_idle, watch=None): the device in native mode with these
 * connections, each (connection, measure or None, consumed bytearray, originator's 4-byte address[,
 * heartbeat: its O->T carries no data, the header-less heartbeat of an input-only or listen-only one[,
 * observed: each change of its image reported in `changes`]]), and streams, each (production, 6-byte
 * destination, bytearray or None, header bytes, unicast; a T->O of at most MAX_PACKET bytes, else
 * ValueError); watch: the earliest supervision deadline of its other connections (class 3), which hands
 * it to Python when reached. */
PyObject *c1_load(Engine *e, PyObject *args) {
    PyObject *conns, *streams, *watch = Py_None;
    int off;
    Dev *d = c1_dev_of(e, args, "iO!O!p|O", &PyList_Type, &conns, &PyList_Type, &streams, &off, &watch);
    if (d == NULL)
        return NULL;
    if (d->native && store_dev(d) < 0)
        return NULL;
    c1_clear_dev(d);
    d->watch = watch == Py_None ? LLONG_MAX : PyLong_AsLongLong(watch);
    if (d->watch == -1 && PyErr_Occurred())
        return NULL;
    Py_ssize_t nc = PyList_GET_SIZE(conns), ns = PyList_GET_SIZE(streams);
    d->conns = PyMem_Calloc((size_t)nc + 1, sizeof(Conn));
    d->streams = PyMem_Calloc((size_t)ns + 1, sizeof(Stream));
    if (d->conns == NULL || d->streams == NULL) {
        c1_clear_dev(d);
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
    c1_clear_dev(d);
    return NULL;
}

/* store(slot, release): the engine's state of the device written into its Python objects (the
 * counters added); release: the device leaves native mode (Python runs it until the next load). */
PyObject *c1_store(Engine *e, PyObject *args) {
    int release = 0;
    Dev *d = c1_dev_of(e, args, "i|p", &release, NULL, NULL, NULL, NULL, NULL);
    if (d == NULL)
        return NULL;
    if (!d->native)
        Py_RETURN_FALSE;
    if (store_dev(d) < 0) {
        c1_clear_dev(d); /* Python takes over with what it has */
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
int c1_oversize(const Dev *d) {
    for (int i = 0; i < d->nstreams; i++)
        if (d->streams[i].data != NULL &&
            HEADER + d->streams[i].header_len + PyByteArray_GET_SIZE(d->streams[i].data) > MAX_PACKET)
            return 1;
    return 0;
}

/* resume(slot) -> bool: the device back in native mode with what the engine held when it was released,
 * if Python changed none of it meanwhile (a transaction that did not touch its connections: an
 * explicit request); False: `load` it again. */
PyObject *c1_resume(Engine *e, PyObject *args) {
    Dev *d = c1_dev_of(e, args, "i", NULL, NULL, NULL, NULL, NULL, NULL);
    if (d == NULL)
        return NULL;
    if (!d->kept || d->watched || c1_oversize(d))
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
PyObject *c1_sync(Engine *e, PyObject *args) {
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
            c1_clear_dev(d);
            return NULL;
        }
        written++;
    }
    return PyLong_FromLong(written);
}

/* native(slot) -> bool: whether the engine runs the device now. */
PyObject *c1_native(Engine *e, PyObject *args) {
    Dev *d = c1_dev_of(e, args, "i", NULL, NULL, NULL, NULL, NULL, NULL);
    if (d == NULL)
        return NULL;
    return PyBool_FromLong(d->native);
}
