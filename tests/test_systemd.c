/* test_systemd.c - the units in contrib/systemd: `systemd-analyze verify`
 * passes on them, with ExecStart pointing at this build's binaries, and
 * they hold the settings contrib/systemd/README.md promises. Where the
 * machine has no systemd-analyze (it comes with the systemd package, which
 * the build does not need), the verify case prints a SKIPPED line. */
#include <check.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testutil.h"

#define PATHLEN 1024
#define OUTLEN 16384

static const char *const units[] = {"vbrender-master.service", "vbrender-worker@.service"};

static const char *bindir(void)
{
    const char *v = getenv("VB_BINDIR");
    return v && *v ? v : "bin";
}

/* The unit's text (up to len - 1 bytes). */
static const char *unit_text(const char *unit, char *buf, size_t len)
{
    char rel[256], path[PATHLEN];
    snprintf(rel, sizeof rel, "contrib/systemd/%s", unit);
    FILE *f = fopen(tu_root_path(path, sizeof path, rel), "rb");
    ck_assert_msg(f != NULL, "cannot open %s", path);
    size_t n = fread(buf, 1, len - 1, f);
    buf[n] = '\0';
    fclose(f);
    return buf;
}

START_TEST(settings)
{
    static const char *const wanted[] = {"Restart=on-failure",
                                         "KillSignal=SIGTERM",
                                         "TimeoutStopSec=",
                                         "DynamicUser=yes",
                                         "ProtectSystem=strict",
                                         "ProtectHome=yes",
                                         "PrivateTmp=yes",
                                         "NoNewPrivileges=yes",
                                         "RestrictAddressFamilies=AF_INET AF_INET6 AF_UNIX"};
    static char text[OUTLEN];
    for (size_t u = 0; u < 2; u++) {
        unit_text(units[u], text, sizeof text);
        for (size_t i = 0; i < sizeof wanted / sizeof wanted[0]; i++)
            ck_assert_msg(strstr(text, wanted[i]), "%s lacks %s", units[u], wanted[i]);
    }
    unit_text(units[0], text, sizeof text);
    ck_assert_msg(strstr(text, "StateDirectory=vbrender") &&
                      strstr(text, "--state ${STATE_DIRECTORY}"),
                  "the master's --state is not its StateDirectory");
    ck_assert_msg(strstr(text, "ExecReload=/bin/kill -HUP $MAINPID"), "no reload by HUP");
}
END_TEST

START_TEST(verify)
{
    static char out[OUTLEN];
    if (tu_run("command -v systemd-analyze", out, sizeof out) != 0) {
        printf("SKIPPED: systemd-analyze not found: contrib/systemd units not verified\n");
        return;
    }
    /* copies whose ExecStart names this build's binaries (verify checks
     * they exist), and an instance of the worker template */
    char dir[PATHLEN], src[PATHLEN], cmd[8192];
    tu_tmp_path(dir, sizeof dir, "systemd-units");
    tu_root_path(src, sizeof src, "contrib/systemd");
    int n = snprintf(cmd, sizeof cmd,
                     "rm -rf '%s' && mkdir -p '%s' && for u in '%s'/*.service; do "
                     "sed 's#/usr/local/bin/#%s/#' \"$u\" > '%s'/\"$(basename \"$u\")\"; done && "
                     "cp '%s/vbrender-worker@.service' '%s/vbrender-worker@test.service' && "
                     "systemd-analyze verify --man=no '%s/vbrender-master.service' "
                     "'%s/vbrender-worker@.service' '%s/vbrender-worker@test.service'",
                     dir, dir, src, bindir(), dir, dir, dir, dir, dir, dir);
    ck_assert_uint_lt((size_t)n, sizeof cmd);
    int rc = tu_run(cmd, out, sizeof out);
    ck_assert_msg(rc == 0, "systemd-analyze verify: exit %d:\n%s", rc, out);
    /* warnings (an unknown key, say) leave the exit status 0 */
    ck_assert_msg(!strstr(out, "vbrender-"), "systemd-analyze verify warns:\n%s", out);
}
END_TEST

int main(void)
{
    Suite *s = suite_create("systemd");
    TCase *tc = tcase_create("units");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, settings);
    tcase_add_test(tc, verify);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
