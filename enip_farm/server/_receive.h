/* The receiving half shared by the two native parts (server/_mmsg.c, server/_class1_o_t.c):
 * recvmmsg(2) of up to MAX_RECEIVE datagrams from one socket, each with the kernel's receive time
 * (SO_TIMESTAMPNS, CLOCK_REALTIME) turned into CLOCK_MONOTONIC ns by the offset between the two
 * clocks read once per call (the wall clock between two monotonic reads, against their midpoint).
 * Linux only. Header-only: each extension gets its own static copy. */
#ifndef ENIP_FARM_RECEIVE_H
#define ENIP_FARM_RECEIVE_H

#include <netinet/in.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>

#define MAX_RECEIVE 32 /* datagrams per socket and call: 64 KiB of buffers, below malloc's mmap threshold */
#define MAX_DATAGRAM 2048

static inline long long ns_of(const struct timespec *t) { return (long long)t->tv_sec * 1000000000LL + t->tv_nsec; }

/* One recvmmsg call's headers, addresses and ancillary buffers. */
typedef struct {
    struct mmsghdr headers[MAX_RECEIVE];
    struct iovec vectors[MAX_RECEIVE];
    struct sockaddr_in sources[MAX_RECEIVE];
    union {
        char buffer[CMSG_SPACE(sizeof(struct timespec)) + CMSG_SPACE(sizeof(struct in_pktinfo))];
        struct cmsghdr align;
    } controls[MAX_RECEIVE];
    long long offset; /* CLOCK_REALTIME - CLOCK_MONOTONIC when the call returned */
    long long read_at; /* CLOCK_MONOTONIC ns when the call returned */
} Received;

/* Up to `limit` (1..MAX_RECEIVE) datagrams of `fd` into `buffers`, without blocking (the GIL is
 * held); the count, or -1 with errno. */
static inline int receive_batch(int fd, Received *r, char (*buffers)[MAX_DATAGRAM], int limit) {
    for (int i = 0; i < limit; i++) {
        r->vectors[i].iov_base = buffers[i];
        r->vectors[i].iov_len = MAX_DATAGRAM;
        memset(&r->headers[i].msg_hdr, 0, sizeof(r->headers[i].msg_hdr));
        r->headers[i].msg_hdr.msg_name = &r->sources[i];
        r->headers[i].msg_hdr.msg_namelen = sizeof(r->sources[i]);
        r->headers[i].msg_hdr.msg_iov = &r->vectors[i];
        r->headers[i].msg_hdr.msg_iovlen = 1;
        r->headers[i].msg_hdr.msg_control = r->controls[i].buffer;
        r->headers[i].msg_hdr.msg_controllen = sizeof(r->controls[i].buffer);
    }
    int received = recvmmsg(fd, r->headers, (unsigned int)limit, MSG_DONTWAIT, NULL);
    r->offset = r->read_at = 0;
    if (received > 0) {
        struct timespec before, real, after;
        clock_gettime(CLOCK_MONOTONIC, &before);
        clock_gettime(CLOCK_REALTIME, &real);
        clock_gettime(CLOCK_MONOTONIC, &after);
        r->read_at = ns_of(&after);
        r->offset = ns_of(&real) - (ns_of(&before) + r->read_at) / 2;
    }
    return received;
}

/* Datagram i's kernel receive time on the monotonic clock, never later than the call's return (a
 * clock step); 0 if it has none. */
static inline long long received_at(Received *r, int i) {
    struct msghdr *header = &r->headers[i].msg_hdr;
    if (header->msg_flags & MSG_CTRUNC)
        return 0;
    for (struct cmsghdr *c = CMSG_FIRSTHDR(header); c != NULL; c = CMSG_NXTHDR(header, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
            struct timespec stamp;
            memcpy(&stamp, CMSG_DATA(c), sizeof(stamp));
            long long at = ns_of(&stamp) - r->offset;
            return at > r->read_at ? r->read_at : at;
        }
    }
    return 0;
}

/* Datagram i's length: a truncated one (MSG_TRUNC) counts as MAX_DATAGRAM, longer than any class-1
 * packet, so the table refuses it by its size. */
static inline size_t received_length(Received *r, int i) {
    return r->headers[i].msg_hdr.msg_flags & MSG_TRUNC ? MAX_DATAGRAM : r->headers[i].msg_len;
}

#endif
