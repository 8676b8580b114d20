/* keys.h - CURVE key pairs (ZeroMQ RFC 26) and allow-lists of public keys,
 * as files.
 *
 *   NAME.key  the key pair, mode 0600 (refused when group or others may
 *             read it, as ssh refuses an unprotected private key):
 *                 # comment lines and blank lines are ignored
 *                 public <40 Z85 characters>
 *                 secret <40 Z85 characters>
 *             the public key must be the one the secret key gives.
 *   NAME.pub  the public key alone: 40 Z85 characters on one line (no
 *             comments: '#' is a Z85 character).
 *   a directory of .pub files is an allow-list; other files in it (a
 *   README, a .key kept beside its .pub) are skipped, and NAME names the
 *   key in log lines.
 *
 * Keys travel as Z85 text (40 characters, what ZeroMQ's CURVE options and
 * a ZAP handler's User-Id take). The one module of the core that uses
 * libzmq: zmq_curve_keypair, zmq_curve_public and the Z85 codec.
 */
#ifndef VB_KEYS_H
#define VB_KEYS_H

#include <stddef.h>

#define KEYS_Z85_LEN 40     /* a key as Z85 text, without the terminator */
#define KEYS_MAX_FILE 4096  /* a .key or .pub file longer than this is not one */
#define KEYS_MAX_SET 100000 /* keys in one allow-list directory */
#define KEYS_NAME_MAX 64    /* a key's name (its file name less .pub), terminator included */

typedef struct keys_pair {
    char public_z85[KEYS_Z85_LEN + 1];
    char secret_z85[KEYS_Z85_LEN + 1];
} keys_pair_t;

/* A fresh key pair. -1 with a message (libzmq without CURVE). */
int keys_generate(keys_pair_t *out, char *err, size_t errlen);

/* Writes BASE.key (mode 0600) and BASE.pub; refuses to overwrite either. */
int keys_write(const char *base, const keys_pair_t *k, char *err, size_t errlen);

/* Loads a .key file: refuses one that group or others may read (naming the
 * file and its mode), one that is not a regular file, a malformed one and
 * one whose public key does not match its secret key. */
int keys_load_secret(const char *path, keys_pair_t *out, char *err, size_t errlen);

/* Loads a .pub file into out (Z85, terminated). */
int keys_load_public(const char *path, char out[KEYS_Z85_LEN + 1], char *err, size_t errlen);

/* Whether text is exactly a Z85 key: 40 characters of the Z85 alphabet. */
int keys_valid_z85(const char *text);

/* A set of public keys: an allow-list. */
typedef struct keys_set keys_set_t;

/* Every NAME.pub in dir (hidden files and other names skipped; an empty
 * directory gives an empty set). A .pub file that is not a key fails the
 * whole load, naming it: a typo must not lock someone out silently. */
keys_set_t *keys_set_load_dir(const char *dir, char *err, size_t errlen);
void keys_set_destroy(keys_set_t **s);

size_t keys_set_count(const keys_set_t *s);
/* Whether the Z85 key is in the set (NULL set or key: no). */
int keys_set_contains(const keys_set_t *s, const char *z85);
/* The name of the key's file (without .pub), or NULL when not in the set. */
const char *keys_set_name(const keys_set_t *s, const char *z85);

#endif
