/* Class-1 cyclic-load originator for bench/bench_cyclic.py (CIP Vol. 2, 3-2: sequenced address +
 * connected data items). Built by the bench with the system compiler:
 *
 *     cc -O2 -pthread -o bench/build/cyclic_originator bench/cyclic_originator.c
 *
 * The connections are opened elsewhere (Forward Open from Python); this program only moves the
 * datagrams. It reads one connection per line from --connections FILE:
 *
 *     HOST O_T_ID T_O_ID RPI_US O_T_SIZE T_O_SIZE [PORT]
 *
 * (sizes as in the Forward Open: O->T = 2-byte sequence count + 4-byte run/idle header + data,
 * T->O = 2 + data; PORT defaults to 2222) and uses the UDP socket inherited as --fd N (or binds
 * --bind ADDR:PORT). With --fd N,M,... (one socket per pair of threads) the connections are spread
 * over that many sender/receiver pairs, connection k on socket k % count (the driver named that
 * socket's port in connection k's Forward Open), so that one pair of threads is not the limit.
 * A sender thread sends O->T on absolute deadlines (clock_nanosleep
 * TIMER_ABSTIME, connection k offset by k/N of its RPI) in batches with sendmmsg, waking on a grid of
 * --batch-us (default 100 us: a send is at most that late by design, so that 1000 connections do not
 * cost 100 000 wake-ups a second); a receiver thread drains the socket with recvmmsg every millisecond
 * and takes each T->O datagram's kernel receive time (SO_TIMESTAMPNS), so this program's own
 * scheduling does not count against the peer. With --realtime P (root) both threads run SCHED_FIFO at
 * priority P, so that other load on the machine does not make the originator late; they sleep
 * between batches, and the kernel's RT throttling bounds them anyway.
 *
 * Phases: --warmup S (sending, nothing measured), the window of --seconds S (measured; "start" and
 * "end" lines on stdout mark it), then it goes on sending until its stdin closes (so the driver can
 * Forward Close every connection while O->T still flows) or --hold S has passed; then it writes the
 * figures as JSON to --json FILE. In the window, per connection: T->O received, lost (gaps in the
 * 32-bit sequence), late (an interval of 2 RPI or more), missed (RPIs without a packet: an interval of
 * k RPI, rounded, misses k - 1), duplicates, period error |interval - RPI|
 * p50/p99/max; and how late this program sent (so "the originator sent on time" is checked, not
 * assumed). Every loop is bounded in time.
 *
 * Misbehaviour (issue 27: a controller's faults, made on purpose so that the farm's verdicts on them
 * can be checked exactly). Each applies to every connection and counts per connection what it did,
 * over the whole run (the JSON's "made" per connection), so a test compares the farm's counts with
 * these, not with a guess. Deadline k (1-based) of a connection is nominally k RPI after its start:
 *   --jitter-us J       deadlines of odd k leave J us late (J < RPI): the intervals alternate
 *                       RPI + J and RPI - J, each J from the RPI (a square wave, not noise: exact);
 *   --gap-every N [--gap-size K]
 *                       from each deadline k % N == 0, K deadlines (1) send nothing, their sequence
 *                       numbers used up: a gap of K in the 32-bit sequence and an interval of K + 1
 *                       RPI (K >= 2 for an interval that no scheduling noise takes below 2 RPI);
 *   --burst-every N --burst-size K
 *                       the K deadlines before each k % N == 0 are held and leave with it, in one
 *                       sendmmsg: a silence of K + 1 RPI, then K + 1 packets at once (K < N);
 *   --repeat-every N    after deadline k % N == 0 its packet is sent again (same 32-bit sequence);
 *   --stale-every N [--stale-by M]
 *                       after deadline k % N == 0 a copy with the sequence M back (2) is sent too
 *                       (stale: older than one already sent; k > M);
 *   --idle-every N      run for N deadlines, then idle (run/idle header bit 0 clear) for N, and so
 *                       on: a transition every N deadlines;
 *   --stop-after N      send nothing after deadline N: the connection falls silent and the target
 *                       times it out (the driver then waits its reconnect delay, Forward Opens again
 *                       and starts this program anew: the delay before reconnecting lives there).
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define MAX_CONNECTIONS 20000
#define BATCH 256
#define CONN_BUCKET_NS 5000    /* per-connection error histogram: 5 us buckets up to 20 ms, */
#define CONN_FINE 4000
#define CONN_COARSE_NS 1000000 /* then 1 ms buckets up to 1 s, */
#define CONN_BUCKETS (CONN_FINE + 980 + 1) /* the last bucket is "more" */
#define ALL_BUCKET_NS 1000     /* all connections: 1 us buckets */
#define ALL_BUCKETS 1000001    /* up to 1 s */
#define LATE_SEND_NS 1000000   /* a send more than 1 ms after its deadline is a late send */
#define MAX_THREADS 16         /* sender/receiver pairs, one socket each */

struct connection {
    char host[64];
    uint32_t o_t_id, t_o_id;
    int64_t rpi_ns;
    int o_t_size, t_o_size;
    struct sockaddr_in destination;
    uint8_t packet[600];
    int packet_length;
    uint32_t sequence;
    /* sender thread */
    uint64_t sent_window, sent_total;
    uint64_t deadlines, datagrams, gaps, gap_runs, repeats, stale, bursts, idle_transitions; /* what it made */
    int idle;
    /* receiver thread */
    int have_last;
    int64_t last_stamp;
    uint32_t last_sequence;
    uint64_t received_window, received_total, lost, late, duplicates, reordered, wrong_size;
    uint64_t missed; /* RPIs with no packet: an interval of k RPI (rounded) misses k - 1 */
    int64_t max_error_ns;
    uint32_t *histogram;
};

struct deadline {
    int64_t when;    /* when it leaves: nominal + this deadline's shift */
    int64_t nominal; /* k RPI after the connection's start */
    int index;
};

static struct connection *connections;
static int connection_count;
static int sock = -1;
static int sockets[MAX_THREADS], socket_count; /* --fd N[,M...] */
/* what one pair of threads counts; summed at the end */
struct pair {
    int index, sock;
    uint64_t sends_late, send_errors, unknown_t_o, malformed_t_o, receive_errors;
    int64_t send_lag_max_ns;
};
static struct pair pairs[MAX_THREADS];
static int64_t t_start, t0, t1, t_hard_end; /* CLOCK_MONOTONIC ns */
static int64_t realtime_offset;               /* CLOCK_REALTIME - CLOCK_MONOTONIC at start */
static atomic_int stopping;
static uint64_t *all_histogram;
static int realtime;                      /* --realtime: SCHED_FIFO for both threads (root) */
static int64_t batch_ns = 100000;         /* --batch-us */
static int64_t receive_pause_ns = 1000000; /* the receiver reads the socket this often when it is drained */
static uint32_t *table; /* T->O id -> index + 1, open addressing */
/* misbehaviour (see the header): 0 = off */
static int64_t jitter_ns;
static uint64_t gap_every, gap_size = 1, burst_every, burst_size, repeat_every, stale_every, stale_by = 2, idle_every, stop_after;
static uint32_t table_mask;

static int64_t now_ns(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static struct timespec to_timespec(int64_t ns) {
    struct timespec ts = {ns / 1000000000LL, ns % 1000000000LL};
    return ts;
}

static uint32_t hash(uint32_t id) { return (id * 2654435761u) & table_mask; }

static struct connection *lookup(uint32_t id) {
    for (uint32_t slot = hash(id), probes = 0; probes <= table_mask; slot = (slot + 1) & table_mask, probes++) {
        uint32_t entry = table[slot];
        if (!entry) return NULL;
        if (connections[entry - 1].t_o_id == id) return &connections[entry - 1];
    }
    return NULL;
}

static void put_le16(uint8_t *p, unsigned v) { p[0] = v & 0xff; p[1] = (v >> 8) & 0xff; }
static void put_le32(uint8_t *p, uint32_t v) { put_le16(p, v & 0xffff); put_le16(p + 2, v >> 16); }
static uint32_t le32(const uint8_t *p) { return p[0] | p[1] << 8 | p[2] << 16 | (uint32_t)p[3] << 24; }
static unsigned le16(const uint8_t *p) { return p[0] | p[1] << 8; }

/* An O->T packet: item count 2, sequenced address (0x8002, 8: id, sequence), connected data
 * (0x00B1: 16-bit sequence count, run/idle header with Run set, outputs). */
static void build_packet(struct connection *c) {
    uint8_t *p = c->packet;
    int data_length = c->o_t_size; /* sequence count + header + data */
    put_le16(p, 2);
    put_le16(p + 2, 0x8002);
    put_le16(p + 4, 8);
    put_le32(p + 6, c->o_t_id);
    put_le32(p + 10, 0);
    put_le16(p + 14, 0x00B1);
    put_le16(p + 16, data_length);
    put_le16(p + 18, 0);
    memset(p + 20, 0, data_length - 2);
    if (data_length >= 6) {
        put_le32(p + 20, 1); /* run */
        for (int i = 24; i < 18 + data_length; i++) p[i] = (uint8_t)i;
    }
    c->packet_length = 18 + data_length;
}

static void heap_push(struct deadline *heap, int *size, struct deadline d) {
    int i = (*size)++;
    while (i > 0) {
        int parent = (i - 1) / 2;
        if (heap[parent].when <= d.when) break;
        heap[i] = heap[parent];
        i = parent;
    }
    heap[i] = d;
}

static struct deadline heap_pop(struct deadline *heap, int *size) {
    struct deadline top = heap[0], last = heap[--(*size)];
    int i = 0;
    for (;;) {
        int child = 2 * i + 1;
        if (child >= *size) break;
        if (child + 1 < *size && heap[child + 1].when < heap[child].when) child++;
        if (last.when <= heap[child].when) break;
        heap[i] = heap[child];
        i = child;
    }
    if (*size) heap[i] = last;
    return top;
}

/* How late deadline k (1-based) of a connection leaves, past its nominal time. */
static int64_t shift(const struct connection *c, uint64_t k) {
    if (burst_every && burst_size) { /* held: it leaves with the release, whatever the jitter */
        uint64_t to_release = (burst_every - k % burst_every) % burst_every; /* deadlines until k % N == 0 */
        if (to_release && to_release <= burst_size) return (int64_t)to_release * c->rpi_ns;
    }
    return jitter_ns && (k & 1) ? jitter_ns : 0;
}

/* Deadline k's packet into out (the connection's template, its sequence numbers and run/idle bit). */
static int compose(const struct connection *c, uint8_t *out, uint32_t sequence, int run) {
    memcpy(out, c->packet, c->packet_length);
    put_le32(out + 10, sequence);
    put_le16(out + 18, sequence & 0xffff);
    if (c->o_t_size >= 6) put_le32(out + 20, run ? 1 : 0);
    return c->packet_length;
}

static void *sender(void *argument) {
    struct pair *p = argument;
    prctl(PR_SET_TIMERSLACK, 1UL);
    struct deadline *heap = calloc(connection_count, sizeof *heap);
    struct mmsghdr *messages = calloc(BATCH, sizeof *messages);
    struct iovec *vectors = calloc(BATCH, sizeof *vectors);
    uint8_t (*out)[600] = calloc(BATCH, sizeof *out); /* a burst sends one connection's packets in one batch */
    int size = 0;
    for (int k = p->index; k < connection_count; k += socket_count) {
        int64_t nominal = t_start + connections[k].rpi_ns * k / connection_count;
        heap_push(heap, &size, (struct deadline){nominal + shift(&connections[k], 1), nominal, k});
    }
    while (!atomic_load(&stopping)) {
        int64_t now = now_ns(CLOCK_MONOTONIC);
        if (now >= t_hard_end) break;
        if (!size) { /* every connection has stopped (--stop-after) */
            struct timespec pause = to_timespec(10000000);
            nanosleep(&pause, NULL);
            continue;
        }
        if (heap[0].when > now) {
            /* wake on a grid of --batch-us: the sends due in one step leave in one sendmmsg */
            int64_t wake = (heap[0].when + batch_ns - 1) / batch_ns * batch_ns;
            struct timespec until = to_timespec(wake < t_hard_end ? wake : t_hard_end);
            clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, NULL);
            continue;
        }
        int n = 0;
        while (n + 3 <= BATCH && size && heap[0].when <= now) { /* up to 3 datagrams per deadline */
            struct deadline d = heap_pop(heap, &size);
            struct connection *c = &connections[d.index];
            uint64_t k = ++c->deadlines;
            int64_t lag = now - d.when;
            int in_window = d.when >= t0 && d.when < t1;
            c->sequence++;
            int idle = idle_every && (k - 1) / idle_every % 2 == 1;
            if (k > 1 && idle != c->idle) c->idle_transitions++;
            c->idle = idle;
            if (gap_every && k >= gap_every && k % gap_every < gap_size) { /* k % N == 0 starts a run of --gap-size */
                c->gaps++; /* its sequence number is used up, nothing leaves */
                if (k % gap_every == 0) c->gap_runs++;
            } else {
                if (in_window) {
                    c->sent_window++;
                    if (lag > p->send_lag_max_ns) p->send_lag_max_ns = lag;
                    if (lag > LATE_SEND_NS) p->sends_late++;
                }
                c->sent_total++;
                int copies = 1;
                uint32_t sequences[3] = {c->sequence, c->sequence, c->sequence - (uint32_t)stale_by};
                if (repeat_every && k % repeat_every == 0) {
                    copies = 2;
                    c->repeats++;
                }
                if (stale_every && k % stale_every == 0 && k > stale_by) {
                    sequences[copies++] = c->sequence - (uint32_t)stale_by;
                    c->stale++;
                }
                if (burst_every && burst_size && k % burst_every == 0) c->bursts++;
                for (int copy = 0; copy < copies; copy++, n++) {
                    int length = compose(c, out[n], sequences[copy], !idle);
                    vectors[n] = (struct iovec){out[n], (size_t)length};
                    messages[n].msg_hdr = (struct msghdr){.msg_name = &c->destination,
                                                          .msg_namelen = sizeof c->destination,
                                                          .msg_iov = &vectors[n],
                                                          .msg_iovlen = 1};
                    c->datagrams++;
                }
            }
            if (stop_after && k >= stop_after) continue; /* silent from here on */
            d.nominal += c->rpi_ns;
            d.when = d.nominal + shift(c, k + 1);
            heap_push(heap, &size, d);
        }
        for (int offset = 0, tries = 0; offset < n && tries < 8; tries++) {
            int sent = sendmmsg(p->sock, messages + offset, n - offset, 0);
            if (sent < 0) {
                if (errno == EINTR) continue;
                p->send_errors++; /* skip the one that failed, go on with the rest */
                offset++;
                continue;
            }
            offset += sent;
        }
    }
    free(heap);
    free(messages);
    free(vectors);
    free(out);
    return NULL;
}

static void take(struct pair *p, const uint8_t *data, int length, int64_t stamp_mono) {
    if (length < 20 || le16(data) != 2 || le16(data + 2) != 0x8002 || le16(data + 4) != 8 ||
        le16(data + 14) != 0x00B1 || le16(data + 16) != (unsigned)length - 18) {
        p->malformed_t_o++;
        return;
    }
    struct connection *c = lookup(le32(data + 6));
    if (!c) {
        p->unknown_t_o++;
        return;
    }
    uint32_t sequence = le32(data + 10);
    c->received_total++;
    if (le16(data + 16) != (unsigned)c->t_o_size) c->wrong_size++;
    int in_window = stamp_mono >= t0 && stamp_mono < t1;
    if (c->have_last) {
        uint32_t step = sequence - c->last_sequence;
        if (step == 0) {
            if (in_window) c->duplicates++;
            return;
        }
        if (step > 0x80000000u) {
            if (in_window) c->reordered++;
            return;
        }
        if (in_window) {
            c->received_window++;
            if (step > 1) c->lost += step - 1;
            int64_t interval = stamp_mono - c->last_stamp;
            int64_t error = interval > c->rpi_ns ? interval - c->rpi_ns : c->rpi_ns - interval;
            if (interval >= 2 * c->rpi_ns) c->late++;
            int64_t periods = (interval + c->rpi_ns / 2) / c->rpi_ns;
            if (periods > 1) c->missed += periods - 1;
            if (error > c->max_error_ns) c->max_error_ns = error;
            int64_t bucket = error / CONN_BUCKET_NS;
            if (bucket >= CONN_FINE) bucket = CONN_FINE + (error - (int64_t)CONN_FINE * CONN_BUCKET_NS) / CONN_COARSE_NS;
            c->histogram[bucket < CONN_BUCKETS - 1 ? bucket : CONN_BUCKETS - 1]++;
            bucket = error / ALL_BUCKET_NS;
            __atomic_fetch_add(&all_histogram[bucket < ALL_BUCKETS - 1 ? bucket : ALL_BUCKETS - 1], 1, __ATOMIC_RELAXED);
        }
    } else if (in_window) {
        c->received_window++;
    }
    c->have_last = 1;
    c->last_sequence = sequence;
    c->last_stamp = stamp_mono;
}

static void *receiver(void *argument) {
    struct pair *p = argument;
    uint8_t (*buffers)[2048] = calloc(BATCH, sizeof *buffers);
    uint8_t (*controls)[CMSG_SPACE(sizeof(struct timespec)) + 64] = calloc(BATCH, sizeof *controls);
    struct mmsghdr *messages = calloc(BATCH, sizeof *messages);
    struct iovec *vectors = calloc(BATCH, sizeof *vectors);
    while (!atomic_load(&stopping) && now_ns(CLOCK_MONOTONIC) < t_hard_end) {
        for (int i = 0; i < BATCH; i++) {
            vectors[i] = (struct iovec){buffers[i], sizeof buffers[i]};
            messages[i].msg_hdr = (struct msghdr){.msg_iov = &vectors[i],
                                                  .msg_iovlen = 1,
                                                  .msg_control = controls[i],
                                                  .msg_controllen = sizeof controls[i]};
        }
        int n = recvmmsg(p->sock, messages, BATCH, MSG_DONTWAIT, NULL);
        if (n < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) p->receive_errors++;
            n = 0;
        }
        if (n < BATCH) { /* drained: the kernel keeps each datagram's time, so reading later costs no accuracy */
            struct timespec pause = to_timespec(receive_pause_ns);
            nanosleep(&pause, NULL);
        }
        int64_t fallback = now_ns(CLOCK_MONOTONIC);
        for (int i = 0; i < n; i++) {
            int64_t stamp = fallback;
            for (struct cmsghdr *cm = CMSG_FIRSTHDR(&messages[i].msg_hdr); cm;
                 cm = CMSG_NXTHDR(&messages[i].msg_hdr, cm)) {
                if (cm->cmsg_level == SOL_SOCKET && cm->cmsg_type == SCM_TIMESTAMPNS) {
                    struct timespec ts;
                    memcpy(&ts, CMSG_DATA(cm), sizeof ts);
                    stamp = (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec - realtime_offset;
                }
            }
            take(p, buffers[i], (int)messages[i].msg_len, stamp);
        }
    }
    free(buffers);
    free(controls);
    free(messages);
    free(vectors);
    return NULL;
}

static int64_t quantile_us(const uint32_t *histogram, uint64_t count, double q) {
    if (!count) return -1;
    uint64_t rank = (uint64_t)(q * (count - 1)), seen = 0;
    for (int b = 0; b < CONN_BUCKETS; b++) {
        seen += histogram[b];
        if (seen > rank)
            return (b < CONN_FINE ? (int64_t)b * CONN_BUCKET_NS
                                  : (int64_t)CONN_FINE * CONN_BUCKET_NS + (int64_t)(b - CONN_FINE) * CONN_COARSE_NS) /
                   1000;
    }
    return -1;
}

static double all_quantile_ms(uint64_t count, double q) {
    if (!count) return -1;
    uint64_t rank = (uint64_t)(q * (count - 1)), seen = 0;
    for (int b = 0; b < ALL_BUCKETS; b++) {
        seen += all_histogram[b];
        if (seen > rank) return (b + 0.5) * ALL_BUCKET_NS / 1e6;
    }
    return -1;
}

static int read_connections(const char *path) {
    FILE *f = fopen(path, "r");
    if (!f) return -1;
    char line[512];
    connections = calloc(MAX_CONNECTIONS, sizeof *connections);
    while (fgets(line, sizeof line, f) && connection_count < MAX_CONNECTIONS) {
        struct connection *c = &connections[connection_count];
        long rpi_us;
        int port = 2222;
        int fields = sscanf(line, "%63s %u %u %ld %d %d %d", c->host, &c->o_t_id, &c->t_o_id, &rpi_us,
                            &c->o_t_size, &c->t_o_size, &port);
        if (fields < 6) continue;
        if (c->o_t_size < 2 || c->o_t_size > 500 || rpi_us < 100) {
            fprintf(stderr, "bad connection line: %s", line);
            return -1;
        }
        c->rpi_ns = rpi_us * 1000;
        c->destination.sin_family = AF_INET;
        c->destination.sin_port = htons(port);
        if (inet_pton(AF_INET, c->host, &c->destination.sin_addr) != 1 ||
            (ntohl(c->destination.sin_addr.s_addr) >> 24) != 127) {
            fprintf(stderr, "not a 127.0.0.0/8 address: %s\n", c->host);
            return -1;
        }
        c->histogram = calloc(CONN_BUCKETS, sizeof *c->histogram);
        build_packet(c);
        connection_count++;
    }
    fclose(f);
    return connection_count;
}

static void usage(void) {
    fprintf(stderr, "usage: cyclic_originator --connections FILE (--fd N[,M...] | --bind ADDR:PORT) --seconds S "
                    "[--warmup S] [--hold S] [--batch-us US] [--realtime PRIORITY] --json FILE\n"
                    "  misbehaviour: [--jitter-us J] [--gap-every N [--gap-size K]] [--burst-every N --burst-size K] "
                    "[--repeat-every N] [--stale-every N [--stale-by M]] [--idle-every N] [--stop-after N]\n");
    exit(2);
}

static uint64_t count_argument(const char *text) {
    char *end;
    long long value = strtoll(text, &end, 10);
    if (*end || value < 1 || value > 1000000000LL) usage();
    return (uint64_t)value;
}

int main(int argc, char **argv) {
    const char *connections_path = NULL, *json_path = NULL, *bind_to = NULL;
    double seconds = 0, warmup = 1.0, hold = 60.0;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--connections")) connections_path = argv[i + 1];
        else if (!strcmp(argv[i], "--fd")) {
            char *next = argv[i + 1];
            while (*next && socket_count < MAX_THREADS) {
                sockets[socket_count++] = (int)strtol(next, &next, 10);
                if (*next == ',') next++;
            }
            sock = sockets[0];
        }
        else if (!strcmp(argv[i], "--bind")) bind_to = argv[i + 1];
        else if (!strcmp(argv[i], "--seconds")) seconds = atof(argv[i + 1]);
        else if (!strcmp(argv[i], "--warmup")) warmup = atof(argv[i + 1]);
        else if (!strcmp(argv[i], "--hold")) hold = atof(argv[i + 1]);
        else if (!strcmp(argv[i], "--json")) json_path = argv[i + 1];
        else if (!strcmp(argv[i], "--realtime")) realtime = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "--batch-us")) batch_ns = (int64_t)(atof(argv[i + 1]) * 1000);
        else if (!strcmp(argv[i], "--jitter-us")) jitter_ns = (int64_t)count_argument(argv[i + 1]) * 1000;
        else if (!strcmp(argv[i], "--gap-every")) gap_every = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--gap-size")) gap_size = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--burst-every")) burst_every = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--burst-size")) burst_size = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--repeat-every")) repeat_every = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--stale-every")) stale_every = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--stale-by")) stale_by = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--idle-every")) idle_every = count_argument(argv[i + 1]);
        else if (!strcmp(argv[i], "--stop-after")) stop_after = count_argument(argv[i + 1]);
        else usage();
    }
    if (!connections_path || !json_path || seconds <= 0 || seconds > 3600 || warmup < 0 || hold < 0 || hold > 600 || batch_ns < 1 || batch_ns > 1000000 ||
        (sock < 0 && !bind_to))
        usage();
    if ((burst_every > 0) != (burst_size > 0) || (burst_every && burst_size >= burst_every) || stale_by > 1000000 ||
        (gap_every && gap_size >= gap_every))
        usage();
    if (read_connections(connections_path) <= 0) {
        fprintf(stderr, "no connections read from %s\n", connections_path);
        return 2;
    }
    for (int k = 0; k < connection_count; k++)
        if (jitter_ns >= connections[k].rpi_ns) {
            fprintf(stderr, "--jitter-us must be less than the RPI\n");
            return 2;
        }
    if (sock < 0) {
        char host[64];
        int port;
        struct sockaddr_in address = {.sin_family = AF_INET};
        if (sscanf(bind_to, "%63[^:]:%d", host, &port) != 2 || inet_pton(AF_INET, host, &address.sin_addr) != 1)
            usage();
        address.sin_port = htons(port);
        sock = socket(AF_INET, SOCK_DGRAM, 0);
        int size = 8 << 20;
        if (setsockopt(sock, SOL_SOCKET, SO_RCVBUFFORCE, &size, sizeof size))
            setsockopt(sock, SOL_SOCKET, SO_RCVBUF, &size, sizeof size);
        if (bind(sock, (struct sockaddr *)&address, sizeof address)) {
            perror("bind");
            return 2;
        }
    }
    if (!socket_count) sockets[socket_count++] = sock;
    int on = 1;
    for (int j = 0; j < socket_count; j++) setsockopt(sockets[j], SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
    table_mask = 1;
    while (table_mask < 4u * (uint32_t)connection_count) table_mask <<= 1;
    table = calloc(table_mask, sizeof *table);
    table_mask -= 1;
    for (int k = 0; k < connection_count; k++) {
        uint32_t slot = hash(connections[k].t_o_id);
        while (table[slot]) slot = (slot + 1) & table_mask;
        table[slot] = k + 1;
    }
    all_histogram = calloc(ALL_BUCKETS, sizeof *all_histogram);

    realtime_offset = now_ns(CLOCK_REALTIME) - now_ns(CLOCK_MONOTONIC);
    t_start = now_ns(CLOCK_MONOTONIC) + 20000000LL;
    t0 = t_start + (int64_t)(warmup * 1e9);
    t1 = t0 + (int64_t)(seconds * 1e9);
    t_hard_end = t1 + (int64_t)(hold * 1e9);
    pthread_t send_threads[MAX_THREADS], receive_threads[MAX_THREADS];
    for (int j = 0; j < socket_count; j++) {
        pairs[j] = (struct pair){.index = j, .sock = sockets[j]};
        pthread_create(&receive_threads[j], NULL, receiver, &pairs[j]);
        pthread_create(&send_threads[j], NULL, sender, &pairs[j]);
    }
    if (realtime > 0) { /* so that the machine's other load does not make this originator late */
        struct sched_param priority = {.sched_priority = realtime};
        for (int j = 0; j < socket_count && realtime; j++)
            if (pthread_setschedparam(send_threads[j], SCHED_FIFO, &priority) ||
                pthread_setschedparam(receive_threads[j], SCHED_FIFO, &priority)) {
                fprintf(stderr, "cyclic_originator: SCHED_FIFO refused, running without it\n");
                realtime = 0;
            }
    }

    struct timespec until = to_timespec(t0);
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, NULL);
    printf("start\n");
    fflush(stdout);
    until = to_timespec(t1);
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, NULL);
    printf("end\n");
    fflush(stdout);
    /* go on sending until stdin closes (the driver has Forward Closed everything) or the hold ends */
    for (;;) {
        int64_t left = t_hard_end - now_ns(CLOCK_MONOTONIC);
        if (left <= 0) break;
        struct pollfd input = {0, POLLIN, 0};
        int ready = poll(&input, 1, (int)(left / 1000000 + 1));
        if (ready < 0 && errno == EINTR) continue;
        if (ready <= 0) break;
        char buffer[256];
        ssize_t got = read(0, buffer, sizeof buffer);
        if (got <= 0) break;
    }
    atomic_store(&stopping, 1);
    uint64_t sends_late = 0, send_errors = 0, unknown_t_o = 0, malformed_t_o = 0, receive_errors = 0;
    int64_t send_lag_max_ns = 0;
    for (int j = 0; j < socket_count; j++) {
        pthread_join(send_threads[j], NULL);
        pthread_join(receive_threads[j], NULL);
        sends_late += pairs[j].sends_late;
        send_errors += pairs[j].send_errors;
        unknown_t_o += pairs[j].unknown_t_o;
        malformed_t_o += pairs[j].malformed_t_o;
        receive_errors += pairs[j].receive_errors;
        if (pairs[j].send_lag_max_ns > send_lag_max_ns) send_lag_max_ns = pairs[j].send_lag_max_ns;
    }

    FILE *out = fopen(json_path, "w");
    if (!out) {
        perror(json_path);
        return 2;
    }
    uint64_t sent_window = 0, sent_total = 0, received_window = 0, lost = 0, late = 0, duplicates = 0, reordered = 0;
    uint64_t wrong_size = 0, expected_window = 0, intervals = 0, received_total = 0, missed = 0;
    int64_t max_error = 0, worst_p99 = 0;
    for (int k = 0; k < connection_count; k++) {
        struct connection *c = &connections[k];
        sent_window += c->sent_window;
        sent_total += c->sent_total;
        received_window += c->received_window;
        received_total += c->received_total;
        missed += c->missed;
        lost += c->lost;
        late += c->late;
        duplicates += c->duplicates;
        reordered += c->reordered;
        wrong_size += c->wrong_size;
        expected_window += (uint64_t)((t1 - t0) / c->rpi_ns);
        if (c->max_error_ns > max_error) max_error = c->max_error_ns;
        uint64_t count = 0;
        for (int b = 0; b < CONN_BUCKETS; b++) count += c->histogram[b];
        intervals += count;
        int64_t p99 = quantile_us(c->histogram, count, 0.99);
        if (p99 > worst_p99) worst_p99 = p99;
    }
    fprintf(out, "{\n \"connections\": %d, \"threads\": %d, \"window_s\": %.6f, \"realtime\": %d,\n",
            connection_count, socket_count, (t1 - t0) / 1e9, realtime);
    fprintf(out, " \"misbehaviour\": {\"jitter_us\": %ld, \"gap_every\": %lu, \"gap_size\": %lu, \"burst_every\": %lu, \"burst_size\": %lu, "
                 "\"repeat_every\": %lu, \"stale_every\": %lu, \"stale_by\": %lu, \"idle_every\": %lu, \"stop_after\": %lu},\n",
            jitter_ns / 1000, gap_every, gap_size, burst_every, burst_size, repeat_every, stale_every, stale_by, idle_every,
            stop_after);
    fprintf(out, " \"o_t_sent_window\": %lu, \"o_t_sent_total\": %lu, \"send_errors\": %lu,\n", sent_window,
            sent_total, send_errors);
    fprintf(out, " \"sends_late\": %lu, \"send_lag_max_ms\": %.3f,\n", sends_late, send_lag_max_ns / 1e6);
    fprintf(out, " \"t_o_expected_window\": %lu, \"t_o_received_window\": %lu, \"lost\": %lu, \"late\": %lu,\n",
            expected_window, received_window, lost, late);
    fprintf(out, " \"t_o_received_total\": %lu, \"missed\": %lu,\n", received_total, missed);
    fprintf(out, " \"duplicates\": %lu, \"reordered\": %lu, \"wrong_size\": %lu, \"unknown\": %lu, "
                 "\"malformed\": %lu, \"receive_errors\": %lu,\n",
            duplicates, reordered, wrong_size, unknown_t_o, malformed_t_o, receive_errors);
    fprintf(out, " \"intervals\": %lu, \"err_p50_ms\": %.4f, \"err_p99_ms\": %.4f, \"err_max_ms\": %.4f, "
                 "\"worst_connection_p99_ms\": %.3f,\n",
            intervals, all_quantile_ms(intervals, 0.5), all_quantile_ms(intervals, 0.99), max_error / 1e6,
            worst_p99 / 1e3);
    fprintf(out, " \"per_connection\": [\n");
    for (int k = 0; k < connection_count; k++) {
        struct connection *c = &connections[k];
        uint64_t count = 0;
        for (int b = 0; b < CONN_BUCKETS; b++) count += c->histogram[b];
        fprintf(out, "  {\"host\": \"%s\", \"o_t_id\": %u, \"t_o_id\": %u, \"o_t_sent\": %lu, \"received\": %lu, \"lost\": %lu, "
                     "\"late\": %lu, \"missed\": %lu, \"duplicates\": %lu, \"p50_us\": %ld, \"p99_us\": %ld, \"max_us\": %ld,\n"
                     "   \"made\": {\"deadlines\": %lu, \"sent\": %lu, \"datagrams\": %lu, \"last_sequence\": %u, \"gaps\": %lu, \"gap_runs\": %lu, "
                     "\"bursts\": %lu, \"repeats\": %lu, \"stale\": %lu, \"idle_transitions\": %lu}}%s\n",
                c->host, c->o_t_id, c->t_o_id, c->sent_window, c->received_window, c->lost, c->late, c->missed,
                c->duplicates, quantile_us(c->histogram, count, 0.5), quantile_us(c->histogram, count, 0.99),
                c->max_error_ns / 1000, c->deadlines, c->sent_total, c->datagrams, c->sequence, c->gaps, c->gap_runs, c->bursts,
                c->repeats, c->stale, c->idle_transitions, k + 1 < connection_count ? "," : "");
    }
    fprintf(out, " ]\n}\n");
    fclose(out);
    return 0;
}
