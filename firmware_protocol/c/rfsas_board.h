/*
 * rfsas DF-board protocol, version 1: reference codec in C99.
 *
 * Framing (COBS + 0x00 delimiter), the 8-byte header, CRC-16/CCITT-FALSE
 * seeded per message type, and pack/unpack for every version-1 message.
 * No dynamic allocation, no global state; every function works on buffers
 * the caller owns. See ../SPEC.md for the protocol itself.
 *
 * Typical use on a board:
 *
 *     uint8_t payload[RFSAS_MEASUREMENT_SIZE], wire[RFSAS_WIRE_SIZE(RFSAS_MEASUREMENT_SIZE)];
 *     size_t n = rfsas_pack_measurement(&m, payload, sizeof payload);
 *     size_t w = rfsas_frame_encode(RFSAS_MEASUREMENT, seq++, 0, 0, payload, n, wire, sizeof wire);
 *     uart_write(wire, w);
 *
 * and for received bytes:
 *
 *     static rfsas_stream rx;          (about 2.1 KB with the default RFSAS_MAX_PAYLOAD)
 *     rfsas_frame f; size_t skip;
 *     int r = rfsas_stream_push(&rx, byte, &f, &skip);
 *     if (r == RFSAS_FRAME) handle(f.type, f.payload, f.length);
 */
#ifndef RFSAS_BOARD_H
#define RFSAS_BOARD_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define RFSAS_MAGIC 0xD1u /* protocol version 1 */
#define RFSAS_HEADER_SIZE 8u
#define RFSAS_CRC_SIZE 2u
#ifndef RFSAS_MAX_PAYLOAD
#define RFSAS_MAX_PAYLOAD 1024u /* may be lowered on small boards */
#endif
#define RFSAS_MAX_FRAME (RFSAS_HEADER_SIZE + RFSAS_MAX_PAYLOAD + RFSAS_CRC_SIZE)
/* Largest COBS encoding of a frame, without the delimiter. */
#define RFSAS_MAX_ENCODED (RFSAS_MAX_FRAME + RFSAS_MAX_FRAME / 254u + 1u)
/* Bytes on the wire for a payload of n bytes (COBS worst case + delimiter). */
#define RFSAS_WIRE_SIZE(n) \
    (RFSAS_HEADER_SIZE + (n) + RFSAS_CRC_SIZE + (RFSAS_HEADER_SIZE + (n) + RFSAS_CRC_SIZE) / 254u + 2u)
#define RFSAS_KNOWN_INCOMPAT 0x00u /* no incompatible flags in version 1 */

/* Message types and their CRC seed bytes (CRC_EXTRA). */
enum rfsas_type {
    RFSAS_HELLO = 0x01,
    RFSAS_INFO = 0x02,
    RFSAS_MEASUREMENT = 0x10,
    RFSAS_MEASUREMENT_BATCH = 0x11,
    RFSAS_SET_CHANNEL = 0x20,
    RFSAS_SET_SCAN_PLAN = 0x21,
    RFSAS_START = 0x22,
    RFSAS_STOP = 0x23,
    RFSAS_HEARTBEAT = 0x30,
    RFSAS_ACK = 0x40,
    RFSAS_NAK = 0x41,
    RFSAS_ERROR_REPORT = 0x42,
    RFSAS_TIME_SYNC_REQUEST = 0x50,
    RFSAS_TIME_SYNC = 0x51
};

/* Compatible flags (header byte 2). */
#define RFSAS_COMPAT_OVERFLOW 0x01u /* board dropped measurements before this frame */
#define RFSAS_COMPAT_RESTART 0x02u  /* first frame since the sender (re)started */

/* Measurement flags. */
#define RFSAS_MEAS_RETRY 0x01u
#define RFSAS_MEAS_BAD_FCS 0x02u
#define RFSAS_MEAS_SATURATED 0x04u

/* Capability bits of rfsas_info.capabilities. */
#define RFSAS_CAP_WIFI_2G4 0x01u
#define RFSAS_CAP_WIFI_5G 0x02u
#define RFSAS_CAP_BLE 0x04u
#define RFSAS_CAP_BATCH 0x08u
#define RFSAS_CAP_TIME_SYNC 0x10u
#define RFSAS_CAP_SCAN_PLAN 0x20u
#define RFSAS_CAP_FRAME_SEQ 0x40u

/* NAK error codes. */
enum rfsas_nak_code {
    RFSAS_NAK_UNKNOWN_TYPE = 1,
    RFSAS_NAK_BAD_PAYLOAD = 2,
    RFSAS_NAK_BAD_VALUE = 3,
    RFSAS_NAK_UNSUPPORTED = 4,
    RFSAS_NAK_BUSY = 5,
    RFSAS_NAK_INTERNAL = 6
};

/* Results: RFSAS_NONE / RFSAS_FRAME from rfsas_stream_push, errors < 0. */
enum rfsas_result {
    RFSAS_FRAME = 1,
    RFSAS_NONE = 0,
    RFSAS_ERR_COBS = -1,
    RFSAS_ERR_SHORT = -2,
    RFSAS_ERR_MAGIC = -3,
    RFSAS_ERR_INCOMPATIBLE = -4,
    RFSAS_ERR_LENGTH = -5,
    RFSAS_ERR_UNKNOWN_TYPE = -6,
    RFSAS_ERR_CRC = -7,
    RFSAS_ERR_PAYLOAD = -8,
    RFSAS_ERR_SPACE = -9 /* output buffer too small */
};

/* Name of a result code ("crc", "cobs", ...), as used by the test vectors. */
const char *rfsas_result_name(int result);

/* ---- CRC ------------------------------------------------------------ */

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0),
 * continuing from register value crc. rfsas_crc16(0xFFFF, "123456789", 9)
 * is 0x29B1. */
uint16_t rfsas_crc16(uint16_t crc, const uint8_t *data, size_t len);

/* CRC seed byte of a message type, or -1 for an unknown type. */
int rfsas_crc_extra(uint8_t type);

/* ---- COBS ----------------------------------------------------------- */

/* COBS-encode len bytes; returns the encoded length (no delimiter), or 0 if
 * cap is too small. Canonical: no empty block after a final 0xFF block. */
size_t rfsas_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);

/* COBS-decode len bytes (which must contain no zero byte); returns 0 and
 * sets *out_len, or RFSAS_ERR_COBS / RFSAS_ERR_SPACE. */
int rfsas_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len);

/* ---- frames --------------------------------------------------------- */

typedef struct {
    uint8_t type;
    uint16_t seq;
    uint8_t incompat;
    uint8_t compat;
    const uint8_t *payload; /* points into the decoder's buffer */
    uint16_t length;
} rfsas_frame;

/* Encode one frame: COBS(header, payload, CRC) followed by 0x00. Returns
 * the number of wire bytes, or 0 if the type is unknown, the payload too
 * long or cap too small. RFSAS_WIRE_SIZE(len) bytes are always enough. */
size_t rfsas_frame_encode(uint8_t type, uint16_t seq, uint8_t compat, uint8_t incompat,
                          const uint8_t *payload, size_t len, uint8_t *out, size_t cap);

/* Check a COBS-decoded frame; fills *f (payload points into decoded).
 * Returns 0 or the first failing check's error. */
int rfsas_frame_check(const uint8_t *decoded, size_t len, rfsas_frame *f);

/* COBS-decode a segment (bytes between delimiters) into work and check it. */
int rfsas_segment_decode(const uint8_t *seg, size_t len, uint8_t *work, size_t cap,
                         rfsas_frame *f);

/* Byte-at-a-time receiver with resynchronisation. */
typedef struct {
    uint8_t seg[RFSAS_MAX_ENCODED];
    size_t len;
    size_t seg_len; /* length of the last completed segment */
    size_t dropped; /* bytes of an overlong segment that were not kept */
    uint8_t work[RFSAS_MAX_FRAME];
    size_t skip;    /* garbage cut off the front of the last frame */
} rfsas_stream;

void rfsas_stream_init(rfsas_stream *s);

/* Push one received byte. Returns RFSAS_NONE, RFSAS_FRAME (then *f is valid
 * until the next push and *skip tells how many garbage bytes preceded the
 * frame in its segment), or an error (< 0) for a segment that held no valid
 * frame. The frame's wire bytes, without the delimiter, are
 * s->seg[*skip .. s->seg_len). */
int rfsas_stream_push(rfsas_stream *s, uint8_t byte, rfsas_frame *f, size_t *skip);

/* ---- messages ------------------------------------------------------- */

#define RFSAS_RSSI_SLOTS 4
#define RFSAS_RSSI_NONE (-128)
#define RFSAS_FRAME_SEQ_NONE 0xFFFFu
#define RFSAS_MAX_SCAN_CHANNELS 64
#define RFSAS_MAX_ERROR_TEXT 64

#define RFSAS_HELLO_SIZE 1u
#define RFSAS_INFO_SIZE 17u
#define RFSAS_MEASUREMENT_SIZE 25u
#define RFSAS_SET_CHANNEL_SIZE 2u
#define RFSAS_HEARTBEAT_SIZE 23u
#define RFSAS_ACK_SIZE 3u
#define RFSAS_NAK_SIZE 6u
#define RFSAS_TIME_SYNC_REQUEST_SIZE 8u
#define RFSAS_TIME_SYNC_SIZE 24u

typedef struct { uint8_t protocol_version; } rfsas_hello;

typedef struct {
    uint8_t protocol_version, fw_major, fw_minor, fw_patch, n_antennas;
    uint32_t capabilities;
    uint64_t board_id;
} rfsas_info;

typedef struct {
    uint64_t t_us;        /* board time, microseconds */
    uint8_t mac[6];       /* transmitter address, over-the-air order */
    uint16_t freq_mhz;
    uint8_t channel;
    uint8_t kind;         /* frame kind */
    uint8_t flags;        /* RFSAS_MEAS_* */
    uint16_t frame_seq;   /* 802.11 sequence number or RFSAS_FRAME_SEQ_NONE */
    int8_t rssi_dbm[RFSAS_RSSI_SLOTS]; /* RFSAS_RSSI_NONE = no value */
} rfsas_measurement;

typedef struct { uint16_t freq_mhz; } rfsas_set_channel;

typedef struct {
    uint16_t dwell_ms;
    uint8_t count;
    uint16_t freq_mhz[RFSAS_MAX_SCAN_CHANNELS];
} rfsas_set_scan_plan;

typedef struct {
    uint64_t uptime_us;
    uint32_t frames_heard, frames_dropped;
    uint16_t queue_depth, queue_capacity;
    uint8_t state;        /* 0 idle, 1 streaming */
    uint16_t freq_mhz;
} rfsas_heartbeat;

typedef struct { uint16_t acked_seq; uint8_t acked_type; } rfsas_ack;

typedef struct {
    uint16_t acked_seq;
    uint8_t acked_type, error;
    uint16_t detail;
} rfsas_nak;

typedef struct {
    uint16_t code;
    uint32_t detail;
    uint8_t text_len;
    char text[RFSAS_MAX_ERROR_TEXT]; /* UTF-8, not NUL-terminated */
} rfsas_error_report;

typedef struct { uint64_t host_time_ns; } rfsas_time_sync_request;

typedef struct { uint64_t host_time_ns, board_rx_us, board_tx_us; } rfsas_time_sync;

/* pack: write the payload, return its length (0 if cap is too small or a
 * field is out of range). unpack: 0 or RFSAS_ERR_PAYLOAD; trailing bytes
 * from a newer sender are ignored. */
size_t rfsas_pack_hello(const rfsas_hello *m, uint8_t *out, size_t cap);
int rfsas_unpack_hello(const uint8_t *p, size_t len, rfsas_hello *m);
size_t rfsas_pack_info(const rfsas_info *m, uint8_t *out, size_t cap);
int rfsas_unpack_info(const uint8_t *p, size_t len, rfsas_info *m);
size_t rfsas_pack_measurement(const rfsas_measurement *m, uint8_t *out, size_t cap);
int rfsas_unpack_measurement(const uint8_t *p, size_t len, rfsas_measurement *m);
size_t rfsas_pack_set_channel(const rfsas_set_channel *m, uint8_t *out, size_t cap);
int rfsas_unpack_set_channel(const uint8_t *p, size_t len, rfsas_set_channel *m);
size_t rfsas_pack_set_scan_plan(const rfsas_set_scan_plan *m, uint8_t *out, size_t cap);
int rfsas_unpack_set_scan_plan(const uint8_t *p, size_t len, rfsas_set_scan_plan *m);
size_t rfsas_pack_heartbeat(const rfsas_heartbeat *m, uint8_t *out, size_t cap);
int rfsas_unpack_heartbeat(const uint8_t *p, size_t len, rfsas_heartbeat *m);
size_t rfsas_pack_ack(const rfsas_ack *m, uint8_t *out, size_t cap);
int rfsas_unpack_ack(const uint8_t *p, size_t len, rfsas_ack *m);
size_t rfsas_pack_nak(const rfsas_nak *m, uint8_t *out, size_t cap);
int rfsas_unpack_nak(const uint8_t *p, size_t len, rfsas_nak *m);
size_t rfsas_pack_error_report(const rfsas_error_report *m, uint8_t *out, size_t cap);
int rfsas_unpack_error_report(const uint8_t *p, size_t len, rfsas_error_report *m);
size_t rfsas_pack_time_sync_request(const rfsas_time_sync_request *m, uint8_t *out, size_t cap);
int rfsas_unpack_time_sync_request(const uint8_t *p, size_t len, rfsas_time_sync_request *m);
size_t rfsas_pack_time_sync(const rfsas_time_sync *m, uint8_t *out, size_t cap);
int rfsas_unpack_time_sync(const uint8_t *p, size_t len, rfsas_time_sync *m);

/* Batches: a 2-byte head (count, record_size) then count records. */
/* Check a batch payload; sets *count and *record_size. */
int rfsas_batch_open(const uint8_t *p, size_t len, uint8_t *count, uint8_t *record_size);
/* Record i of a checked batch payload. */
int rfsas_batch_get(const uint8_t *p, uint8_t record_size, uint8_t i, rfsas_measurement *m);
/* Pack n measurements as a batch payload; returns its length or 0. */
size_t rfsas_pack_batch(const rfsas_measurement *ms, size_t n, uint8_t *out, size_t cap);

#ifdef __cplusplus
}
#endif

#endif /* RFSAS_BOARD_H */
