/* settings.h - a job's settings, written once: one table of every setting
 * a client may give a job (its command-line flag, its key in the submit
 * request's JSON, its type, limits, default and help), and the functions
 * that drive from it the client's parser and usage text and the master's
 * validation, so that the two cannot disagree on what is allowed.
 *
 * The master's daemon limits (--max-spp, --max-pixels) apply on top of the
 * table's (master/submit.c). Pure functions over a const table: no state,
 * safe from any thread. */
#ifndef VB_SETTINGS_H
#define VB_SETTINGS_H

#include <stddef.h>
#include <stdio.h>

#include <cJSON.h>

typedef enum settings_type {
    SETTINGS_INTEGER, /* a whole number in [min, max] (exact in a JSON double: max <= 2^53) */
    SETTINGS_NUMBER,  /* a finite number in [min, max], or (min, max] with min_open */
    SETTINGS_CHOICE,  /* one of choices[] */
    SETTINGS_SWITCH,  /* a flag without a value; true in the JSON (false: as if absent) */
    SETTINGS_BITS     /* a non-empty string of 0 and 1 */
} settings_type_t;

/* Where a setting's default comes from when the request leaves it out. */
typedef enum settings_default {
    SETTINGS_DEFAULT_VALUE, /* def (or def_choice for a CHOICE) */
    SETTINGS_DEFAULT_SCENE, /* the scene's "render" block (scene.h) */
    SETTINGS_DEFAULT_OTHER  /* worked out by the master; def_text says how */
} settings_default_t;

typedef struct settings_def {
    const char *flag;    /* "--spp" */
    const char *key;     /* "spp", in the submit request */
    const char *metavar; /* "N" in "--spp N"; NULL for a SWITCH */
    settings_type_t type;
    double min, max;            /* INTEGER, NUMBER */
    int min_open;               /* NUMBER: min itself is refused */
    const char *const *choices; /* CHOICE: NULL-terminated */
    settings_default_t default_from;
    double def;             /* INTEGER, NUMBER with SETTINGS_DEFAULT_VALUE */
    const char *def_choice; /* CHOICE with SETTINGS_DEFAULT_VALUE */
    const char *def_text;   /* the usage text's words for a default that is not a value */
    const char *help;       /* usage text; '\n' starts a continuation line */
} settings_def_t;

/* The table, and its length. */
const settings_def_t *settings_table(size_t *count);

/* The table's entry for a flag ("--spp") or a JSON key ("spp"); NULL if none. */
const settings_def_t *settings_find_flag(const char *flag);
const settings_def_t *settings_find_key(const char *key);

/* Client: if flag is a setting, checks its value (argv's next word, NULL
 * at the end) and adds it to request under the setting's key. Returns the
 * number of words used besides the flag (0 for a SWITCH, else 1), -1 if
 * flag is no setting (nothing written), or -2 with a message that names
 * the flag and the allowed values. */
int settings_parse_flag(const char *flag, const char *value, cJSON *request, char *err,
                        size_t errlen);

/* Master: checks every setting present in request (other keys are not
 * looked at). 0, or -1 with a message that names the key and the allowed
 * range. */
int settings_check_request(const cJSON *request, char *err, size_t errlen);

/* What a setting takes, in words, as the messages say it: "an integer
 * from 1 to 4096", "a number in (0, 1]", "thesis, variance, relerr or
 * none" (with quote: each choice in double quotes, as in JSON). */
void settings_describe(const settings_def_t *d, int quote, char *buf, size_t len);

/* The value of a (checked) setting in request, or fallback when absent. */
double settings_number(const cJSON *request, const char *key, double fallback);
const char *settings_string(const cJSON *request, const char *key, const char *fallback);
int settings_switch(const cJSON *request, const char *key);

/* Writes the usage lines of every setting to f, one flag per line with
 * its help from column 27 and its default, as "  --spp N ... (default: the
 * scene's)". */
void settings_usage(FILE *f);

#endif
