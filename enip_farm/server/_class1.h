/* The native class-1 engine's shared types, constants and declarations: the per-packet work of
 * established class-1 connections (CIP Networks Library Vol. 2, 3-2 and 3-3; Vol. 1, 3-4.4.9),
 * native: the cyclic I/O thread's hot path for the devices in "native mode" (server/native.py
 * decides which, and loads and stores their state: Python stays authoritative for everything else).
 * One extension, `_class1`, of four sources:
 * - _class1.c: the type and the module (the device table, new/dealloc, methods, PyInit);
 * - _class1_state.c: the state moves between the engine and Python (load, store, resume, sync);
 * - _class1_o_t.c: O->T consumption and the originator measurement, the socket receive;
 * - _class1_t_o.c: T->O production and supervision, the send batch.
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
 * exported, so Python may still resize them). Time is passed in (CLOCK_MONOTONIC ns). Functions
 * shared between the sources carry the prefix c1_. */
#ifndef ENIP_FARM_CLASS1_H
#define ENIP_FARM_CLASS1_H

#define _GNU_SOURCE
#define PY_SSIZE_T_CLEAN
#include <Python.h>

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
enum { T_IN_OCTETS, T_IN_UCAST, T_IN_DISCARDS, T_OUT_OCTETS, T_OUT_UCAST, T_OUT_NUCAST, T_OUT_ERRORS, NTRAFFIC };
/* the counters' keys (the device's `counters` mapping, its `traffic` attributes), interned at import
 * (_class1.c) */
extern PyObject *c1_counter_keys[NCOUNTERS], *c1_traffic_keys[NTRAFFIC];

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

/* _class1_state.c: the state moves between the engine and Python (server/native.py) */
void c1_clear_dev(Dev *d);
Dev *c1_dev_of(Engine *e, PyObject *args, const char *format, void *a, void *b, void *c, void *d_, void *f, void *g);
int c1_oversize(const Dev *d);
PyObject *c1_load(Engine *e, PyObject *args);
PyObject *c1_store(Engine *e, PyObject *args);
PyObject *c1_resume(Engine *e, PyObject *args);
PyObject *c1_sync(Engine *e, PyObject *args);
PyObject *c1_native(Engine *e, PyObject *args);

/* _class1_o_t.c: O->T */
PyObject *c1_consume(Engine *e, PyObject *args);
PyObject *c1_receive(Engine *e, PyObject *args);

/* _class1_t_o.c: T->O and supervision */
PyObject *c1_produce(Engine *e, PyObject *args);
PyObject *c1_timer(Engine *e, PyObject *args);
PyObject *c1_turns(Engine *e, PyObject *noargs);

#endif
