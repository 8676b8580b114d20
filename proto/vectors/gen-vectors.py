#!/usr/bin/env python3
"""gen-vectors.py - writes the golden test vectors of proto/PROTOCOL.md.

Independent of proto/proto.c on purpose: every byte comes from Python's
struct module with explicit little-endian formats, so a vector checks the C
encoder and decoder rather than repeating them. The values are fixed; running
this again must give the same files (the checked-in .hex files are the
reference, this script only documents how they were made).

    proto/vectors/gen-vectors.py            # from the project root

Writes proto/vectors/*.hex (valid), proto/vectors/invalid/*.hex and the
fuzz seed corpus tests/data/fuzz-proto/*.bin (one byte 0x20 = header length,
then the header and payload frames: the input format of tests/fuzz_proto.c).
"""
import os
import struct

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
VEC = os.path.join(ROOT, "proto", "vectors")
FUZZ = os.path.join(ROOT, "tests", "data", "fuzz-proto")

MAGIC = 0x50524256
TYPES = {"HELLO": 1, "WELCOME": 2, "REFUSE": 3, "CREDIT": 4, "SCENE_REQUEST": 5,
         "SCENE_BUNDLE": 6, "TASK": 7, "RESULT": 8, "HEARTBEAT": 9, "BYE": 10,
         "TASK_FAILED": 11}


class Frame:
    """A frame built field by field; remembers offsets for the comments."""

    def __init__(self):
        self.fields = []  # (offset, bytes, name, shown value)
        self.size = 0

    def add(self, fmt, value, name, shown=None):
        b = struct.pack("<" + fmt, value) if fmt else bytes(value)
        self.fields.append((self.size, b, name, repr(value) if shown is None else shown))
        self.size += len(b)
        return self

    def raw(self, b, name, shown):
        return self.add(None, b, name, shown)

    def bytes(self):
        return b"".join(f[1] for f in self.fields)

    def hex(self):
        if not self.fields:
            return "-"
        return " ".join(f[1].hex() for f in self.fields if f[1])

    def comments(self, title):
        out = ["# %s (%d bytes):" % (title, self.size)]
        for off, b, name, shown in self.fields:
            out.append("#   %4d  %3d  %-22s %s" % (off, len(b), name, shown))
        return out


def header(type_, job=0, task=0, attempt=0, payload_size=0, magic=MAGIC, version=2):
    h = Frame()
    h.add("I", magic, "magic", "0x%08x" % magic + (' "VBRP"' if magic == MAGIC else ""))
    h.add("H", version, "version")
    h.add("H", type_, "type", "%d (%s)" % (type_, {v: k for k, v in TYPES.items()}.get(type_, "?")))
    h.add("Q", job, "job", "0x%x" % job)
    h.add("Q", task, "task")
    h.add("I", attempt, "attempt")
    h.add("I", payload_size, "payload_size")
    return h


def hexbytes(b):
    return b.hex() if b else "(none)"


def write(path, title, notes, h, p, seed=None):
    lines = ["# %s" % title]
    lines += ["# %s" % n for n in notes]
    lines.append("# Format: '#' lines are comments; the first other line is the header frame,")
    lines.append("# the second the payload frame ('-' if empty), as hex (spaces only separate")
    lines.append("# fields for reading). All integers little-endian; f64 as IEEE-754 bits.")
    lines += h.comments("header")
    lines += p.comments("payload")
    lines.append(h.hex())
    lines.append(p.hex())
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    if seed:
        with open(os.path.join(FUZZ, seed), "wb") as f:
            f.write(bytes([len(h.bytes())]) + h.bytes() + p.bytes())


def f64(x):
    return struct.unpack("<Q", struct.pack("<d", x))[0]


def fhex(x):
    return "%r (bits 0x%016x)" % (x, f64(x))


# ---- payload builders ------------------------------------------------------

def hello(threads, build):
    p = Frame()
    p.add("I", threads, "threads")
    p.raw(build.ljust(32, b"\0"), "build[32]", repr(build.decode("latin-1")) + " NUL-padded")
    return p


def welcome(hb, lease):
    return Frame().add("I", hb, "heartbeat_ms").add("I", lease, "lease_ms")


def text(t):
    p = Frame().add("I", len(t), "text_len")
    if t:
        p.raw(t, "text", repr(t.decode("latin-1")))
    return p


def credit(n):
    return Frame().add("I", n, "credit")


HASH_A = bytes(range(0x00, 0x20))
HASH_B = bytes(range(0x20, 0x40))


def bundle(hash_, json, meshes, extra=b""):
    p = Frame()
    p.raw(hash_, "hash[32]", hash_.hex())
    p.add("I", len(json), "json_size")
    p.add("I", len(meshes), "mesh_count")
    p.raw(json, "json", repr(json.decode()))
    for i, (name, data) in enumerate(meshes):
        p.add("H", len(name), "mesh[%d].name_len" % i)
        p.raw(name, "mesh[%d].name" % i, repr(name.decode("latin-1")))
        p.add("I", len(data), "mesh[%d].size" % i)
        if data:
            p.raw(data, "mesh[%d].data" % i, repr(data))
    if extra:
        p.raw(extra, "(trailing)", extra.hex())
    return p


def task(hash_, seed, integrator, max_depth, layer, records, count=None, reserved=b"\0\0",
         cut=None, sampler=0):
    p = Frame()
    p.raw(hash_, "scene_hash[32]", hash_.hex())
    p.add("Q", seed, "seed", "0x%016x" % seed)
    p.add("B", integrator, "integrator", "%d%s" % (integrator, {0: " (path)", 1: " (naive)", 2: " (direct)"}.get(integrator, "")))
    p.add("B", sampler, "sampler", "%d%s" % (sampler, {0: " (independent)", 1: " (sobol)"}.get(sampler, "")))
    p.raw(reserved, "reserved[2]", reserved.hex())
    p.add("I", max_depth, "max_depth")
    p.add("I", layer, "layer")
    p.add("I", len(records) if count is None else count, "count")
    for i, (pixel, sc, first, prior, sums) in enumerate(records):
        r = Frame()
        r.add("I", pixel, "[%d].pixel" % i)
        r.add("I", sc, "[%d].sample_count" % i)
        r.add("Q", first, "[%d].first_sample" % i)
        r.add("Q", prior, "[%d].prior_count" % i)
        for c in range(3):
            r.add("d", sums[c], "[%d].prior_sum[%d]" % (i, c), fhex(sums[c]))
        for off, b, name, shown in r.fields:
            if cut is not None and i == len(records) - 1 and off >= cut:
                break
            p.fields.append((p.size, b, "record" + name, shown))
            p.size += len(b)
    return p


def result(rays, busy, records, count=None, reserved=0):
    p = Frame()
    p.add("Q", rays, "rays")
    p.add("Q", busy, "busy_us")
    p.add("I", len(records) if count is None else count, "count")
    p.add("I", reserved, "reserved")
    for i, rec in enumerate(records):
        pixel, samples, nonfinite, sums, m2, pvar = rec[:6]
        rays = rec[6] if len(rec) > 6 else samples + nonfinite  # the fewest rays valid
        p.add("I", pixel, "record[%d].pixel" % i)
        p.add("I", samples, "record[%d].samples" % i)
        p.add("I", nonfinite, "record[%d].nonfinite" % i)
        p.add("I", rays, "record[%d].rays" % i)
        for c in range(3):
            p.add("d", sums[c], "record[%d].sum[%d]" % (i, c), fhex(sums[c]))
        p.add("d", m2, "record[%d].lum_m2" % i, fhex(m2))
        p.add("d", pvar, "record[%d].pvar" % i, fhex(pvar))
    return p


def valid(name, type_, p, notes, job=0, task_=0, attempt=0):
    h = header(TYPES[type_], job, task_, attempt, p.size)
    write(os.path.join(VEC, name + ".hex"), "%s.hex - a valid %s message." % (name, type_),
          notes, h, p, seed=name + ".bin")


def invalid(name, p, notes, type_=None, h=None, **kw):
    if h is None:
        h = header(TYPES[type_], payload_size=p.size, **kw)
    write(os.path.join(VEC, "invalid", name + ".hex"), "invalid/%s.hex - must be refused." % name,
          notes, h, p)


JOB, TASK_ID, ATTEMPT = 0x1122334455667788, 42, 3
TASK_RECORDS = [
    (7, 16, 80, 80, (1.5, 0.25, 0.0)),
    (1000000, 4096, 1 << 32, 3, (0.1, 2.0, 1e300)),
]
RESULT_RECORDS = [
    (7, 15, 1, (3.0, 0.5, 0.125), 0.75, 0.01, 83),
    (1000000, 4096, 0, (5e-324, 4096.0, 0.0), 0.0, 0.0, 0xFFFFFFFF),
]
BUNDLE_JSON = b'{"meshes":["quad.obj"]}'
BUNDLE_MESHES = [(b"quad.obj", b"v 0 0 0\n"), (b"empty.ply", b"")]


def main():
    os.makedirs(os.path.join(VEC, "invalid"), exist_ok=True)
    os.makedirs(FUZZ, exist_ok=True)

    valid("hello", "HELLO", hello(16, b"vbrender-p2-t2-avx2-gcc12.2"), ["A worker with 16 threads."])
    valid("welcome", "WELCOME", welcome(1000, 30000), ["Heartbeat every second, 30 s lease."])
    valid("refuse", "REFUSE", text(b"build differs: vbrender-p2-t2-sse4.2-gcc12.2"),
          ["The master refuses a worker of another build."])
    valid("credit", "CREDIT", credit(8), ["The worker can take 8 more tasks."])
    valid("scene_request", "SCENE_REQUEST", Frame().raw(HASH_A, "hash[32]", HASH_A.hex()),
          ["The worker asks for the bundle whose hash is 00 01 .. 1f."])
    valid("scene_bundle", "SCENE_BUNDLE", bundle(HASH_B, BUNDLE_JSON, BUNDLE_MESHES),
          ["A bundle with two mesh files, the second empty (size 0)."])
    valid("task", "TASK", task(HASH_A, 0xDEADBEEFCAFEF00D, 1, 8, 5, TASK_RECORDS, sampler=1),
          ["Job, task and attempt fence the task; two pixel records, the second with",
           "first_sample 2^32 (crosses 32 bits) and prior_sum[2] = 1e300."],
          JOB, TASK_ID, ATTEMPT)
    valid("result", "RESULT", result(123456789012, 250000, RESULT_RECORDS),
          ["The answer to task.hex (same job, task, attempt); record 1 has a subnormal sum[0]",
           "and its rays saturated at 2^32 - 1."],
          JOB, TASK_ID, ATTEMPT)
    valid("heartbeat", "HEARTBEAT", Frame(), ["Empty payload."])
    valid("bye", "BYE", text(b"worker shutting down"), ["A worker leaving."])
    valid("task_failed", "TASK_FAILED", text(b"scene: mesh quad.obj: bad vertex"),
          ["The worker cannot do task 42, attempt 3."], JOB, TASK_ID, ATTEMPT)

    # ---- invalid ----
    invalid("bad_magic", Frame(), ["HEARTBEAT with magic 0x50524257 ('W' for 'V')."],
            h=header(9, magic=0x50524257))
    invalid("wrong_version", Frame(), ["HEARTBEAT from a version 1 peer: decode returns -2."],
            h=header(9, version=1))
    invalid("unknown_type", Frame(), ["Message type 12 does not exist."], h=header(12))
    sh = header(9)
    sh.fields[-1] = (28, b"\0\0\0", "payload_size (cut short)", "3 of 4 bytes")
    sh.size = 31
    invalid("short_header", Frame(), ["A 31-byte header frame."], h=sh)
    invalid("size_mismatch", credit(8), ["CREDIT whose header says 8 payload bytes; the frame has 4."],
            h=header(4, payload_size=8))
    invalid("credit_zero", credit(0), ["CREDIT 0."], "CREDIT")
    invalid("hello_bad_build", hello(16, b"vbrender\x07"), ["HELLO whose build id has a BEL byte."],
            "HELLO")
    invalid("text_with_nul", text(b"a\0b"), ["BYE whose text has a NUL byte inside."], "BYE")
    invalid("count_over_limit", task(HASH_A, 1, 0, 0, 0, [], count=70000),
            ["TASK claiming 70000 records (limit 65536), with none present."], "TASK")
    invalid("truncated_record", task(HASH_A, 1, 0, 0, 0, TASK_RECORDS, cut=24),
            ["TASK of count 2 whose second record stops after prior_count (24 of 48 bytes)",
             "(header payload_size matches the frame)."], "TASK")
    invalid("bad_integrator", task(HASH_A, 1, 3, 0, 0, TASK_RECORDS[:1]),
            ["TASK with integrator 3."], "TASK")
    invalid("reserved_set", task(HASH_A, 1, 0, 0, 0, TASK_RECORDS[:1], reserved=b"\1\0"),
            ["TASK with reserved byte 1 set."], "TASK")
    invalid("bad_sampler", task(HASH_A, 1, 0, 0, 0, TASK_RECORDS[:1], sampler=2),
            ["TASK with sampler 2."], "TASK")
    invalid("task_zero_samples", task(HASH_A, 1, 0, 0, 0, [(1, 0, 0, 0, (0.0, 0.0, 0.0))]),
            ["TASK record with sample_count 0."], "TASK")
    invalid("task_inf_prior",
            task(HASH_A, 1, 0, 0, 0, [(1, 1, 0, 1, (float("inf"), 0.0, 0.0))]),
            ["TASK record with prior_sum[0] = +Inf."], "TASK")
    nan_records = [RESULT_RECORDS[0], (8, 1, 0, (0.0, 0.0, 0.0), 0.0, float("nan"))]
    invalid("nan_in_record", result(1, 1, nan_records), ["RESULT whose record 1 has pvar NaN."],
            "RESULT")
    invalid("result_negative", result(1, 1, [(8, 1, 0, (0.0, 0.0, -1.0), 0.0, 0.0)]),
            ["RESULT whose record 0 has sum[2] = -1."], "RESULT")
    invalid("result_few_rays", result(1, 1, [(8, 3, 1, (0.0, 0.0, 0.0), 0.0, 0.0, 3)]),
            ["RESULT whose record 0 has 3 rays for 4 samples (each traces at least one)."], "RESULT")
    invalid("result_zero_samples", result(1, 1, [(8, 0, 0, (0.0, 0.0, 0.0), 0.0, 0.0)]),
            ["RESULT record with samples 0 and nonfinite 0."], "RESULT")
    invalid("duplicate_mesh_name",
            bundle(HASH_B, b"{}", [(b"quad.obj", b"a"), (b"quad.obj", b"b")]),
            ["SCENE_BUNDLE with two meshes named quad.obj."], "SCENE_BUNDLE")
    invalid("name_with_slash", bundle(HASH_B, b"{}", [(b"../quad.obj", b"a")]),
            ["SCENE_BUNDLE with a mesh named ../quad.obj."], "SCENE_BUNDLE")
    invalid("name_dotdot", bundle(HASH_B, b"{}", [(b"..", b"a")]),
            ["SCENE_BUNDLE with a mesh named '..'."], "SCENE_BUNDLE")
    invalid("bundle_trailing", bundle(HASH_B, b"{}", [(b"a.obj", b"a")], extra=b"\0"),
            ["SCENE_BUNDLE with one byte after the last mesh."], "SCENE_BUNDLE")


if __name__ == "__main__":
    main()
