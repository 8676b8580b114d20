/* settings.c - the table of a job's settings and what is driven from it
 * (settings.h). The client's parser turns a flag's word into the JSON value
 * the request carries and then checks that value with the master's own
 * check, so a value the client lets through is one the master takes. */
#include "settings.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "defaults.h"
#include "tracer.h"

/* The names sched_adaptive_from_name and scene_integrator_from_name take
 * (tests/test_settings.c checks that they do). */
static const char *const adaptive_choices[] = {"relmse",   "relerr", "thesis",
                                               "variance", "none",   NULL};
static const char *const integrator_choices[] = {"path", "naive", "direct", NULL};
/* tracer_sampler_from_name's names */
static const char *const sampler_choices[] = {"sobol", "independent", NULL};

/* Limits: where the client and the master used to differ, the tighter of
 * the two. A seed stops at 2^53 - 1, the largest integer a JSON number
 * holds with its successor still distinct, so that the client (reading
 * digits) and the master (reading a double) refuse the same values. */
static const settings_def_t table[] = {
    {.flag = "--spp",
     .key = "spp",
     .metavar = "N",
     .type = SETTINGS_INTEGER,
     .min = 1,
     .max = 4294967295.0,
     .default_from = SETTINGS_DEFAULT_SCENE,
     .def_text = "the scene's",
     .help = "most samples per pixel"},
    {.flag = "--granularity",
     .key = "granularity",
     .metavar = "G",
     .type = SETTINGS_INTEGER,
     .min = 1,
     .max = TRACER_MAX_TASK_SAMPLES,
     .def = JOB_DEFAULT_GRANULARITY,
     .help = "samples per pixel per layer"},
    {.flag = "--adaptive",
     .key = "adaptive",
     .metavar = "MODE",
     .type = SETTINGS_CHOICE,
     .choices = adaptive_choices,
     .def_choice = JOB_DEFAULT_ADAPTIVE,
     .help = "relmse (the relMSE one more layer takes off\n"
             "per ray it costs),\n"
             "relerr (t-bound of layer means over mean),\n"
             "thesis (eq. 4.1, as published), variance (of the\n"
             "pixel mean) or none (uniform)"},
    {.flag = "--random-selection",
     .key = "random_selection",
     .type = SETTINGS_SWITCH,
     .help = "pixels below the threshold still run with probability m/T"},
    {.flag = "--dilate",
     .key = "dilate",
     .type = SETTINGS_SWITCH,
     .help = "also sample the neighbours of selected pixels"},
    {.flag = "--target-error",
     .key = "target_error",
     .metavar = "E",
     .type = SETTINGS_NUMBER,
     .min = 0,
     .max = 1e6,
     .min_open = 1,
     .default_from = SETTINGS_DEFAULT_OTHER,
     .def = JOB_DEFAULT_TARGET_ERROR,
     .def_text = "none",
     .help = "stop a pixel when its confidence half-width\n"
             "<= E x mean, from the error its neighbours'\n"
             "replicates give (the EXR's variance; with\n"
             "--replicates 1, their layers' spread, larger).\n"
             "Light that no path has found yet\n"
             "(a pixel seen only by rare paths) looks converged:\n"
             "no rule can vouch for it. Every pixel short of E\n"
             "takes every layer (--adaptive's skip rule is off).\n"
             "The summary counts the pixels the rule stopped and\n"
             "those that ran to --spp"},
    {.flag = "--confidence",
     .key = "confidence",
     .metavar = "C",
     .type = SETTINGS_NUMBER,
     .min = 0,
     .max = 0.999999,
     .min_open = 1,
     .def = JOB_DEFAULT_CONFIDENCE,
     .help = "the confidence of that half-width"},
    {.flag = "--target-share",
     .key = "target_share",
     .metavar = "S",
     .type = SETTINGS_NUMBER,
     .min = 0,
     .max = 1,
     .min_open = 1,
     .def = JOB_DEFAULT_TARGET_SHARE,
     .help = "the job stops when a share S of the pixels\nhave met --target-error"},
    {.flag = "--uniform-layers",
     .key = "uniform_layers",
     .metavar = "K",
     .type = SETTINGS_INTEGER,
     .min = 0,
     .max = 1000000,
     .default_from = SETTINGS_DEFAULT_OTHER,
     .def_text = "8, or half if fewer; thesis: half",
     .help = "layers before the skip rule applies"},
    {.flag = "--flags",
     .key = "flags",
     .metavar = "0011...",
     .type = SETTINGS_BITS,
     .default_from = SETTINGS_DEFAULT_OTHER,
     .help = "the thesis's flag sequence: 1 where a layer applies the\n"
             "skip rule, one per layer (overrides --uniform-layers)"},
    {.flag = "--seed",
     .key = "seed",
     .metavar = "S",
     .type = SETTINGS_INTEGER,
     .min = 0,
     .max = 9007199254740991.0,
     .default_from = SETTINGS_DEFAULT_SCENE,
     .def_text = "the scene's",
     .help = "random seed"},
    {.flag = "--time-limit",
     .key = "time_limit",
     .metavar = "SECONDS",
     .type = SETTINGS_NUMBER,
     .min = 0,
     .max = 1e9,
     .min_open = 1,
     .default_from = SETTINGS_DEFAULT_OTHER,
     .def = JOB_DEFAULT_TIME_LIMIT,
     .def_text = "none",
     .help = "stop issuing work after this long"},
    {.flag = "--integrator",
     .key = "integrator",
     .metavar = "path|naive|direct",
     .type = SETTINGS_CHOICE,
     .choices = integrator_choices,
     .default_from = SETTINGS_DEFAULT_SCENE,
     .def_text = "the scene's",
     .help = "path: NEE + MIS; naive: hits only; direct: 1 bounce"},
    {.flag = "--max-depth",
     .key = "max_depth",
     .metavar = "D",
     .type = SETTINGS_INTEGER,
     .min = 0,
     .max = 1000000,
     .default_from = SETTINGS_DEFAULT_SCENE,
     .def_text = "the scene's",
     .help = "most path segments, 0: unlimited"},
    {.flag = "--sampler",
     .key = "sampler",
     .metavar = "sobol|independent",
     .type = SETTINGS_CHOICE,
     .choices = sampler_choices,
     .def_choice = JOB_DEFAULT_SAMPLER,
     .help = "sobol: Owen-scrambled Sobol, one sequence per pixel;\n"
             "independent: hashed random numbers"},
    {.flag = "--replicates",
     .key = "replicates",
     .metavar = "R",
     .type = SETTINGS_INTEGER,
     .min = 1,
     .max = RNG_MAX_REPLICATES,
     .def = JOB_DEFAULT_REPLICATES,
     .help = "sobol: a pixel's layers go to R independently\n"
             "scrambled sequences in turn, whose spread calibrates\n"
             "the EXR variance channel (1: one sequence, the\n"
             "channel then overstates the error 10-50x)"},
};

#define TABLE_LEN (sizeof table / sizeof table[0])

const settings_def_t *settings_table(size_t *count)
{
    *count = TABLE_LEN;
    return table;
}

const settings_def_t *settings_find_flag(const char *flag)
{
    for (size_t i = 0; i < TABLE_LEN; i++)
        if (strcmp(table[i].flag, flag) == 0)
            return &table[i];
    return NULL;
}

const settings_def_t *settings_find_key(const char *key)
{
    for (size_t i = 0; i < TABLE_LEN; i++)
        if (strcmp(table[i].key, key) == 0)
            return &table[i];
    return NULL;
}

static int choice_index(const settings_def_t *d, const char *name)
{
    for (int i = 0; d->choices[i]; i++)
        if (strcmp(d->choices[i], name) == 0)
            return i;
    return -1;
}

/* The one check of a value, for the client's and the master's. */
static int value_ok(const settings_def_t *d, const cJSON *v)
{
    switch (d->type) {
    case SETTINGS_INTEGER:
    case SETTINGS_NUMBER: {
        double x = cJSON_IsNumber(v) ? v->valuedouble : NAN;
        if (!(x >= d->min && x <= d->max) || (d->min_open && x == d->min))
            return 0;
        return d->type == SETTINGS_NUMBER || x == floor(x);
    }
    case SETTINGS_CHOICE:
        return cJSON_IsString(v) && choice_index(d, v->valuestring) >= 0;
    case SETTINGS_SWITCH:
        return cJSON_IsBool(v);
    case SETTINGS_BITS:
        return cJSON_IsString(v) && v->valuestring[0] &&
               strspn(v->valuestring, "01") == strlen(v->valuestring);
    }
    return 0;
}

void settings_describe(const settings_def_t *d, int quote, char *buf, size_t len)
{
    const char *q = quote ? "\"" : "";
    size_t n = 0;
    switch (d->type) {
    case SETTINGS_INTEGER:
        snprintf(buf, len, "an integer from %.0f to %.0f", d->min, d->max);
        break;
    case SETTINGS_NUMBER:
        snprintf(buf, len, "a number in %s%.15g, %.15g]", d->min_open ? "(" : "[", d->min, d->max);
        break;
    case SETTINGS_CHOICE:
        buf[0] = '\0';
        for (int i = 0; d->choices[i] && n < len; i++) {
            const char *sep = i == 0 ? "" : d->choices[i + 1] ? ", " : " or ";
            int w = snprintf(buf + n, len - n, "%s%s%s%s", sep, q, d->choices[i], q);
            n += w > 0 ? (size_t)w : 0;
        }
        break;
    case SETTINGS_SWITCH:
        snprintf(buf, len, "true or false");
        break;
    case SETTINGS_BITS:
        snprintf(buf, len, "a sequence of 0 and 1, one per layer");
        break;
    }
}

/* The JSON value of a flag's word, by syntax only (value_ok checks the
 * rest); NULL if the word is not one. Integers are read as digits, so
 * "1e3", "0x10" and "-0" are refused as they were. */
static cJSON *value_from_word(const settings_def_t *d, const char *word)
{
    if (d->type == SETTINGS_SWITCH)
        return cJSON_CreateTrue();
    if (!word || !*word)
        return NULL;
    char *end;
    errno = 0;
    if (d->type == SETTINGS_INTEGER) {
        if (word[0] < '0' || word[0] > '9')
            return NULL;
        unsigned long long v = strtoull(word, &end, 10);
        return errno || *end ? NULL : cJSON_CreateNumber((double)v);
    }
    if (d->type == SETTINGS_NUMBER) {
        /* out of range (ERANGE) is left to value_ok, as the master would see it */
        double v = strtod(word, &end);
        return *end ? NULL : cJSON_CreateNumber(v);
    }
    return cJSON_CreateString(word);
}

int settings_parse_flag(const char *flag, const char *value, cJSON *request, char *err,
                        size_t errlen)
{
    const settings_def_t *d = settings_find_flag(flag);
    if (!d)
        return -1;
    cJSON *v = value_from_word(d, value);
    if (!v || !value_ok(d, v)) {
        cJSON_Delete(v);
        char allowed[160];
        settings_describe(d, 0, allowed, sizeof allowed);
        snprintf(err, errlen, "%s must be %s (got '%s')", flag, allowed, value ? value : "");
        return -2;
    }
    cJSON_DeleteItemFromObjectCaseSensitive(request, d->key); /* the last one given counts */
    cJSON_AddItemToObject(request, d->key, v);
    return d->type == SETTINGS_SWITCH ? 0 : 1;
}

int settings_check_request(const cJSON *request, char *err, size_t errlen)
{
    for (size_t i = 0; i < TABLE_LEN; i++) {
        const cJSON *v = cJSON_GetObjectItemCaseSensitive(request, table[i].key);
        if (v && !value_ok(&table[i], v)) {
            char allowed[160];
            settings_describe(&table[i], 1, allowed, sizeof allowed);
            snprintf(err, errlen, "%s must be %s", table[i].key, allowed);
            return -1;
        }
    }
    return 0;
}

double settings_number(const cJSON *request, const char *key, double fallback)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(request, key);
    return cJSON_IsNumber(v) ? v->valuedouble : fallback;
}

const char *settings_string(const cJSON *request, const char *key, const char *fallback)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(request, key);
    return cJSON_IsString(v) ? v->valuestring : fallback;
}

int settings_switch(const cJSON *request, const char *key)
{
    return cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(request, key));
}

/* The words a setting's usage line ends with: " (default 32)"; "" for none. */
static void default_words(const settings_def_t *d, char *buf, size_t len)
{
    if (d->def_text)
        snprintf(buf, len, " (default: %s)", d->def_text);
    else if (d->type == SETTINGS_CHOICE && d->def_choice)
        snprintf(buf, len, " (default %s)", d->def_choice);
    else if (d->default_from == SETTINGS_DEFAULT_VALUE &&
             (d->type == SETTINGS_INTEGER || d->type == SETTINGS_NUMBER))
        snprintf(buf, len, " (default %g)", d->def);
    else
        buf[0] = '\0';
}

void settings_usage(FILE *f)
{
    enum { HELP_COLUMN = 26, WIDTH = 88 };
    for (size_t i = 0; i < TABLE_LEN; i++) {
        const settings_def_t *d = &table[i];
        char left[64], def[96];
        snprintf(left, sizeof left, "%s%s%s", d->flag, d->metavar ? " " : "",
                 d->metavar ? d->metavar : "");
        fprintf(f, "  %-*s ", HELP_COLUMN - 3, left);
        const char *p = d->help, *nl;
        for (; (nl = strchr(p, '\n')) != NULL; p = nl + 1)
            fprintf(f, "%.*s\n%*s", (int)(nl - p), p, HELP_COLUMN, "");
        default_words(d, def, sizeof def);
        /* the default on a line of its own where the last one would grow too long */
        if (HELP_COLUMN + strlen(p) + strlen(def) > WIDTH)
            fprintf(f, "%s\n%*s%s\n", p, HELP_COLUMN - 1, "", def);
        else
            fprintf(f, "%s%s\n", p, def);
    }
}
