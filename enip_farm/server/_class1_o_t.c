/* O->T of the native class-1 engine (_class1.h): the consumption of a native device's datagrams on
 * UDP 2222 (CIP Networks Library Vol. 2, 3-2; cip/io_packets.py `receive`: originator, port, sequence,
 * size, run/idle, the supervision deadline of Vol. 1, 3-4.4.9 renewed), the originator measurement
 * (Vol. 2, 3-2.1's sequences; cip/o_t_measure.py `o_t`) and the socket receive (recvmmsg,
 * server/_receive.h). */
#include "_class1.h"

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
PyObject *c1_consume(Engine *e, PyObject *args) {
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
PyObject *c1_receive(Engine *e, PyObject *args) {
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
