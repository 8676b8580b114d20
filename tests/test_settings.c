/* test_settings.c - the table of job settings (common/settings.c): every
 * entry complete and its default within its limits; the client's parser
 * and the master's check taking and refusing the same values at every
 * boundary of every numeric setting (min - 1, min, max, max + 1, and the
 * doubles either side of an open bound), derived from the table so that
 * the test follows it; messages naming the flag or key and the range; the
 * choices known to the scheduler and the scene; the usage lines; the
 * submit row of proto/PROTOCOL.md. */
#include <check.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "defaults.h"
#include "scene.h"
#include "sched.h"
#include "settings.h"
#include "testutil.h"
#include "tracer.h"

/* The master's verdict on {key: value}. */
static int master_takes(const settings_def_t *d, cJSON *value)
{
    cJSON *req = cJSON_CreateObject();
    cJSON_AddItemToObject(req, d->key, value);
    char err[256] = "";
    int ok = settings_check_request(req, err, sizeof err) == 0;
    if (!ok)
        ck_assert_msg(strstr(err, d->key) != NULL, "%s: message \"%s\" lacks the key", d->key, err);
    cJSON_Delete(req);
    return ok;
}

/* The client's verdict on `flag word`; when it takes it, the request it
 * writes must pass the master's check and hold *parsed. */
static int client_takes(const settings_def_t *d, const char *word, double *parsed)
{
    cJSON *req = cJSON_CreateObject();
    char err[256] = "";
    int rc = settings_parse_flag(d->flag, word, req, err, sizeof err);
    ck_assert_msg(rc != -1, "%s not found by its flag", d->flag);
    if (rc >= 0) {
        ck_assert_msg(settings_check_request(req, err, sizeof err) == 0,
                      "%s %s: the client took it, the master refuses: %s", d->flag, word, err);
        *parsed = settings_number(req, d->key, NAN);
    } else {
        ck_assert_msg(strstr(err, d->flag) != NULL, "%s: message \"%s\" lacks the flag", d->flag,
                      err);
    }
    cJSON_Delete(req);
    return rc >= 0;
}

START_TEST(table_consistent)
{
    size_t n;
    const settings_def_t *t = settings_table(&n);
    ck_assert_uint_gt(n, 10);
    for (size_t i = 0; i < n; i++) {
        const settings_def_t *d = &t[i];
        ck_assert_msg(d->flag && strncmp(d->flag, "--", 2) == 0 && d->flag[2], "entry %zu", i);
        ck_assert_msg(d->key && *d->key, "%s has no key", d->flag);
        ck_assert_msg(d->help && *d->help, "%s has no help", d->flag);
        ck_assert_msg((d->metavar != NULL) == (d->type != SETTINGS_SWITCH), "%s metavar", d->flag);
        ck_assert_ptr_eq(settings_find_flag(d->flag), d);
        ck_assert_ptr_eq(settings_find_key(d->key), d);
        if (d->type == SETTINGS_INTEGER || d->type == SETTINGS_NUMBER) {
            ck_assert_msg(d->min < d->max, "%s: min %g, max %g", d->flag, d->min, d->max);
            /* a larger integer is not exact in the JSON the client sends */
            ck_assert_msg(d->type != SETTINGS_INTEGER ||
                              (d->max <= 9007199254740991.0 && d->min == floor(d->min) &&
                               d->max == floor(d->max)),
                          "%s: integer limits", d->flag);
            if (d->default_from == SETTINGS_DEFAULT_VALUE)
                ck_assert_msg(master_takes(d, cJSON_CreateNumber(d->def)),
                              "%s: default %g outside its limits", d->flag, d->def);
        }
        if (d->type == SETTINGS_CHOICE) {
            ck_assert_ptr_nonnull(d->choices);
            ck_assert_ptr_nonnull(d->choices[0]);
            if (d->default_from == SETTINGS_DEFAULT_VALUE)
                ck_assert_msg(d->def_choice && master_takes(d, cJSON_CreateString(d->def_choice)),
                              "%s: default not one of its choices", d->flag);
        }
        ck_assert_msg(d->default_from != SETTINGS_DEFAULT_SCENE || d->def_text,
                      "%s: a default from the scene needs words", d->flag);
    }
}
END_TEST

/* The values either side of each limit, and whether they are allowed. */
static int boundaries(const settings_def_t *d, double v[8], int ok[8])
{
    int k = 0;
    v[k] = d->min - 1, ok[k++] = 0;
    v[k] = d->min, ok[k++] = !d->min_open;
    v[k] = d->max, ok[k++] = 1;
    v[k] = d->max + 1, ok[k++] = 0;
    if (d->type == SETTINGS_NUMBER) {
        v[k] = nextafter(d->min, -INFINITY), ok[k++] = 0;
        v[k] = nextafter(d->min, INFINITY), ok[k++] = 1;
        v[k] = nextafter(d->max, -INFINITY), ok[k++] = 1;
        v[k] = nextafter(d->max, INFINITY), ok[k++] = 0;
    }
    return k;
}

START_TEST(client_and_master_agree_on_boundaries)
{
    size_t n, numeric = 0;
    const settings_def_t *t = settings_table(&n);
    for (size_t i = 0; i < n; i++) {
        const settings_def_t *d = &t[i];
        if (d->type != SETTINGS_INTEGER && d->type != SETTINGS_NUMBER)
            continue;
        numeric++;
        double v[8];
        int ok[8], count = boundaries(d, v, ok);
        for (int k = 0; k < count; k++) {
            char word[64];
            snprintf(word, sizeof word, d->type == SETTINGS_INTEGER ? "%.0f" : "%.17g", v[k]);
            double parsed = NAN;
            int client = client_takes(d, word, &parsed);
            int master = master_takes(d, cJSON_CreateNumber(v[k]));
            ck_assert_msg(client == ok[k] && master == ok[k],
                          "%s %s: want %s, client %s, master %s", d->flag, word,
                          ok[k] ? "taken" : "refused", client ? "takes" : "refuses",
                          master ? "takes" : "refuses");
            if (client)
                ck_assert_msg(parsed == v[k], "%s %s: sent %.17g", d->flag, word, parsed);
        }
    }
    ck_assert_uint_ge(numeric, 9);
}
END_TEST

START_TEST(client_refuses_what_is_no_number)
{
    static const char *const words[] = {"", "abc", "1x", "+1", "-0", "0x10", "1e3", " 1"};
    const settings_def_t *spp = settings_find_flag("--spp");
    for (size_t k = 0; k < sizeof words / sizeof words[0]; k++) {
        double parsed;
        ck_assert_msg(!client_takes(spp, words[k], &parsed), "--spp '%s' taken", words[k]);
    }
    double parsed;
    ck_assert(!client_takes(spp, NULL, &parsed)); /* the flag last, without its value */
    ck_assert(!client_takes(settings_find_flag("--confidence"), "nan", &parsed));
    ck_assert(!client_takes(settings_find_flag("--time-limit"), "inf", &parsed));
}
END_TEST

START_TEST(messages_name_the_range)
{
    cJSON *req = cJSON_Parse("{\"uniform_layers\": 4294967294}");
    char err[256];
    ck_assert_int_eq(settings_check_request(req, err, sizeof err), -1);
    ck_assert_str_eq(err, "uniform_layers must be an integer from 0 to 1000000");
    cJSON_Delete(req);
    req = cJSON_Parse("{\"confidence\": 1}");
    ck_assert_int_eq(settings_check_request(req, err, sizeof err), -1);
    ck_assert_str_eq(err, "confidence must be a number in (0, 0.999999]");
    cJSON_Delete(req);
    req = cJSON_Parse("{\"adaptive\": \"fast\"}");
    ck_assert_int_eq(settings_check_request(req, err, sizeof err), -1);
    ck_assert_str_eq(
        err, "adaptive must be \"relmse\", \"relerr\", \"thesis\", \"variance\" or \"none\"");
    cJSON_Delete(req);
    req = cJSON_CreateObject();
    ck_assert_int_eq(settings_parse_flag("--granularity", "4097", req, err, sizeof err), -2);
    ck_assert_str_eq(err, "--granularity must be an integer from 1 to 4096 (got '4097')");
    ck_assert_int_eq(settings_parse_flag("--workers", "2", req, err, sizeof err), -1);
    ck_assert_ptr_null(req->child);
    cJSON_Delete(req);
}
END_TEST

START_TEST(other_types)
{
    cJSON *req = cJSON_CreateObject();
    char err[256];
    ck_assert_int_eq(settings_parse_flag("--dilate", "--spp", req, err, sizeof err), 0);
    ck_assert_int_eq(settings_parse_flag("--flags", "0011", req, err, sizeof err), 1);
    ck_assert_int_eq(settings_parse_flag("--flags", "0021", req, err, sizeof err), -2);
    ck_assert_int_eq(settings_parse_flag("--adaptive", "relerr", req, err, sizeof err), 1);
    ck_assert_int_eq(settings_parse_flag("--spp", "8", req, err, sizeof err), 1);
    ck_assert_int_eq(settings_parse_flag("--spp", "16", req, err, sizeof err), 1);
    ck_assert_int_eq(settings_check_request(req, err, sizeof err), 0);
    ck_assert(settings_switch(req, "dilate"));
    ck_assert(!settings_switch(req, "random_selection"));
    ck_assert_str_eq(settings_string(req, "flags", NULL), "0011");
    ck_assert_str_eq(settings_string(req, "adaptive", NULL), "relerr");
    ck_assert(settings_number(req, "spp", 0) == 16); /* the last one given */
    ck_assert(settings_number(req, "seed", 7) == 7);
    cJSON_Delete(req);
    static const char *const refused[] = {"{\"dilate\": 1}", "{\"flags\": \"\"}",
                                          "{\"flags\": 11}", "{\"integrator\": \"fast\"}",
                                          "{\"spp\": 2.5}",  "{\"time_limit\": \"9\"}"};
    for (size_t k = 0; k < sizeof refused / sizeof refused[0]; k++) {
        req = cJSON_Parse(refused[k]);
        ck_assert_msg(settings_check_request(req, err, sizeof err) == -1, "%s taken", refused[k]);
        cJSON_Delete(req);
    }
}
END_TEST

/* The table's choices are the names the scheduler and the scene know, the
 * master's submit maps them with those functions. */
START_TEST(choices_known)
{
    const settings_def_t *a = settings_find_key("adaptive"), *in = settings_find_key("integrator");
    int count = 0, seen = 0;
    for (int k = 0; a->choices[k]; k++, count++) {
        int mode = sched_adaptive_from_name(a->choices[k]);
        ck_assert_msg(mode >= 0 && !(seen & 1 << mode), "%s", a->choices[k]);
        seen |= 1 << mode;
    }
    ck_assert_int_eq(count, SCHED_ADAPTIVE_RELMSE + 1); /* every mode the scheduler has */
    ck_assert_int_ge(sched_adaptive_from_name(JOB_DEFAULT_ADAPTIVE), 0);
    for (int k = 0; in->choices[k]; k++)
        ck_assert_int_ge(scene_integrator_from_name(in->choices[k]), 0);
    ck_assert_str_eq(scene_integrator_name(SCENE_INTEGRATOR_PATH), "path");
    ck_assert_str_eq(scene_integrator_name(SCENE_INTEGRATOR_NAIVE), "naive");
    const settings_def_t *sm = settings_find_key("sampler");
    for (int k = 0; sm->choices[k]; k++) {
        int v = tracer_sampler_from_name(sm->choices[k]);
        ck_assert_int_ge(v, 0);
        ck_assert_str_eq(tracer_sampler_name((rng_sampler_t)v), sm->choices[k]);
    }
    ck_assert_int_eq(tracer_sampler_from_name(JOB_DEFAULT_SAMPLER), RNG_SAMPLER_SOBOL);
    ck_assert_int_eq(tracer_sampler_from_name("halton"), -1);
}
END_TEST

START_TEST(usage_lines)
{
    char *text = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&text, &len);
    ck_assert_ptr_nonnull(f);
    settings_usage(f);
    fclose(f);
    size_t n;
    const settings_def_t *t = settings_table(&n);
    for (size_t i = 0; i < n; i++) {
        char line[64];
        snprintf(line, sizeof line, "\n  %s", t[i].flag);
        ck_assert_msg(strstr(text, line + (i == 0)) != NULL, "%s missing", t[i].flag);
        char help[128];
        snprintf(help, sizeof help, "%.*s", (int)strcspn(t[i].help, "\n"), t[i].help);
        ck_assert_msg(strstr(text, help) != NULL, "%s's help missing", t[i].flag);
    }
    ck_assert_ptr_nonnull(strstr(text, "--granularity G         samples per pixel per layer "
                                       "(default " DEFAULTS_STR(JOB_DEFAULT_GRANULARITY) ")\n"));
    for (char *p = text, *nl; (nl = strchr(p, '\n')) != NULL; p = nl + 1)
        ck_assert_msg(nl - p <= 88, "line too long: %.*s", (int)(nl - p), p);
    free(text);
}
END_TEST

/* proto/PROTOCOL.md's submit row lists every setting with what it takes,
 * in the words of settings_describe. */
START_TEST(protocol_row_matches)
{
    char path[1024];
    FILE *f = fopen(tu_root_path(path, sizeof path, "proto/PROTOCOL.md"), "r");
    ck_assert_msg(f != NULL, "cannot open %s", path);
    static char line[16384];
    const char *row = NULL;
    while (!row && fgets(line, sizeof line, f))
        if (strncmp(line, "| `submit` |", 12) == 0)
            row = line;
    fclose(f);
    ck_assert_msg(row != NULL, "no submit row in %s", path);
    size_t n;
    const settings_def_t *t = settings_table(&n);
    for (size_t i = 0; i < n; i++) {
        char want[256], allowed[160];
        settings_describe(&t[i], 1, allowed, sizeof allowed);
        snprintf(want, sizeof want, "`%s`: %s", t[i].key, allowed);
        ck_assert_msg(strstr(row, want) != NULL, "the submit row lacks \"%s\"", want);
    }
}
END_TEST

static Suite *settings_suite(void)
{
    Suite *s = suite_create("settings");
    TCase *tc = tcase_create("settings");
    tcase_add_test(tc, table_consistent);
    tcase_add_test(tc, client_and_master_agree_on_boundaries);
    tcase_add_test(tc, client_refuses_what_is_no_number);
    tcase_add_test(tc, messages_name_the_range);
    tcase_add_test(tc, other_types);
    tcase_add_test(tc, choices_known);
    tcase_add_test(tc, usage_lines);
    tcase_add_test(tc, protocol_row_matches);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(settings_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
