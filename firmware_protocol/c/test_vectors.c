/*
 * Checks the C reference codec against the shared test vectors.
 *
 * For every vector the wire bytes are pushed through rfsas_stream_push one
 * byte at a time; every reported frame is unpacked, rendered as the
 * canonical "name=value" text and re-encoded; the resulting lines must equal
 * the vector's "expect" lines exactly. Self-checks of the CRC check value,
 * COBS round trips and pack/unpack round trips run first.
 *
 * Usage: test_vectors VECTORS.txt      (exit status 0 when everything passes)
 */
#include "rfsas_board.h"

#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_LINE 16384
#define MAX_WIRE 8192
#define MAX_EXPECT 32

static int failures = 0;
static int checks = 0;

static void fail(const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    fputs("FAIL: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    failures++;
}

/* ---- text builder ------------------------------------------------------ */

typedef struct {
    char buf[MAX_LINE];
    size_t len;
} text;

static void add(text *t, const char *fmt, ...) {
    va_list ap;
    int n;
    va_start(ap, fmt);
    n = vsnprintf(t->buf + t->len, sizeof t->buf - t->len, fmt, ap);
    va_end(ap);
    if (n > 0) t->len += (size_t)n;
    if (t->len >= sizeof t->buf) t->len = sizeof t->buf - 1;
}

static void add_rssi(text *t, const int8_t *rssi) {
    int k;
    for (k = 0; k < RFSAS_RSSI_SLOTS; k++) {
        if (k) add(t, ",");
        if (rssi[k] == RFSAS_RSSI_NONE) {
            add(t, "-");
        } else {
            add(t, "%d", rssi[k]);
        }
    }
}

static void render_measurement(text *t, const rfsas_measurement *m, const char *prefix) {
    add(t, "%st_us=%" PRIu64 " %smac=%02x%02x%02x%02x%02x%02x", prefix, m->t_us, prefix,
        m->mac[0], m->mac[1], m->mac[2], m->mac[3], m->mac[4], m->mac[5]);
    add(t, " %sfreq_mhz=%u %schannel=%u %skind=%u %sflags=%u", prefix, m->freq_mhz, prefix,
        m->channel, prefix, m->kind, prefix, m->flags);
    if (m->frame_seq == RFSAS_FRAME_SEQ_NONE) {
        add(t, " %sframe_seq=-", prefix);
    } else {
        add(t, " %sframe_seq=%u", prefix, m->frame_seq);
    }
    add(t, " %srssi_dbm=", prefix);
    add_rssi(t, m->rssi_dbm);
}

/* Unpack f's payload, render it into t and pack it again into payload/len.
 * Returns 0 or RFSAS_ERR_PAYLOAD. */
static int render_and_repack(const rfsas_frame *f, text *t, uint8_t *payload, size_t *len) {
    const uint8_t *p = f->payload;
    size_t n = f->length, cap = RFSAS_MAX_PAYLOAD;
    switch (f->type) {
    case RFSAS_HELLO: {
        rfsas_hello m;
        if (rfsas_unpack_hello(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "protocol_version=%u", m.protocol_version);
        *len = rfsas_pack_hello(&m, payload, cap);
        return 0;
    }
    case RFSAS_INFO: {
        rfsas_info m;
        if (rfsas_unpack_info(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "protocol_version=%u fw_major=%u fw_minor=%u fw_patch=%u n_antennas=%u",
            m.protocol_version, m.fw_major, m.fw_minor, m.fw_patch, m.n_antennas);
        add(t, " capabilities=%" PRIu32 " board_id=%" PRIu64, m.capabilities, m.board_id);
        *len = rfsas_pack_info(&m, payload, cap);
        return 0;
    }
    case RFSAS_MEASUREMENT: {
        rfsas_measurement m;
        if (rfsas_unpack_measurement(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        render_measurement(t, &m, "");
        *len = rfsas_pack_measurement(&m, payload, cap);
        return 0;
    }
    case RFSAS_MEASUREMENT_BATCH: {
        static rfsas_measurement ms[256];
        uint8_t count, size, i;
        char prefix[8];
        if (rfsas_batch_open(p, n, &count, &size)) return RFSAS_ERR_PAYLOAD;
        add(t, "count=%u", count);
        for (i = 0; i < count; i++) {
            if (rfsas_batch_get(p, size, i, &ms[i])) return RFSAS_ERR_PAYLOAD;
            snprintf(prefix, sizeof prefix, "%u.", i);
            add(t, " ");
            render_measurement(t, &ms[i], prefix);
        }
        *len = rfsas_pack_batch(ms, count, payload, cap);
        return 0;
    }
    case RFSAS_SET_CHANNEL: {
        rfsas_set_channel m;
        if (rfsas_unpack_set_channel(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "freq_mhz=%u", m.freq_mhz);
        *len = rfsas_pack_set_channel(&m, payload, cap);
        return 0;
    }
    case RFSAS_SET_SCAN_PLAN: {
        rfsas_set_scan_plan m;
        uint8_t k;
        if (rfsas_unpack_set_scan_plan(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "dwell_ms=%u freqs_mhz=", m.dwell_ms);
        if (m.count == 0) add(t, "-");
        for (k = 0; k < m.count; k++) add(t, k ? ",%u" : "%u", m.freq_mhz[k]);
        *len = rfsas_pack_set_scan_plan(&m, payload, cap);
        return 0;
    }
    case RFSAS_START:
    case RFSAS_STOP:
        *len = 0;
        return 0;
    case RFSAS_HEARTBEAT: {
        rfsas_heartbeat m;
        if (rfsas_unpack_heartbeat(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "uptime_us=%" PRIu64 " frames_heard=%" PRIu32 " frames_dropped=%" PRIu32,
            m.uptime_us, m.frames_heard, m.frames_dropped);
        add(t, " queue_depth=%u queue_capacity=%u state=%u freq_mhz=%u", m.queue_depth,
            m.queue_capacity, m.state, m.freq_mhz);
        *len = rfsas_pack_heartbeat(&m, payload, cap);
        return 0;
    }
    case RFSAS_ACK: {
        rfsas_ack m;
        if (rfsas_unpack_ack(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "acked_seq=%u acked_type=%u", m.acked_seq, m.acked_type);
        *len = rfsas_pack_ack(&m, payload, cap);
        return 0;
    }
    case RFSAS_NAK: {
        rfsas_nak m;
        if (rfsas_unpack_nak(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "acked_seq=%u acked_type=%u error=%u detail=%u", m.acked_seq, m.acked_type,
            m.error, m.detail);
        *len = rfsas_pack_nak(&m, payload, cap);
        return 0;
    }
    case RFSAS_ERROR_REPORT: {
        rfsas_error_report m;
        uint8_t k;
        if (rfsas_unpack_error_report(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "code=%u detail=%" PRIu32 " text=", m.code, m.detail);
        if (m.text_len == 0) add(t, "-");
        for (k = 0; k < m.text_len; k++) add(t, "%02x", (unsigned char)m.text[k]);
        *len = rfsas_pack_error_report(&m, payload, cap);
        return 0;
    }
    case RFSAS_TIME_SYNC_REQUEST: {
        rfsas_time_sync_request m;
        if (rfsas_unpack_time_sync_request(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "host_time_ns=%" PRIu64, m.host_time_ns);
        *len = rfsas_pack_time_sync_request(&m, payload, cap);
        return 0;
    }
    case RFSAS_TIME_SYNC: {
        rfsas_time_sync m;
        if (rfsas_unpack_time_sync(p, n, &m)) return RFSAS_ERR_PAYLOAD;
        add(t, "host_time_ns=%" PRIu64 " board_rx_us=%" PRIu64 " board_tx_us=%" PRIu64,
            m.host_time_ns, m.board_rx_us, m.board_tx_us);
        *len = rfsas_pack_time_sync(&m, payload, cap);
        return 0;
    }
    default:
        return RFSAS_ERR_PAYLOAD;
    }
}

/* ---- one vector ----------------------------------------------------------- */

typedef struct {
    char name[128];
    uint8_t wire[MAX_WIRE];
    size_t wire_len;
    char expect[MAX_EXPECT][MAX_LINE];
    int n_expect;
} vector;

static rfsas_stream stream;

static void run_vector(const vector *v) {
    static text got[MAX_EXPECT * 2];
    static uint8_t payload[RFSAS_MAX_PAYLOAD];
    static uint8_t wire[RFSAS_WIRE_SIZE(RFSAS_MAX_PAYLOAD)];
    int n_got = 0, i;
    size_t b;
    rfsas_stream_init(&stream);
    for (b = 0; b <= v->wire_len; b++) {
        rfsas_frame f;
        size_t skip = 0;
        int r;
        text *t;
        if (b == v->wire_len) {
            if (stream.len == 0) break;
            r = RFSAS_NONE;
        } else {
            r = rfsas_stream_push(&stream, v->wire[b], &f, &skip);
        }
        if (r == RFSAS_NONE && b < v->wire_len) continue;
        if (n_got >= MAX_EXPECT * 2) break;
        t = &got[n_got++];
        t->len = 0;
        t->buf[0] = '\0';
        if (b == v->wire_len) {
            add(t, "error truncated");
        } else if (r < 0) {
            add(t, "error %s", rfsas_result_name(r));
        } else {
            text fields;
            size_t plen = 0, wlen;
            int same;
            fields.len = 0;
            fields.buf[0] = '\0';
            if (render_and_repack(&f, &fields, payload, &plen) != 0) {
                add(t, "error payload");
                continue;
            }
            wlen = rfsas_frame_encode(f.type, f.seq, f.compat, f.incompat, payload, plen, wire,
                                      sizeof wire);
            same = wlen == stream.seg_len - skip + 1 &&
                   memcmp(wire, stream.seg + skip, wlen - 1) == 0 && wire[wlen - 1] == 0;
            add(t, "frame 0x%02x %u %u %zu %d", f.type, f.seq, f.compat, skip, same);
            if (fields.len) add(t, " %s", fields.buf);
        }
    }
    checks++;
    if (n_got != v->n_expect) {
        fail("%s: %d results, expected %d", v->name, n_got, v->n_expect);
    }
    for (i = 0; i < n_got && i < v->n_expect; i++) {
        if (strcmp(got[i].buf, v->expect[i]) != 0) {
            fail("%s: result %d\n  got      %s\n  expected %s", v->name, i, got[i].buf,
                 v->expect[i]);
        }
    }
}

static void copy_text(char *dst, size_t cap, const char *src) {
    size_t k = 0;
    while (k + 1 < cap && src[k] != '\0') {
        dst[k] = src[k];
        k++;
    }
    dst[k] = '\0';
}

static int hexval(int c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static int run_file(const char *path) {
    static char line[MAX_LINE + 16];
    static vector v;
    FILE *fp = fopen(path, "r");
    int in_vector = 0, lineno = 0, n_vectors = 0;
    if (!fp) {
        fail("cannot open %s", path);
        return 0;
    }
    while (fgets(line, sizeof line, fp)) {
        size_t len = strlen(line);
        lineno++;
        while (len && (line[len - 1] == '\n' || line[len - 1] == '\r')) line[--len] = '\0';
        if (len == 0 || line[0] == '#') continue;
        if (strncmp(line, "vector ", 7) == 0) {
            memset(&v, 0, sizeof v);
            copy_text(v.name, sizeof v.name, line + 7);
            in_vector = 1;
        } else if (!in_vector) {
            fail("%s:%d: line outside a vector", path, lineno);
        } else if (strncmp(line, "note ", 5) == 0) {
            continue;
        } else if (strncmp(line, "wire ", 5) == 0) {
            size_t k, n = (len - 5) / 2;
            if (n > MAX_WIRE || (len - 5) % 2) {
                fail("%s:%d: bad wire line", path, lineno);
                continue;
            }
            for (k = 0; k < n; k++) {
                int hi = hexval(line[5 + 2 * k]), lo = hexval(line[6 + 2 * k]);
                if (hi < 0 || lo < 0) fail("%s:%d: bad hex", path, lineno);
                v.wire[k] = (uint8_t)((hi << 4) | (lo & 0xF));
            }
            v.wire_len = n;
        } else if (strncmp(line, "expect ", 7) == 0) {
            if (v.n_expect >= MAX_EXPECT) {
                fail("%s:%d: too many expect lines", path, lineno);
                continue;
            }
            copy_text(v.expect[v.n_expect++], MAX_LINE, line + 7);
        } else if (strcmp(line, "end") == 0) {
            run_vector(&v);
            n_vectors++;
            in_vector = 0;
        } else {
            fail("%s:%d: unexpected line", path, lineno);
        }
    }
    fclose(fp);
    return n_vectors;
}

/* ---- self checks ---------------------------------------------------------- */

static uint32_t lcg_state = 12345u;
static uint32_t lcg(void) {
    lcg_state = lcg_state * 1103515245u + 12345u;
    return lcg_state >> 8;
}

static void self_checks(void) {
    static uint8_t data[2000], enc[2100], dec[2100];
    const uint8_t check[] = "123456789";
    size_t trial, n, k, e_len, d_len;
    checks++;
    if (rfsas_crc16(0xFFFFu, check, 9) != 0x29B1u) fail("CRC-16/CCITT-FALSE check value");
    for (trial = 0; trial < 2000; trial++) {
        n = trial < 600 ? trial : lcg() % sizeof data;
        for (k = 0; k < n; k++) {
            /* mostly non-zero so long runs occur, sometimes zeros */
            data[k] = (uint8_t)((lcg() % 8 == 0) && (trial % 3 == 0) ? 0 : 1 + lcg() % 255);
        }
        checks++;
        e_len = rfsas_cobs_encode(data, n, enc, sizeof enc);
        if (e_len == 0 || memchr(enc, 0, e_len) != NULL) {
            fail("COBS encode of %zu bytes", n);
            continue;
        }
        if (rfsas_cobs_decode(enc, e_len, dec, sizeof dec, &d_len) != 0 || d_len != n ||
            memcmp(dec, data, n) != 0) {
            fail("COBS round trip of %zu bytes", n);
        }
    }
    for (trial = 0; trial < 1000; trial++) {
        rfsas_measurement m, back;
        uint8_t p[RFSAS_MEASUREMENT_SIZE];
        int j;
        m.t_us = ((uint64_t)lcg() << 40) ^ lcg();
        for (j = 0; j < 6; j++) m.mac[j] = (uint8_t)lcg();
        m.freq_mhz = (uint16_t)lcg();
        m.channel = (uint8_t)lcg();
        m.kind = (uint8_t)lcg();
        m.flags = (uint8_t)lcg();
        m.frame_seq = (uint16_t)(lcg() % 4096);
        for (j = 0; j < RFSAS_RSSI_SLOTS; j++) m.rssi_dbm[j] = (int8_t)((int)(lcg() % 256) - 128);
        checks++;
        if (rfsas_pack_measurement(&m, p, sizeof p) != RFSAS_MEASUREMENT_SIZE ||
            rfsas_unpack_measurement(p, sizeof p, &back) != 0 ||
            memcmp(&m.mac, &back.mac, 6) != 0 || m.t_us != back.t_us ||
            m.freq_mhz != back.freq_mhz || m.frame_seq != back.frame_seq ||
            memcmp(m.rssi_dbm, back.rssi_dbm, sizeof m.rssi_dbm) != 0) {
            fail("measurement pack/unpack round trip %zu", trial);
        }
    }
    {
        /* a frame that does not fit must be refused, not overrun */
        uint8_t small[8], pl[4] = {1, 2, 3, 4};
        checks++;
        if (rfsas_frame_encode(RFSAS_SET_CHANNEL, 1, 0, 0, pl, 2, small, sizeof small) != 0) {
            fail("frame_encode accepted a buffer that is too small");
        }
        checks++;
        if (rfsas_frame_encode(0x7E, 1, 0, 0, pl, 2, enc, sizeof enc) != 0) {
            fail("frame_encode accepted an unknown type");
        }
    }
}

int main(int argc, char **argv) {
    int n_vectors;
    if (argc != 2) {
        fprintf(stderr, "usage: %s VECTORS.txt\n", argv[0]);
        return 2;
    }
    self_checks();
    n_vectors = run_file(argv[1]);
    if (n_vectors == 0) fail("no vectors in %s", argv[1]);
    printf("%d vectors, %d checks, %d failures\n", n_vectors, checks, failures);
    return failures ? 1 : 0;
}
