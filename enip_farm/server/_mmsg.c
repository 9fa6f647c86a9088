/* Batched UDP for the cyclic I/O thread (server/batch.py): recvmmsg(2) over the device sockets that
 * epoll reported ready, each datagram with the kernel's receive time (SO_TIMESTAMPNS, CLOCK_REALTIME,
 * turned into CLOCK_MONOTONIC ns by the offset between the two clocks read once per call: the wall clock
 * between two monotonic reads, against their midpoint), and
 * sendmmsg(2) of every T->O packet due in one tick from one socket, each with its device's source
 * address (IP_PKTINFO, ipi_spec_dst). One system call per socket read and one per tick sent, instead
 * of one per datagram. Linux only; server/batch.py falls back to recvmsg/sendto when this module is
 * not built. The receiving half is server/_receive.h's, shared with server/_class1_o_t.c. */
#define _GNU_SOURCE
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>

#include "_receive.h"

#define MAX_BATCH 256

/* send_batch(fd, messages) -> list of (index, errno): messages is a list of (payload, destination,
 * source); destination is 6 bytes (IPv4 address, port, both in network order), source 4 bytes
 * (the device's IPv4 address) or b"" for the socket's own. */
static PyObject *send_batch(PyObject *self, PyObject *args) {
    int fd;
    PyObject *messages;
    if (!PyArg_ParseTuple(args, "iO!", &fd, &PyList_Type, &messages))
        return NULL;
    Py_ssize_t count = PyList_GET_SIZE(messages);
    PyObject *failures = PyList_New(0);
    if (failures == NULL)
        return NULL;
    struct mmsghdr headers[MAX_BATCH];
    struct iovec vectors[MAX_BATCH];
    struct sockaddr_in destinations[MAX_BATCH];
    union {
        char buffer[CMSG_SPACE(sizeof(struct in_pktinfo))];
        struct cmsghdr align;
    } controls[MAX_BATCH];
    Py_ssize_t start = 0;
    while (start < count) {
        Py_ssize_t n = count - start < MAX_BATCH ? count - start : MAX_BATCH;
        for (Py_ssize_t i = 0; i < n; i++) {
            PyObject *item = PyList_GET_ITEM(messages, start + i);
            if (!PyTuple_Check(item) || PyTuple_GET_SIZE(item) != 3) {
                Py_DECREF(failures);
                PyErr_SetString(PyExc_TypeError, "a message is (payload, destination, source)");
                return NULL;
            }
            PyObject *payload = PyTuple_GET_ITEM(item, 0), *destination = PyTuple_GET_ITEM(item, 1),
                     *source = PyTuple_GET_ITEM(item, 2);
            if (!PyBytes_Check(payload) || !PyBytes_Check(destination) || PyBytes_GET_SIZE(destination) != 6 ||
                !PyBytes_Check(source) || (PyBytes_GET_SIZE(source) != 4 && PyBytes_GET_SIZE(source) != 0)) {
                Py_DECREF(failures);
                PyErr_SetString(PyExc_TypeError, "payload bytes, destination 6 bytes, source 4 or 0 bytes");
                return NULL;
            }
            const char *to = PyBytes_AS_STRING(destination);
            memset(&destinations[i], 0, sizeof(destinations[i]));
            destinations[i].sin_family = AF_INET;
            memcpy(&destinations[i].sin_addr, to, 4);
            memcpy(&destinations[i].sin_port, to + 4, 2);
            vectors[i].iov_base = PyBytes_AS_STRING(payload);
            vectors[i].iov_len = (size_t)PyBytes_GET_SIZE(payload);
            struct msghdr *header = &headers[i].msg_hdr;
            memset(header, 0, sizeof(*header));
            header->msg_name = &destinations[i];
            header->msg_namelen = sizeof(destinations[i]);
            header->msg_iov = &vectors[i];
            header->msg_iovlen = 1;
            if (PyBytes_GET_SIZE(source) == 4) {
                memset(controls[i].buffer, 0, sizeof(controls[i].buffer));
                header->msg_control = controls[i].buffer;
                header->msg_controllen = sizeof(controls[i].buffer);
                struct cmsghdr *control = CMSG_FIRSTHDR(header);
                control->cmsg_level = IPPROTO_IP;
                control->cmsg_type = IP_PKTINFO;
                control->cmsg_len = CMSG_LEN(sizeof(struct in_pktinfo));
                struct in_pktinfo info;
                memset(&info, 0, sizeof(info));
                memcpy(&info.ipi_spec_dst, PyBytes_AS_STRING(source), 4);
                memcpy(CMSG_DATA(control), &info, sizeof(info));
            }
        }
        Py_ssize_t done = 0;
        while (done < n) {
            /* The sockets are non-blocking: the call never waits, so the GIL stays held (releasing
             * it per call would hand it to any other thread and wait a switch interval for it back). */
            int sent = sendmmsg(fd, headers + done, (unsigned int)(n - done), MSG_DONTWAIT), error = 0;
            if (sent < 0)
                error = errno;
            if (sent < 0) {
                if (error == EINTR)
                    continue;
                PyObject *failure = Py_BuildValue("(ni)", start + done, error);
                if (failure == NULL || PyList_Append(failures, failure) < 0) {
                    Py_XDECREF(failure);
                    Py_DECREF(failures);
                    return NULL;
                }
                Py_DECREF(failure);
                done += 1; /* that message failed: go on with the next */
            } else {
                done += sent;
            }
        }
        start += n;
    }
    return failures;
}

/* recv_batch(fds, limit) -> list of (fd, payload, host, port, received_at): up to `limit` datagrams
 * from each socket that has some, without blocking (one recvmmsg per socket); received_at is the
 * kernel's receive time in CLOCK_MONOTONIC ns (time.monotonic_ns), 0 where the socket gave none. */
static PyObject *recv_batch(PyObject *self, PyObject *args) {
    PyObject *fds;
    int limit;
    if (!PyArg_ParseTuple(args, "O!i", &PyList_Type, &fds, &limit))
        return NULL;
    if (limit < 1 || limit > MAX_RECEIVE)
        limit = MAX_RECEIVE;
    PyObject *out = PyList_New(0);
    if (out == NULL)
        return NULL;
    char (*buffers)[MAX_DATAGRAM] = PyMem_RawMalloc((size_t)limit * MAX_DATAGRAM);
    if (buffers == NULL) {
        Py_DECREF(out);
        return PyErr_NoMemory();
    }
    Received r;
    Py_ssize_t count = PyList_GET_SIZE(fds);
    for (Py_ssize_t f = 0; f < count; f++) {
        int fd = (int)PyLong_AsLong(PyList_GET_ITEM(fds, f));
        if (fd == -1 && PyErr_Occurred()) {
            PyMem_RawFree(buffers);
            Py_DECREF(out);
            return NULL;
        }
        int received = receive_batch(fd, &r, buffers, limit);
        for (int i = 0; i < received; i++) {
            char host[INET_ADDRSTRLEN];
            if (inet_ntop(AF_INET, &r.sources[i].sin_addr, host, sizeof(host)) == NULL)
                host[0] = '\0';
            PyObject *item = Py_BuildValue("(iy#siL)", fd, buffers[i], (Py_ssize_t)received_length(&r, i), host,
                                           (int)ntohs(r.sources[i].sin_port), received_at(&r, i));
            if (item == NULL || PyList_Append(out, item) < 0) {
                Py_XDECREF(item);
                PyMem_RawFree(buffers);
                Py_DECREF(out);
                return NULL;
            }
            Py_DECREF(item);
        }
    }
    PyMem_RawFree(buffers);
    return out;
}

static PyMethodDef methods[] = {
    {"send_batch", send_batch, METH_VARARGS, "sendmmsg: (payload, destination, source) messages from one socket"},
    {"recv_batch", recv_batch, METH_VARARGS, "recvmmsg: waiting datagrams of several sockets, without blocking"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_mmsg", NULL, -1, methods};

PyMODINIT_FUNC PyInit__mmsg(void) { return PyModule_Create(&module); }
