/* The ceiling for bench/bench_cyclic.py: the least a class-1 adapter does, in C, in the farm's
 * shape. Built by the bench with the system compiler:
 *
 *     cc -O2 -o bench/build/cyclic_responder bench/cyclic_responder.c
 *
 * No Forward Open, no objects: it reads the connections from --connections FILE, one a line,
 *
 *     DEVICE_HOST O_T_ID T_O_ID RPI_US O_T_SIZE T_O_SIZE ORIGINATOR_HOST ORIGINATOR_PORT
 *
 * binds UDP 2222 on every device address (one socket each), and in one thread: epoll over the
 * sockets and one timerfd; one recvfrom per O->T datagram (checked: items, connection id, size;
 * the outputs copied to the connection's image), one sendto per T->O datagram, produced at the RPI
 * on absolute deadlines (connection k offset by k/N of its RPI; a binary heap of deadlines, the
 * timerfd armed for the earliest; one a whole RPI behind skips to its first deadline after now) from the device's own socket to the originator. Prints "ready"
 * once every socket is bound, runs until SIGTERM/SIGINT or --seconds S (at most 3600), then reads
 * what is still queued on its sockets and prints its counts as one JSON line on stdout. Traffic only to and from 127.0.0.0/8.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#define MAX_CONNECTIONS 20000
#define READS_PER_WAKE 64

struct connection {
    uint32_t o_t_id, t_o_id;
    int64_t rpi_ns;
    int o_t_size, t_o_size;
    int sock;
    struct sockaddr_in originator;
    uint8_t outputs[512];
    uint8_t packet[600];
    int packet_length;
    uint32_t sequence;
};

struct deadline {
    int64_t when;
    int index;
};

static struct connection connections[MAX_CONNECTIONS];
static int connection_count;
static volatile sig_atomic_t stopping;
static uint32_t *table, table_mask; /* O->T id -> index + 1 */
static uint64_t o_t_received, o_t_bad, t_o_sent, send_errors;

static void on_signal(int sig) { (void)sig; stopping = 1; }

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void put_le16(uint8_t *p, unsigned v) { p[0] = v & 0xff; p[1] = (v >> 8) & 0xff; }
static void put_le32(uint8_t *p, uint32_t v) { put_le16(p, v & 0xffff); put_le16(p + 2, v >> 16); }
static uint32_t le32(const uint8_t *p) { return p[0] | p[1] << 8 | p[2] << 16 | (uint32_t)p[3] << 24; }
static unsigned le16(const uint8_t *p) { return p[0] | p[1] << 8; }
static uint32_t hash(uint32_t id) { return (id * 2654435761u) & table_mask; }

static struct connection *lookup(uint32_t id) {
    for (uint32_t slot = hash(id), probes = 0; probes <= table_mask; slot = (slot + 1) & table_mask, probes++) {
        uint32_t entry = table[slot];
        if (!entry) return NULL;
        if (connections[entry - 1].o_t_id == id) return &connections[entry - 1];
    }
    return NULL;
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

/* One O->T datagram: two items, sequenced address + connected data, known id, the agreed size. */
static void consume(const uint8_t *data, int length) {
    if (length < 20 || le16(data) != 2 || le16(data + 2) != 0x8002 || le16(data + 14) != 0x00B1 ||
        le16(data + 16) != (unsigned)length - 18) {
        o_t_bad++;
        return;
    }
    struct connection *c = lookup(le32(data + 6));
    if (!c || le16(data + 16) != (unsigned)c->o_t_size) {
        o_t_bad++;
        return;
    }
    o_t_received++;
    if (c->o_t_size > 6) memcpy(c->outputs, data + 24, c->o_t_size - 6);
}

static void produce(struct connection *c) {
    c->sequence++;
    put_le32(c->packet + 10, c->sequence);
    put_le16(c->packet + 18, c->sequence & 0xffff);
    if (sendto(c->sock, c->packet, c->packet_length, 0, (struct sockaddr *)&c->originator, sizeof c->originator) < 0)
        send_errors++;
    else
        t_o_sent++;
}

static int loopback(const char *host, struct sockaddr_in *address, int port) {
    address->sin_family = AF_INET;
    address->sin_port = htons(port);
    return inet_pton(AF_INET, host, &address->sin_addr) == 1 && (ntohl(address->sin_addr.s_addr) >> 24) == 127;
}

int main(int argc, char **argv) {
    const char *path = NULL;
    double seconds = 600;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--connections")) path = argv[i + 1];
        else if (!strcmp(argv[i], "--seconds")) seconds = atof(argv[i + 1]);
    }
    if (!path || seconds <= 0 || seconds > 3600) {
        fprintf(stderr, "usage: cyclic_responder --connections FILE [--seconds S]\n");
        return 2;
    }
    FILE *f = fopen(path, "r");
    if (!f) {
        perror(path);
        return 2;
    }
    int epoll = epoll_create1(0);
    char line[512];
    char hosts[MAX_CONNECTIONS][64]; /* device address of each socket, to share one socket per address */
    int socks[MAX_CONNECTIONS], sock_count = 0;
    while (fgets(line, sizeof line, f) && connection_count < MAX_CONNECTIONS) {
        struct connection *c = &connections[connection_count];
        char host[64], originator[64];
        long rpi_us;
        int port;
        if (sscanf(line, "%63s %u %u %ld %d %d %63s %d", host, &c->o_t_id, &c->t_o_id, &rpi_us, &c->o_t_size,
                   &c->t_o_size, originator, &port) != 8)
            continue;
        struct sockaddr_in device;
        if (!loopback(host, &device, 2222) || !loopback(originator, &c->originator, port) || rpi_us < 100 ||
            c->t_o_size < 2 || c->t_o_size > 500 || c->o_t_size < 2 || c->o_t_size > 500) {
            fprintf(stderr, "bad connection line: %s", line);
            return 2;
        }
        c->rpi_ns = rpi_us * 1000;
        c->sock = -1;
        for (int s = sock_count - 1; s >= 0 && c->sock < 0; s--)
            if (!strcmp(hosts[s], host)) c->sock = socks[s];
        if (c->sock < 0) {
            int sock = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK, 0), on = 1;
            setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &on, sizeof on);
            if (bind(sock, (struct sockaddr *)&device, sizeof device)) {
                fprintf(stderr, "bind %s:2222: %s\n", host, strerror(errno));
                return 2;
            }
            struct epoll_event event = {.events = EPOLLIN, .data.fd = sock};
            epoll_ctl(epoll, EPOLL_CTL_ADD, sock, &event);
            strcpy(hosts[sock_count], host);
            socks[sock_count++] = sock;
            c->sock = sock;
        }
        /* T->O: sequenced address (T->O id, sequence), connected data (sequence count, inputs) */
        uint8_t *p = c->packet;
        put_le16(p, 2);
        put_le16(p + 2, 0x8002);
        put_le16(p + 4, 8);
        put_le32(p + 6, c->t_o_id);
        put_le16(p + 14, 0x00B1);
        put_le16(p + 16, c->t_o_size);
        memset(p + 18, 0, c->t_o_size);
        c->packet_length = 18 + c->t_o_size;
        connection_count++;
    }
    fclose(f);
    if (!connection_count) {
        fprintf(stderr, "no connections in %s\n", path);
        return 2;
    }
    table_mask = 1;
    while (table_mask < 4u * (uint32_t)connection_count) table_mask <<= 1;
    table = calloc(table_mask, sizeof *table);
    table_mask -= 1;
    for (int k = 0; k < connection_count; k++) {
        uint32_t slot = hash(connections[k].o_t_id);
        while (table[slot]) slot = (slot + 1) & table_mask;
        table[slot] = k + 1;
    }
    struct sigaction action = {.sa_handler = on_signal};
    sigaction(SIGTERM, &action, NULL);
    sigaction(SIGINT, &action, NULL);
    prctl(PR_SET_TIMERSLACK, 1UL);
    int timer = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK);
    struct epoll_event timer_event = {.events = EPOLLIN, .data.fd = timer};
    epoll_ctl(epoll, EPOLL_CTL_ADD, timer, &timer_event);

    struct deadline *heap = calloc(connection_count, sizeof *heap);
    int size = 0;
    int64_t start = now_ns() + 1000000, end = start + (int64_t)(seconds * 1e9);
    for (int k = 0; k < connection_count; k++)
        heap_push(heap, &size, (struct deadline){start + connections[k].rpi_ns * k / connection_count, k});
    printf("ready\n");
    fflush(stdout);

    struct epoll_event events[256];
    uint8_t buffer[2048];
    while (!stopping) {
        int64_t now = now_ns();
        if (now >= end) break;
        while (heap[0].when <= now) {
            struct deadline d = heap_pop(heap, &size);
            produce(&connections[d.index]);
            d.when += connections[d.index].rpi_ns;
            if (d.when <= now) /* behind by a whole RPI: skip to the first deadline after now, as the farm does */
                d.when += ((now - d.when) / connections[d.index].rpi_ns + 1) * connections[d.index].rpi_ns;
            heap_push(heap, &size, d);
        }
        struct itimerspec arm = {.it_value = {heap[0].when / 1000000000LL, heap[0].when % 1000000000LL}};
        timerfd_settime(timer, TFD_TIMER_ABSTIME, &arm, NULL);
        int n = epoll_wait(epoll, events, 256, 1000);
        for (int i = 0; i < n; i++) {
            int fd = events[i].data.fd;
            if (fd == timer) {
                uint64_t expirations;
                ssize_t ignored = read(timer, &expirations, sizeof expirations); /* re-armed above */
                (void)ignored;
                continue;
            }
            for (int r = 0; r < READS_PER_WAKE; r++) {
                ssize_t got = recvfrom(fd, buffer, sizeof buffer, 0, NULL, NULL);
                if (got < 0) break;
                consume(buffer, (int)got);
            }
        }
    }
    for (int s = 0; s < sock_count; s++) /* what was sent before the signal is counted too */
        for (int r = 0; r < 100000; r++) {
            ssize_t got = recvfrom(socks[s], buffer, sizeof buffer, 0, NULL, NULL);
            if (got < 0) break;
            consume(buffer, (int)got);
        }
    printf("{\"o_t_received\": %lu, \"o_t_bad\": %lu, \"t_o_sent\": %lu, \"send_errors\": %lu, \"sockets\": %d}\n",
           o_t_received, o_t_bad, t_o_sent, send_errors, sock_count);
    fflush(stdout);
    return 0;
}
