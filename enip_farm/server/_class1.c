/* The native class-1 engine's type and module (_class1.h; CIP Networks Library Vol. 2, 3-2 and 3-3):
 * `Engine`, one per cyclic I/O thread, its table of devices (`add`: a device's UDP 2222 socket),
 * new/dealloc, the methods (the state moves of _class1_state.c, the O->T of _class1_o_t.c, the T->O
 * and supervision of _class1_t_o.c) and PyInit__class1 (the counters' keys interned). */
#include "_class1.h"

#include <structmember.h>

static const char *counter_names[NCOUNTERS] = {"o_t_packets", "t_o_packets", "o_t_dropped_wrong_originator",
                                               "o_t_dropped_wrong_port", "o_t_dropped_stale",
                                               "o_t_dropped_wrong_size", "t_o_send_errors"};
static const char *traffic_names[NTRAFFIC] = {"in_octets", "in_ucast", "in_discards", "out_octets",
                                              "out_ucast", "out_nucast", "out_errors"};
PyObject *c1_counter_keys[NCOUNTERS], *c1_traffic_keys[NTRAFFIC]; /* interned at import */

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

static PyObject *engine_new(PyTypeObject *type, PyObject *args, PyObject *kwargs) {
    (void)args;
    (void)kwargs;
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
        c1_clear_dev(&e->devs[i]);
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
    {"load", (PyCFunction)c1_load, METH_VARARGS, "load(slot, conns, streams, outputs_off_on_idle, watch=None)"},
    {"store", (PyCFunction)c1_store, METH_VARARGS, "store(slot, release=False) -> was native"},
    {"sync", (PyCFunction)c1_sync, METH_VARARGS, "sync(count) -> devices written back"},
    {"turns", (PyCFunction)c1_turns, METH_NOARGS, "turns() -> produce calls so far"},
    {"resume", (PyCFunction)c1_resume, METH_VARARGS, "resume(slot) -> bool: native again, if nothing changed"},
    {"native", (PyCFunction)c1_native, METH_VARARGS, "native(slot) -> bool"},
    {"consume", (PyCFunction)c1_consume, METH_VARARGS, "consume(slot, data, host, port, now, received_at)"},
    {"receive", (PyCFunction)c1_receive, METH_VARARGS, "receive(fds, limit, now) -> (rest, taken)"},
    {"produce", (PyCFunction)c1_produce, METH_VARARGS, "produce(now, horizon, collect=False, supervise=True)"},
    {"timer", (PyCFunction)c1_timer, METH_VARARGS, "timer(slot) -> next deadline or None"},
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

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, .m_name = "_class1", .m_size = -1};

PyMODINIT_FUNC PyInit__class1(void) {
    if (PyType_Ready(&EngineType) < 0)
        return NULL;
    for (int i = 0; i < NCOUNTERS; i++)
        if (c1_counter_keys[i] == NULL && (c1_counter_keys[i] = PyUnicode_InternFromString(counter_names[i])) == NULL)
            return NULL;
    for (int i = 0; i < NTRAFFIC; i++)
        if (c1_traffic_keys[i] == NULL && (c1_traffic_keys[i] = PyUnicode_InternFromString(traffic_names[i])) == NULL)
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
