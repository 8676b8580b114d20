/* keys.c - see keys.h. */
#include "keys.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zmq.h>

static const char z85_alphabet[] =
    "0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ.-:+=^!/*?&<>()[]{}@%$#";

int keys_valid_z85(const char *text)
{
    if (!text || strlen(text) != KEYS_Z85_LEN)
        return 0;
    for (const char *p = text; *p; p++)
        if (!strchr(z85_alphabet, *p))
            return 0;
    /* the alphabet is not enough: a group of five can overflow 32 bits */
    uint8_t bin[32];
    return zmq_z85_decode(bin, text) != NULL;
}

int keys_generate(keys_pair_t *out, char *err, size_t errlen)
{
    memset(out, 0, sizeof *out);
    if (zmq_curve_keypair(out->public_z85, out->secret_z85) != 0) {
        snprintf(err, errlen, "cannot make a CURVE key pair: %s (libzmq built without CURVE?)",
                 zmq_strerror(errno));
        return -1;
    }
    return 0;
}

/* ---- files ------------------------------------------------------------------------- */

/* Reads a small regular file into buf (terminated). With secret set, the
 * file must be private to its owner. Its close is unchecked: a descriptor
 * only read from loses nothing. */
static int read_small(const char *path, int secret, char *buf, size_t cap, char *err, size_t errlen)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        snprintf(err, errlen, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode)) {
        snprintf(err, errlen, "%s: not a regular file", path);
        close(fd);
        return -1;
    }
    if (secret && (st.st_mode & 077)) {
        /* as ssh: a secret others could have read is no secret */
        snprintf(
            err, errlen,
            "%s: permissions 0%03o are too open: a secret key must be readable by its owner only "
            "(chmod 600 '%s')",
            path, (unsigned)(st.st_mode & 0777), path);
        close(fd);
        return -1;
    }
    if (st.st_size >= (off_t)cap) {
        snprintf(err, errlen, "%s: too long for a key file (%lld bytes)", path,
                 (long long)st.st_size);
        close(fd);
        return -1;
    }
    size_t n = 0;
    for (;;) {
        ssize_t got = read(fd, buf + n, cap - 1 - n);
        if (got < 0 && errno == EINTR)
            continue;
        if (got < 0) {
            snprintf(err, errlen, "%s: cannot read: %s", path, strerror(errno));
            close(fd);
            return -1;
        }
        n += (size_t)got;
        if (got == 0 || n == cap - 1)
            break;
    }
    close(fd);
    buf[n] = '\0';
    if (memchr(buf, '\0', n)) {
        snprintf(err, errlen, "%s: not a text file", path);
        return -1;
    }
    return 0;
}

/* Cuts trailing spaces, tabs and carriage returns off line (in place). */
static void trim_end(char *line)
{
    size_t n = strlen(line);
    while (n > 0 && (line[n - 1] == ' ' || line[n - 1] == '\t' || line[n - 1] == '\r'))
        line[--n] = '\0';
}

int keys_load_public(const char *path, char out[KEYS_Z85_LEN + 1], char *err, size_t errlen)
{
    char buf[KEYS_MAX_FILE];
    if (read_small(path, 0, buf, sizeof buf, err, errlen) < 0)
        return -1;
    /* one line, its newline optional */
    char *nl = strchr(buf, '\n');
    if (nl) {
        *nl = '\0';
        for (const char *p = nl + 1; *p; p++)
            if (*p != '\n' && *p != '\r' && *p != ' ' && *p != '\t') {
                snprintf(err, errlen, "%s: not a public key file (more than one line)", path);
                return -1;
            }
    }
    trim_end(buf);
    if (!keys_valid_z85(buf)) {
        snprintf(err, errlen,
                 "%s: not a CURVE public key (%d Z85 characters on one line, as 'vbrender keygen' "
                 "writes)",
                 path, KEYS_Z85_LEN);
        return -1;
    }
    memcpy(out, buf, KEYS_Z85_LEN + 1);
    return 0;
}

int keys_load_secret(const char *path, keys_pair_t *out, char *err, size_t errlen)
{
    memset(out, 0, sizeof *out);
    char buf[KEYS_MAX_FILE];
    if (read_small(path, 1, buf, sizeof buf, err, errlen) < 0)
        return -1;
    int have_pub = 0, have_sec = 0, lineno = 0;
    for (char *line = buf, *next; line; line = next) {
        next = strchr(line, '\n');
        if (next)
            *next++ = '\0';
        lineno++;
        trim_end(line);
        if (line[0] == '\0' || line[0] == '#')
            continue;
        char *val = NULL;
        int *have = NULL;
        char *dst = NULL;
        if (strncmp(line, "public ", 7) == 0) {
            val = line + 7, have = &have_pub, dst = out->public_z85;
        } else if (strncmp(line, "secret ", 7) == 0) {
            val = line + 7, have = &have_sec, dst = out->secret_z85;
        } else {
            snprintf(err, errlen, "%s: line %d: expected 'public KEY' or 'secret KEY'", path,
                     lineno);
            goto fail;
        }
        while (*val == ' ' || *val == '\t')
            val++;
        if (*have || !keys_valid_z85(val)) {
            snprintf(err, errlen, "%s: line %d: %s", path, lineno,
                     *have ? "a second key of that kind" : "not a key (40 Z85 characters)");
            goto fail;
        }
        memcpy(dst, val, KEYS_Z85_LEN + 1);
        *have = 1;
    }
    if (!have_pub || !have_sec) {
        snprintf(
            err, errlen,
            "%s: not a key pair file (needs a 'public' and a 'secret' line, as 'vbrender keygen' "
            "writes)",
            path);
        goto fail;
    }
    char derived[KEYS_Z85_LEN + 1];
    if (zmq_curve_public(derived, out->secret_z85) != 0 || strcmp(derived, out->public_z85) != 0) {
        snprintf(err, errlen, "%s: its public key is not the one its secret key gives", path);
        goto fail;
    }
    explicit_bzero(buf, sizeof buf);
    return 0;
fail:
    explicit_bzero(buf, sizeof buf);
    explicit_bzero(out, sizeof *out);
    return -1;
}

/* Creates path (which must not exist) with mode and writes text to it. */
static int write_new(const char *path, mode_t mode, const char *text, char *err, size_t errlen)
{
    int fd = open(path, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, mode);
    if (fd < 0) {
        snprintf(err, errlen, "%s: cannot create: %s", path, strerror(errno));
        return -1;
    }
    /* the umask may only have removed bits, but say exactly what we mean */
    size_t n = strlen(text), done = 0;
    int ok = fchmod(fd, mode) == 0;
    while (ok && done < n) {
        ssize_t w = write(fd, text + done, n - done);
        if (w < 0 && errno == EINTR)
            continue;
        ok = w > 0;
        done += w > 0 ? (size_t)w : 0;
    }
    /* On a failure the close and unlink are unchecked: the write failed
     * and says so, and a partial file left behind is refused on load as
     * malformed, and keeps keys_write from overwriting it. */
    if (!ok || fsync(fd) != 0) {
        snprintf(err, errlen, "%s: cannot write: %s", path, strerror(errno));
        (void)close(fd);
        (void)unlink(path);
        return -1;
    }
    if (close(fd) != 0) {
        snprintf(err, errlen, "%s: cannot write: %s", path, strerror(errno));
        (void)unlink(path);
        return -1;
    }
    return 0;
}

int keys_write(const char *base, const keys_pair_t *k, char *err, size_t errlen)
{
    char key_path[4096], pub_path[4096], text[256];
    if ((size_t)snprintf(key_path, sizeof key_path, "%s.key", base) >= sizeof key_path ||
        (size_t)snprintf(pub_path, sizeof pub_path, "%s.pub", base) >= sizeof pub_path) {
        snprintf(err, errlen, "key name too long");
        return -1;
    }
    /* both or neither: refuse before writing anything */
    struct stat st;
    const char *exists = lstat(key_path, &st) == 0   ? key_path
                         : lstat(pub_path, &st) == 0 ? pub_path
                                                     : NULL;
    if (exists) {
        snprintf(err, errlen, "%s exists already: not overwriting a key", exists);
        return -1;
    }
    snprintf(text, sizeof text,
             "# vbrender CURVE key pair (ZeroMQ RFC 26, Z85). Keep it secret: mode 0600.\n"
             "public %s\nsecret %s\n",
             k->public_z85, k->secret_z85);
    int rc = write_new(key_path, 0600, text, err, errlen);
    explicit_bzero(text, sizeof text);
    if (rc < 0)
        return -1;
    snprintf(text, sizeof text, "%s\n", k->public_z85);
    if (write_new(pub_path, 0644, text, err, errlen) < 0) {
        /* both or neither: a key pair left without its .pub is said */
        if (unlink(key_path) != 0) {
            size_t used = strlen(err);
            snprintf(err + used, errlen - used, "; and %s is left (cannot remove it: %s)", key_path,
                     strerror(errno));
        }
        return -1;
    }
    return 0;
}

/* ---- sets ---------------------------------------------------------------------------- */

typedef struct keys_entry {
    char z85[KEYS_Z85_LEN + 1];
    char name[KEYS_NAME_MAX];
} keys_entry_t;

struct keys_set {
    keys_entry_t *entries; /* sorted by z85, no duplicates: bsearch */
    size_t count;
};

static int entry_cmp(const void *a, const void *b)
{
    return strcmp(((const keys_entry_t *)a)->z85, ((const keys_entry_t *)b)->z85);
}

static int has_pub_suffix(const char *name)
{
    size_t n = strlen(name);
    return n > 4 && strcmp(name + n - 4, ".pub") == 0;
}

keys_set_t *keys_set_load_dir(const char *dir, char *err, size_t errlen)
{
    DIR *d = opendir(dir);
    if (!d) {
        snprintf(err, errlen, "%s: cannot open the key directory: %s", dir, strerror(errno));
        return NULL;
    }
    keys_set_t *s = calloc(1, sizeof *s);
    size_t cap = 0;
    if (!s) {
        snprintf(err, errlen, "out of memory");
        closedir(d);
        return NULL;
    }
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.' || !has_pub_suffix(e->d_name))
            continue;
        if (s->count == KEYS_MAX_SET) {
            snprintf(err, errlen, "%s: more than %d keys", dir, KEYS_MAX_SET);
            goto fail;
        }
        if (s->count == cap) {
            size_t ncap = cap ? 2 * cap : 16;
            keys_entry_t *p = realloc(s->entries, ncap * sizeof *p);
            if (!p) {
                snprintf(err, errlen, "out of memory");
                goto fail;
            }
            s->entries = p;
            cap = ncap;
        }
        char path[4096];
        if ((size_t)snprintf(path, sizeof path, "%s/%s", dir, e->d_name) >= sizeof path) {
            snprintf(err, errlen, "%s: path too long", dir);
            goto fail;
        }
        keys_entry_t *k = &s->entries[s->count];
        if (keys_load_public(path, k->z85, err, errlen) < 0)
            goto fail;
        size_t len = strlen(e->d_name) - 4;
        if (len >= KEYS_NAME_MAX)
            len = KEYS_NAME_MAX - 1;
        memcpy(k->name, e->d_name, len);
        k->name[len] = '\0';
        s->count++;
    }
    closedir(d);
    d = NULL;
    if (s->count > 1) {
        qsort(s->entries, s->count, sizeof *s->entries, entry_cmp);
        /* one key in two files: keep the first name in sort order */
        size_t out = 1;
        for (size_t i = 1; i < s->count; i++)
            if (strcmp(s->entries[i].z85, s->entries[out - 1].z85) != 0)
                s->entries[out++] = s->entries[i];
        s->count = out;
    }
    return s;
fail:
    if (d)
        closedir(d);
    keys_set_destroy(&s);
    return NULL;
}

void keys_set_destroy(keys_set_t **sp)
{
    if (!sp || !*sp)
        return;
    free((*sp)->entries);
    free(*sp);
    *sp = NULL;
}

size_t keys_set_count(const keys_set_t *s)
{
    return s ? s->count : 0;
}

static const keys_entry_t *find(const keys_set_t *s, const char *z85)
{
    if (!s || !z85 || !s->count || strlen(z85) != KEYS_Z85_LEN)
        return NULL;
    keys_entry_t probe;
    memcpy(probe.z85, z85, KEYS_Z85_LEN + 1);
    return bsearch(&probe, s->entries, s->count, sizeof *s->entries, entry_cmp);
}

int keys_set_contains(const keys_set_t *s, const char *z85)
{
    return find(s, z85) != NULL;
}

const char *keys_set_name(const keys_set_t *s, const char *z85)
{
    const keys_entry_t *e = find(s, z85);
    return e ? e->name : NULL;
}
