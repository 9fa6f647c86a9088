/* T->O and supervision of the native class-1 engine (_class1.h): each native device's streams
 * produced on their absolute deadlines (CIP Networks Library Vol. 2, 3-3: a packet every RPI;
 * cip/io_schedule.py `produce`, cip/io_packets.py `produce`), its connections supervised (Vol. 1,
 * 3-4.4.9: a deadline reached is Python's), and the packets sent together (sendmmsg, from the
 * device's own address). */
#include "_class1.h"

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
PyObject *c1_produce(Engine *e, PyObject *args) {
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
        if (expired || c1_oversize(d)) { /* a timeout, or an image past a packet: Python's (pull, handle_timer, push) */
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
PyObject *c1_timer(Engine *e, PyObject *args) {
    Dev *d = c1_dev_of(e, args, "i", NULL, NULL, NULL, NULL, NULL, NULL);
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

/* turns() -> produce calls so far (a device loaded again after one ran without it is rescheduled). */
PyObject *c1_turns(Engine *e, PyObject *noargs) {
    (void)noargs;
    return PyLong_FromLongLong(e->turns);
}
