/* proto.h - the vbrender wire protocol between master and workers: every
 * constant, every limit, and the one encoder/decoder pair.
 *
 * A message is two ZeroMQ frames: a 32-byte header frame and a payload frame
 * of fixed little-endian records (proto/PROTOCOL.md gives every byte). The
 * functions here are pure: no sockets, no allocation in the encoder beyond
 * the caller's buffer, and the decoder checks every field and every length
 * before anything reads a record, so bytes off the wire can never reach an
 * out-of-range index or an unchecked pointer.
 */
#ifndef VB_PROTO_H
#define VB_PROTO_H

#include <stddef.h>
#include <stdint.h>

#include "tracer.h"

#define PROTO_MAGIC 0x50524256u /* "VBRP" read as little-endian bytes */
#define PROTO_VERSION 2
#define PROTO_HEADER_SIZE 32
#define PROTO_HASH_SIZE 32  /* BLAKE2b-256 of a scene bundle */
#define PROTO_BUILD_SIZE 32 /* build id: versions + ISA + compiler, NUL-padded */
#define PROTO_TEXT_MAX 1024 /* refusal and error texts */

/* Limits that bound every allocation a peer can cause. */
#define PROTO_MAX_TASK_PIXELS 65536      /* records in one task or result */
#define PROTO_MAX_SCENE_JSON (64u << 20) /* bytes of scene JSON in a bundle */
#define PROTO_MAX_MESHES 64              /* mesh files in a bundle */
#define PROTO_MAX_MESH_BYTES (1u << 30)  /* bytes of one mesh file */
#define PROTO_MAX_BUNDLE (1536u << 20)   /* bytes of a whole bundle payload */
#define PROTO_MAX_NAME 128               /* mesh file name in a bundle */
#define PROTO_MAX_CREDIT 1024            /* tasks a worker may ask for at once */
#define PROTO_CREDIT_PER_THREAD 2        /* what a worker asks for: tasks in flight per thread */
#define PROTO_MAX_THREADS 4096

#define PROTO_TASK_RECORD_SIZE 48
#define PROTO_RESULT_RECORD_SIZE 56
/* The largest payload a worker sends: a RESULT of PROTO_MAX_TASK_PIXELS
 * records after its 24-byte head. */
#define PROTO_MAX_RESULT_PAYLOAD (24 + (size_t)PROTO_RESULT_RECORD_SIZE * PROTO_MAX_TASK_PIXELS)

typedef enum proto_type {
    PROTO_HELLO = 1,         /* worker -> master: threads, build id, ISA */
    PROTO_WELCOME = 2,       /* master -> worker: accepted; heartbeat interval */
    PROTO_REFUSE = 3,        /* either way: refused (version, build), with a text */
    PROTO_CREDIT = 4,        /* worker -> master: ready for n more tasks */
    PROTO_SCENE_REQUEST = 5, /* worker -> master: send the bundle with this hash */
    PROTO_SCENE_BUNDLE = 6,  /* master -> worker: scene JSON plus mesh files */
    PROTO_TASK = 7,          /* master -> worker: one layer for a batch of pixels */
    PROTO_RESULT = 8,        /* worker -> master: the task's per-pixel results */
    PROTO_HEARTBEAT = 9,     /* either way: still here */
    PROTO_BYE = 10,          /* either way: leaving (worker: outstanding tasks released) */
    PROTO_TASK_FAILED = 11,  /* worker -> master: cannot do this task (e.g. scene fails) */
    PROTO_TYPE_MAX = 11
} proto_type_t;

/* The header frame: magic u32, version u16, type u16, job u64, task u64,
 * attempt u32, payload_size u32 (must equal the payload frame's size). */
typedef struct proto_header {
    uint16_t version;
    uint16_t type;
    uint64_t job;
    uint64_t task;
    uint32_t attempt;
    uint32_t payload_size;
} proto_header_t;

typedef struct proto_hello {
    uint32_t threads;
    char build[PROTO_BUILD_SIZE + 1]; /* NUL-terminated */
} proto_hello_t;

typedef struct proto_welcome {
    uint32_t heartbeat_ms; /* send something at least this often */
    uint32_t lease_ms;     /* a task not answered within this is issued again */
} proto_welcome_t;

typedef struct proto_text {
    /* REFUSE, BYE, TASK_FAILED: UTF-8, NUL-terminated, at most PROTO_TEXT_MAX
     * bytes (NULL: empty). Encode: the caller's string; decode: recs->text. */
    const char *text;
} proto_text_t;

typedef struct proto_mesh_file {
    char name[PROTO_MAX_NAME + 1]; /* as the bundle's scene JSON names it */
    const uint8_t *data;           /* points into the decoded payload */
    uint32_t size;
} proto_mesh_file_t;

typedef struct proto_bundle {
    uint8_t hash[PROTO_HASH_SIZE];
    const char *json; /* points into the payload; NOT NUL-terminated */
    uint32_t json_size;
    uint32_t mesh_count;
    const proto_mesh_file_t *meshes; /* mesh_count files; decode: recs->meshes */
} proto_bundle_t;

/* A task: one layer of G samples for a batch of pixels. */
typedef struct proto_task {
    uint8_t scene_hash[PROTO_HASH_SIZE];
    tracer_settings_t settings; /* seed, integrator, sampler, max_depth */
    uint32_t layer;
    uint32_t count;
    const tracer_task_t *records; /* count records; decode: recs->tasks */
} proto_task_t;

typedef struct proto_result {
    uint64_t rays;
    uint64_t busy_us; /* worker time spent tracing this task */
    uint32_t count;
    const tracer_result_t *records; /* count records; decode: recs->results */
} proto_result_t;

/* A message: its header and the fields of its type. Small (about 100
 * bytes), so it lives on the stack. Its variable-length parts (records,
 * mesh files, text) are pointers: to encode, the caller points them at its
 * own data; a decode sets them itself, into the proto_records_t it is
 * given, and clears everything else first, so nothing from an earlier
 * message survives into the next. */
typedef struct proto_msg {
    proto_header_t h;
    union {
        proto_hello_t hello;
        proto_welcome_t welcome;
        proto_text_t text;
        uint32_t credit;
        uint8_t scene_hash[PROTO_HASH_SIZE]; /* SCENE_REQUEST */
        proto_bundle_t bundle;
        proto_task_t task;
        proto_result_t result;
    } u;
} proto_msg_t;

/* Where proto_decode puts a message's variable-length parts: the caller's
 * buffers, each with its capacity, apart from the message so that no
 * decode can overwrite them. A buffer left NULL (or a capacity of 0)
 * refuses messages that need it: a TASK with no tasks, a RESULT with
 * records but no results, a SCENE_BUNDLE with more mesh files than
 * mesh_capacity. Texts are copied into text, which every side has. */
typedef struct proto_records {
    tracer_task_t *tasks;
    uint32_t task_capacity;
    tracer_result_t *results;
    uint32_t result_capacity;
    proto_mesh_file_t *meshes;
    uint32_t mesh_capacity;
    char text[PROTO_TEXT_MAX + 1];
} proto_records_t;

/* The size the payload of msg will take. */
size_t proto_payload_size(const proto_msg_t *msg);

/* Encodes msg (its h.type and fields; h.version and h.payload_size are set
 * by the encoder) into header[PROTO_HEADER_SIZE] and payload[cap]. Returns
 * the payload size, or -1 with a message if a field is out of range or cap
 * is too small. */
long proto_encode(const proto_msg_t *msg, uint8_t header[PROTO_HEADER_SIZE], uint8_t *payload,
                  size_t cap, char *err, size_t errlen);

/* Decodes the two frames into *out (cleared first) and the caller's
 * buffers in *recs (which may be NULL when no message with records, files
 * or text is wanted). Checks magic, version (a peer with another version
 * gets -2 so the caller can send a REFUSE saying so), type, the payload size
 * against the header and the type's layout, every count against its limit
 * and recs' capacity, every enum and every string. Returns 0, -1
 * (malformed) or -2 (version). On failure *out and *recs may be partly
 * written. A bundle's json and data point into payload: valid only while
 * payload is; every other pointer in *out points into *recs. */
int proto_decode(const uint8_t *header, size_t header_size, const uint8_t *payload,
                 size_t payload_size, proto_msg_t *out, proto_records_t *recs, char *err,
                 size_t errlen);

/* "TASK", "RESULT", ... ("?" for unknown values). */
const char *proto_type_name(uint16_t type);

/* The content hash of a bundle (BLAKE2b-256, libsodium): over json_size
 * and mesh_count (u32 little-endian), the JSON, then for each mesh its name
 * length (u32), name, size (u32) and bytes. Every field is framed by its
 * length, so two different bundles cannot be read as the same bytes.
 * sodium_init() must have been called. */
void proto_bundle_hash(const proto_bundle_t *bundle, uint8_t out[PROTO_HASH_SIZE]);

/* This build's id: "vbrender-<proto version>-<ISA>-<compiler>", so peers
 * that could trace different bits refuse each other. isa from tracer_isa. */
void proto_build_id(const char *isa, char out[PROTO_BUILD_SIZE + 1]);
/* The same with the ISA this CPU supports (avx2 or sse4.2), without an
 * Embree device: what --version prints and the master says it runs. */
void proto_host_build_id(char out[PROTO_BUILD_SIZE + 1]);

#endif
