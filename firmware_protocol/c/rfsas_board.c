/* rfsas DF-board protocol, version 1: reference codec. See rfsas_board.h. */
#include "rfsas_board.h"

#include <string.h>

/* ---- little-endian helpers ------------------------------------------ */

static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v) {
    put16(p, (uint16_t)v);
    put16(p + 2, (uint16_t)(v >> 16));
}
static void put64(uint8_t *p, uint64_t v) {
    put32(p, (uint32_t)v);
    put32(p + 4, (uint32_t)(v >> 32));
}
static uint16_t get16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get32(const uint8_t *p) {
    return (uint32_t)get16(p) | ((uint32_t)get16(p + 2) << 16);
}
static uint64_t get64(const uint8_t *p) {
    return (uint64_t)get32(p) | ((uint64_t)get32(p + 4) << 32);
}

const char *rfsas_result_name(int result) {
    switch (result) {
    case RFSAS_FRAME: return "frame";
    case RFSAS_NONE: return "none";
    case RFSAS_ERR_COBS: return "cobs";
    case RFSAS_ERR_SHORT: return "short";
    case RFSAS_ERR_MAGIC: return "magic";
    case RFSAS_ERR_INCOMPATIBLE: return "incompatible";
    case RFSAS_ERR_LENGTH: return "length";
    case RFSAS_ERR_UNKNOWN_TYPE: return "unknown_type";
    case RFSAS_ERR_CRC: return "crc";
    case RFSAS_ERR_PAYLOAD: return "payload";
    case RFSAS_ERR_SPACE: return "space";
    default: return "?";
    }
}

/* ---- CRC ------------------------------------------------------------ */

uint16_t rfsas_crc16(uint16_t crc, const uint8_t *data, size_t len) {
    size_t i;
    int bit;
    for (i = 0; i < len; i++) {
        crc ^= (uint16_t)(data[i] << 8);
        for (bit = 0; bit < 8; bit++) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

int rfsas_crc_extra(uint8_t type) {
    switch (type) {
    case RFSAS_HELLO: return 0xCC;
    case RFSAS_INFO: return 0x17;
    case RFSAS_MEASUREMENT: return 0xC2;
    case RFSAS_MEASUREMENT_BATCH: return 0xBB;
    case RFSAS_SET_CHANNEL: return 0xE4;
    case RFSAS_SET_SCAN_PLAN: return 0xCF;
    case RFSAS_START: return 0x1A;
    case RFSAS_STOP: return 0x81;
    case RFSAS_HEARTBEAT: return 0x5E;
    case RFSAS_ACK: return 0x32;
    case RFSAS_NAK: return 0x41;
    case RFSAS_ERROR_REPORT: return 0x54;
    case RFSAS_TIME_SYNC_REQUEST: return 0x48;
    case RFSAS_TIME_SYNC: return 0xFD;
    default: return -1;
    }
}

static uint16_t crc_start(uint8_t extra) { return rfsas_crc16(0xFFFFu, &extra, 1); }

/* ---- COBS ----------------------------------------------------------- */

/* Streaming COBS encoder: lets a frame be encoded without a second buffer. */
typedef struct {
    uint8_t *out;
    size_t cap, pos, code_pos;
    uint8_t code;
    int full;    /* the last block was closed because it reached 254 bytes */
    int overflow;
} cobs_enc;

static void cobs_begin(cobs_enc *e, uint8_t *out, size_t cap) {
    e->out = out;
    e->cap = cap;
    e->code_pos = 0;
    e->pos = 1;
    e->code = 1;
    e->full = 0;
    e->overflow = cap == 0;
}

static void cobs_put(cobs_enc *e, uint8_t byte) {
    if (e->overflow) return;
    e->full = 0;
    if (byte != 0) {
        if (e->pos >= e->cap) {
            e->overflow = 1;
            return;
        }
        e->out[e->pos++] = byte;
        if (++e->code != 0xFF) return;
        e->full = 1;
    }
    /* close the block: a zero byte, or 254 data bytes */
    e->out[e->code_pos] = e->code;
    if (e->pos >= e->cap) {
        e->overflow = 1;
        return;
    }
    e->code_pos = e->pos++;
    e->code = 1;
}

static size_t cobs_end(cobs_enc *e) {
    if (e->overflow) return 0;
    if (e->full) return e->pos - 1; /* canonical: no empty block after a 0xFF block */
    e->out[e->code_pos] = e->code;
    return e->pos;
}

size_t rfsas_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap) {
    cobs_enc e;
    size_t i;
    cobs_begin(&e, out, cap);
    for (i = 0; i < len; i++) cobs_put(&e, in[i]);
    return cobs_end(&e);
}

int rfsas_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len) {
    size_t i = 0, o = 0, k;
    if (len == 0) return RFSAS_ERR_COBS;
    while (i < len) {
        uint8_t code = in[i];
        if (code == 0 || i + code > len) return RFSAS_ERR_COBS;
        for (k = 1; k < code; k++) {
            if (in[i + k] == 0) return RFSAS_ERR_COBS;
            if (o >= cap) return RFSAS_ERR_SPACE;
            out[o++] = in[i + k];
        }
        i += code;
        if (code != 0xFF && i < len) {
            if (o >= cap) return RFSAS_ERR_SPACE;
            out[o++] = 0;
        }
    }
    *out_len = o;
    return 0;
}

/* ---- frames --------------------------------------------------------- */

size_t rfsas_frame_encode(uint8_t type, uint16_t seq, uint8_t compat, uint8_t incompat,
                          const uint8_t *payload, size_t len, uint8_t *out, size_t cap) {
    uint8_t header[RFSAS_HEADER_SIZE];
    uint16_t crc;
    size_t i, n;
    int extra = rfsas_crc_extra(type);
    cobs_enc e;
    if (extra < 0 || len > RFSAS_MAX_PAYLOAD) return 0;
    header[0] = RFSAS_MAGIC;
    header[1] = incompat;
    header[2] = compat;
    put16(header + 3, seq);
    header[5] = type;
    put16(header + 6, (uint16_t)len);
    crc = crc_start((uint8_t)extra);
    crc = rfsas_crc16(crc, header, sizeof header);
    crc = rfsas_crc16(crc, payload, len);
    cobs_begin(&e, out, cap);
    for (i = 0; i < sizeof header; i++) cobs_put(&e, header[i]);
    for (i = 0; i < len; i++) cobs_put(&e, payload[i]);
    cobs_put(&e, (uint8_t)(crc >> 8)); /* CRC most significant byte first */
    cobs_put(&e, (uint8_t)crc);
    n = cobs_end(&e);
    if (n == 0 || n >= cap) return 0;
    out[n] = 0;
    return n + 1;
}

int rfsas_frame_check(const uint8_t *d, size_t len, rfsas_frame *f) {
    uint16_t length, crc;
    int extra;
    if (len < RFSAS_HEADER_SIZE + RFSAS_CRC_SIZE) return RFSAS_ERR_SHORT;
    if (d[0] != RFSAS_MAGIC) return RFSAS_ERR_MAGIC;
    if (d[1] & (uint8_t)~RFSAS_KNOWN_INCOMPAT) return RFSAS_ERR_INCOMPATIBLE;
    length = get16(d + 6);
    if ((size_t)length != len - RFSAS_HEADER_SIZE - RFSAS_CRC_SIZE) return RFSAS_ERR_LENGTH;
    extra = rfsas_crc_extra(d[5]);
    if (extra < 0) return RFSAS_ERR_UNKNOWN_TYPE;
    /* the CRC over everything including the stored CRC is zero when it matches */
    crc = rfsas_crc16(crc_start((uint8_t)extra), d, len);
    if (crc != 0) return RFSAS_ERR_CRC;
    f->type = d[5];
    f->seq = get16(d + 3);
    f->incompat = d[1];
    f->compat = d[2];
    f->payload = d + RFSAS_HEADER_SIZE;
    f->length = length;
    return 0;
}

int rfsas_segment_decode(const uint8_t *seg, size_t len, uint8_t *work, size_t cap,
                         rfsas_frame *f) {
    size_t n = 0;
    int r;
    if (len > RFSAS_MAX_ENCODED) return RFSAS_ERR_LENGTH;
    r = rfsas_cobs_decode(seg, len, work, cap, &n);
    if (r == RFSAS_ERR_SPACE) return RFSAS_ERR_LENGTH;
    if (r != 0) return r;
    return rfsas_frame_check(work, n, f);
}

void rfsas_stream_init(rfsas_stream *s) {
    s->len = 0;
    s->seg_len = 0;
    s->dropped = 0;
    s->skip = 0;
}

int rfsas_stream_push(rfsas_stream *s, uint8_t byte, rfsas_frame *f, size_t *skip) {
    size_t n = s->len, i;
    int r;
    if (byte != 0) {
        if (s->len < sizeof s->seg) {
            s->seg[s->len++] = byte;
        } else {
            /* keep the newest bytes: the end of an overlong segment may be a frame */
            memmove(s->seg, s->seg + 1, sizeof s->seg - 1);
            s->seg[sizeof s->seg - 1] = byte;
            s->dropped++;
        }
        return RFSAS_NONE;
    }
    s->len = 0;
    s->seg_len = n;
    if (n == 0 && s->dropped == 0) return RFSAS_NONE; /* idle delimiter */
    r = s->dropped ? RFSAS_ERR_LENGTH
                   : rfsas_segment_decode(s->seg, n, s->work, sizeof s->work, f);
    s->dropped = 0;
    if (r == 0) {
        s->skip = *skip = 0;
        return RFSAS_FRAME;
    }
    /* Garbage without a delimiter sticks to the front of the next frame:
     * try every later offset where a code byte is followed by the magic. */
    for (i = 1; i + 1 < n; i++) {
        if (s->seg[i + 1] != RFSAS_MAGIC) continue;
        if (rfsas_segment_decode(s->seg + i, n - i, s->work, sizeof s->work, f) == 0) {
            s->skip = *skip = i;
            return RFSAS_FRAME;
        }
    }
    return r;
}

/* ---- messages ------------------------------------------------------- */

#define NEED(n) do { if (cap < (n)) return 0; } while (0)
#define HAVE(n) do { if (len < (n)) return RFSAS_ERR_PAYLOAD; } while (0)

size_t rfsas_pack_hello(const rfsas_hello *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_HELLO_SIZE);
    out[0] = m->protocol_version;
    return RFSAS_HELLO_SIZE;
}

int rfsas_unpack_hello(const uint8_t *p, size_t len, rfsas_hello *m) {
    HAVE(RFSAS_HELLO_SIZE);
    m->protocol_version = p[0];
    return 0;
}

size_t rfsas_pack_info(const rfsas_info *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_INFO_SIZE);
    out[0] = m->protocol_version;
    out[1] = m->fw_major;
    out[2] = m->fw_minor;
    out[3] = m->fw_patch;
    out[4] = m->n_antennas;
    put32(out + 5, m->capabilities);
    put64(out + 9, m->board_id);
    return RFSAS_INFO_SIZE;
}

int rfsas_unpack_info(const uint8_t *p, size_t len, rfsas_info *m) {
    HAVE(RFSAS_INFO_SIZE);
    m->protocol_version = p[0];
    m->fw_major = p[1];
    m->fw_minor = p[2];
    m->fw_patch = p[3];
    m->n_antennas = p[4];
    m->capabilities = get32(p + 5);
    m->board_id = get64(p + 9);
    return 0;
}

size_t rfsas_pack_measurement(const rfsas_measurement *m, uint8_t *out, size_t cap) {
    int k;
    NEED(RFSAS_MEASUREMENT_SIZE);
    if (m->frame_seq > 4095u && m->frame_seq != RFSAS_FRAME_SEQ_NONE) return 0;
    put64(out, m->t_us);
    memcpy(out + 8, m->mac, 6);
    put16(out + 14, m->freq_mhz);
    out[16] = m->channel;
    out[17] = m->kind;
    out[18] = m->flags;
    put16(out + 19, m->frame_seq);
    for (k = 0; k < RFSAS_RSSI_SLOTS; k++) out[21 + k] = (uint8_t)m->rssi_dbm[k];
    return RFSAS_MEASUREMENT_SIZE;
}

int rfsas_unpack_measurement(const uint8_t *p, size_t len, rfsas_measurement *m) {
    int k;
    HAVE(RFSAS_MEASUREMENT_SIZE);
    m->t_us = get64(p);
    memcpy(m->mac, p + 8, 6);
    m->freq_mhz = get16(p + 14);
    m->channel = p[16];
    m->kind = p[17];
    m->flags = p[18];
    m->frame_seq = get16(p + 19);
    for (k = 0; k < RFSAS_RSSI_SLOTS; k++) {
        m->rssi_dbm[k] = (int8_t)(p[21 + k] >= 0x80 ? (int)p[21 + k] - 256 : (int)p[21 + k]);
    }
    return 0;
}

size_t rfsas_pack_set_channel(const rfsas_set_channel *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_SET_CHANNEL_SIZE);
    put16(out, m->freq_mhz);
    return RFSAS_SET_CHANNEL_SIZE;
}

int rfsas_unpack_set_channel(const uint8_t *p, size_t len, rfsas_set_channel *m) {
    HAVE(RFSAS_SET_CHANNEL_SIZE);
    m->freq_mhz = get16(p);
    return 0;
}

size_t rfsas_pack_set_scan_plan(const rfsas_set_scan_plan *m, uint8_t *out, size_t cap) {
    size_t k, n = 3u + 2u * (size_t)m->count;
    if (m->count > RFSAS_MAX_SCAN_CHANNELS) return 0;
    NEED(n);
    put16(out, m->dwell_ms);
    out[2] = m->count;
    for (k = 0; k < m->count; k++) put16(out + 3 + 2 * k, m->freq_mhz[k]);
    return n;
}

int rfsas_unpack_set_scan_plan(const uint8_t *p, size_t len, rfsas_set_scan_plan *m) {
    size_t k;
    HAVE(3u);
    m->dwell_ms = get16(p);
    m->count = p[2];
    if (m->count > RFSAS_MAX_SCAN_CHANNELS) return RFSAS_ERR_PAYLOAD;
    HAVE(3u + 2u * (size_t)m->count);
    for (k = 0; k < m->count; k++) m->freq_mhz[k] = get16(p + 3 + 2 * k);
    return 0;
}

size_t rfsas_pack_heartbeat(const rfsas_heartbeat *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_HEARTBEAT_SIZE);
    put64(out, m->uptime_us);
    put32(out + 8, m->frames_heard);
    put32(out + 12, m->frames_dropped);
    put16(out + 16, m->queue_depth);
    put16(out + 18, m->queue_capacity);
    out[20] = m->state;
    put16(out + 21, m->freq_mhz);
    return RFSAS_HEARTBEAT_SIZE;
}

int rfsas_unpack_heartbeat(const uint8_t *p, size_t len, rfsas_heartbeat *m) {
    HAVE(RFSAS_HEARTBEAT_SIZE);
    m->uptime_us = get64(p);
    m->frames_heard = get32(p + 8);
    m->frames_dropped = get32(p + 12);
    m->queue_depth = get16(p + 16);
    m->queue_capacity = get16(p + 18);
    m->state = p[20];
    m->freq_mhz = get16(p + 21);
    return 0;
}

size_t rfsas_pack_ack(const rfsas_ack *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_ACK_SIZE);
    put16(out, m->acked_seq);
    out[2] = m->acked_type;
    return RFSAS_ACK_SIZE;
}

int rfsas_unpack_ack(const uint8_t *p, size_t len, rfsas_ack *m) {
    HAVE(RFSAS_ACK_SIZE);
    m->acked_seq = get16(p);
    m->acked_type = p[2];
    return 0;
}

size_t rfsas_pack_nak(const rfsas_nak *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_NAK_SIZE);
    put16(out, m->acked_seq);
    out[2] = m->acked_type;
    out[3] = m->error;
    put16(out + 4, m->detail);
    return RFSAS_NAK_SIZE;
}

int rfsas_unpack_nak(const uint8_t *p, size_t len, rfsas_nak *m) {
    HAVE(RFSAS_NAK_SIZE);
    m->acked_seq = get16(p);
    m->acked_type = p[2];
    m->error = p[3];
    m->detail = get16(p + 4);
    return 0;
}

size_t rfsas_pack_error_report(const rfsas_error_report *m, uint8_t *out, size_t cap) {
    if (m->text_len > RFSAS_MAX_ERROR_TEXT) return 0;
    NEED(6u + (size_t)m->text_len);
    put16(out, m->code);
    put32(out + 2, m->detail);
    memcpy(out + 6, m->text, m->text_len);
    return 6u + (size_t)m->text_len;
}

int rfsas_unpack_error_report(const uint8_t *p, size_t len, rfsas_error_report *m) {
    size_t n;
    HAVE(6u);
    m->code = get16(p);
    m->detail = get32(p + 2);
    n = len - 6u;
    if (n > RFSAS_MAX_ERROR_TEXT) n = RFSAS_MAX_ERROR_TEXT;
    m->text_len = (uint8_t)n;
    memcpy(m->text, p + 6, n);
    return 0;
}

size_t rfsas_pack_time_sync_request(const rfsas_time_sync_request *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_TIME_SYNC_REQUEST_SIZE);
    put64(out, m->host_time_ns);
    return RFSAS_TIME_SYNC_REQUEST_SIZE;
}

int rfsas_unpack_time_sync_request(const uint8_t *p, size_t len, rfsas_time_sync_request *m) {
    HAVE(RFSAS_TIME_SYNC_REQUEST_SIZE);
    m->host_time_ns = get64(p);
    return 0;
}

size_t rfsas_pack_time_sync(const rfsas_time_sync *m, uint8_t *out, size_t cap) {
    NEED(RFSAS_TIME_SYNC_SIZE);
    put64(out, m->host_time_ns);
    put64(out + 8, m->board_rx_us);
    put64(out + 16, m->board_tx_us);
    return RFSAS_TIME_SYNC_SIZE;
}

int rfsas_unpack_time_sync(const uint8_t *p, size_t len, rfsas_time_sync *m) {
    HAVE(RFSAS_TIME_SYNC_SIZE);
    m->host_time_ns = get64(p);
    m->board_rx_us = get64(p + 8);
    m->board_tx_us = get64(p + 16);
    return 0;
}

int rfsas_batch_open(const uint8_t *p, size_t len, uint8_t *count, uint8_t *record_size) {
    HAVE(2u);
    *count = p[0];
    *record_size = p[1];
    if (*record_size < RFSAS_MEASUREMENT_SIZE) return RFSAS_ERR_PAYLOAD;
    HAVE(2u + (size_t)*count * *record_size);
    return 0;
}

int rfsas_batch_get(const uint8_t *p, uint8_t record_size, uint8_t i, rfsas_measurement *m) {
    return rfsas_unpack_measurement(p + 2 + (size_t)i * record_size, record_size, m);
}

size_t rfsas_pack_batch(const rfsas_measurement *ms, size_t n, uint8_t *out, size_t cap) {
    size_t i;
    if (n > (RFSAS_MAX_PAYLOAD - 2u) / RFSAS_MEASUREMENT_SIZE) return 0;
    NEED(2u + n * RFSAS_MEASUREMENT_SIZE);
    out[0] = (uint8_t)n;
    out[1] = RFSAS_MEASUREMENT_SIZE;
    for (i = 0; i < n; i++) {
        if (!rfsas_pack_measurement(&ms[i], out + 2 + i * RFSAS_MEASUREMENT_SIZE,
                                    RFSAS_MEASUREMENT_SIZE)) {
            return 0;
        }
    }
    return 2u + n * RFSAS_MEASUREMENT_SIZE;
}
