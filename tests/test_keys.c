/* test_keys.c - CURVE key files (common/keys.c): a generated pair written
 * and read back, a secret key others may read refused by name and mode,
 * keys that are not Z85 (or not 40 characters, or overflow a group)
 * refused, a pair whose halves do not match refused, keygen never
 * overwriting, and a directory of .pub files loaded as an allow-list with
 * other files skipped and a bad .pub failing the load by name. */
#include <check.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "keys.h"
#include "testutil.h"

#define PATHLEN 1024

/* A fresh scratch directory for this test. */
static const char *scratch_dir(char *buf, size_t len, const char *name)
{
    char file[128], cmd[PATHLEN + 32], out[256];
    snprintf(file, sizeof file, "keys-%ld-%s", (long)getpid(), name);
    tu_tmp_path(buf, len, file);
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", buf);
    tu_run(cmd, out, sizeof out);
    ck_assert_int_eq(mkdir(buf, 0700), 0);
    return buf;
}

static void remove_dir(const char *dir)
{
    char cmd[PATHLEN + 32], out[256];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    tu_run(cmd, out, sizeof out);
}

static void write_file(const char *path, const char *text, mode_t mode)
{
    FILE *f = fopen(path, "w");
    ck_assert_msg(f != NULL, "cannot write %s", path);
    fputs(text, f);
    fclose(f);
    ck_assert_int_eq(chmod(path, mode), 0);
}

START_TEST(test_round_trip)
{
    char dir[512], base[PATHLEN], path[PATHLEN + 8], err[1024], pub[KEYS_Z85_LEN + 1];
    scratch_dir(dir, sizeof dir, "rt");
    snprintf(base, sizeof base, "%s/alice", dir);
    keys_pair_t k, back;
    ck_assert_int_eq(keys_generate(&k, err, sizeof err), 0);
    ck_assert(keys_valid_z85(k.public_z85));
    ck_assert(keys_valid_z85(k.secret_z85));
    ck_assert_str_ne(k.public_z85, k.secret_z85);
    ck_assert_msg(keys_write(base, &k, err, sizeof err) == 0, "%s", err);

    struct stat st;
    snprintf(path, sizeof path, "%s.key", base);
    ck_assert_int_eq(stat(path, &st), 0);
    ck_assert_uint_eq(st.st_mode & 0777, 0600);
    ck_assert_msg(keys_load_secret(path, &back, err, sizeof err) == 0, "%s", err);
    ck_assert_str_eq(back.public_z85, k.public_z85);
    ck_assert_str_eq(back.secret_z85, k.secret_z85);

    snprintf(path, sizeof path, "%s.pub", base);
    ck_assert_msg(keys_load_public(path, pub, err, sizeof err) == 0, "%s", err);
    ck_assert_str_eq(pub, k.public_z85);
    /* the secret key appears in the .key file only */
    FILE *f = fopen(path, "r");
    char text[256] = "";
    ck_assert_ptr_nonnull(fgets(text, sizeof text, f));
    fclose(f);
    ck_assert_ptr_null(strstr(text, k.secret_z85));

    /* two pairs differ */
    keys_pair_t k2;
    ck_assert_int_eq(keys_generate(&k2, err, sizeof err), 0);
    ck_assert_str_ne(k2.public_z85, k.public_z85);

    /* never overwritten: neither file changes */
    ck_assert_int_eq(keys_write(base, &k2, err, sizeof err), -1);
    ck_assert_ptr_nonnull(strstr(err, "exists already"));
    snprintf(path, sizeof path, "%s.key", base);
    ck_assert_int_eq(keys_load_secret(path, &back, err, sizeof err), 0);
    ck_assert_str_eq(back.public_z85, k.public_z85);
    /* nor when only the .pub is there */
    snprintf(path, sizeof path, "%s/bob.pub", dir);
    write_file(path, "x\n", 0644);
    snprintf(base, sizeof base, "%s/bob", dir);
    ck_assert_int_eq(keys_write(base, &k2, err, sizeof err), -1);
    snprintf(path, sizeof path, "%s/bob.key", dir);
    ck_assert_int_eq(access(path, F_OK), -1);
    remove_dir(dir);
}
END_TEST

START_TEST(test_mode_refused)
{
    char dir[512], base[PATHLEN], path[PATHLEN + 8], err[1024];
    scratch_dir(dir, sizeof dir, "mode");
    snprintf(base, sizeof base, "%s/k", dir);
    keys_pair_t k, back;
    ck_assert_int_eq(keys_generate(&k, err, sizeof err), 0);
    ck_assert_int_eq(keys_write(base, &k, err, sizeof err), 0);
    snprintf(path, sizeof path, "%s.key", base);
    static const mode_t bad[] = {0644, 0640, 0604, 0660, 0602, 0620, 0666};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        ck_assert_int_eq(chmod(path, bad[i]), 0);
        ck_assert_int_eq(keys_load_secret(path, &back, err, sizeof err), -1);
        char mode[16];
        snprintf(mode, sizeof mode, "0%03o", (unsigned)bad[i]);
        ck_assert_msg(strstr(err, path) && strstr(err, mode) && strstr(err, "too open"),
                      "mode %s: %s", mode, err);
        /* nothing of the key is handed out */
        ck_assert_str_eq(back.secret_z85, "");
    }
    ck_assert_int_eq(chmod(path, 0400), 0);
    ck_assert_msg(keys_load_secret(path, &back, err, sizeof err) == 0, "%s", err);
    /* a directory is not a key file */
    ck_assert_int_eq(keys_load_secret(dir, &back, err, sizeof err), -1);
    ck_assert_ptr_nonnull(strstr(err, "not a regular file"));
    /* a missing one is named */
    snprintf(path, sizeof path, "%s/none.key", dir);
    ck_assert_int_eq(keys_load_secret(path, &back, err, sizeof err), -1);
    ck_assert_ptr_nonnull(strstr(err, path));
    remove_dir(dir);
}
END_TEST

START_TEST(test_bad_z85)
{
    char err[1024], dir[512], path[PATHLEN + 16], text[512], pub[KEYS_Z85_LEN + 1];
    keys_pair_t k, other, back;
    ck_assert_int_eq(keys_generate(&k, err, sizeof err), 0);
    ck_assert_int_eq(keys_generate(&other, err, sizeof err), 0);
    ck_assert(!keys_valid_z85(NULL));
    ck_assert(!keys_valid_z85(""));
    char s[64];
    snprintf(s, sizeof s, "%.39s", k.public_z85); /* 39 characters */
    ck_assert(!keys_valid_z85(s));
    snprintf(s, sizeof s, "%s0", k.public_z85); /* 41 */
    ck_assert(!keys_valid_z85(s));
    snprintf(s, sizeof s, "%s", k.public_z85);
    s[7] = ' '; /* not in the alphabet */
    ck_assert(!keys_valid_z85(s));
    s[7] = '"';
    ck_assert(!keys_valid_z85(s));
    /* every character of the alphabet, but "#####" is over 2^32 */
    ck_assert(!keys_valid_z85("########################################"));
    ck_assert(keys_valid_z85("0000000000000000000000000000000000000000"));

    scratch_dir(dir, sizeof dir, "z85");
    /* .pub files */
    static const char *const bad_pub[] = {"", "\n", "short\n",
                                          "########################################\n"};
    for (size_t i = 0; i < sizeof bad_pub / sizeof bad_pub[0]; i++) {
        snprintf(path, sizeof path, "%s/bad%zu.pub", dir, i);
        write_file(path, bad_pub[i], 0644);
        ck_assert_int_eq(keys_load_public(path, pub, err, sizeof err), -1);
        ck_assert_msg(strstr(err, path) != NULL, "%s", err);
    }
    snprintf(path, sizeof path, "%s/two.pub", dir);
    snprintf(text, sizeof text, "%s\n%s\n", k.public_z85, other.public_z85);
    write_file(path, text, 0644);
    ck_assert_int_eq(keys_load_public(path, pub, err, sizeof err), -1);
    /* a missing newline and a CR LF are fine */
    snprintf(path, sizeof path, "%s/crlf.pub", dir);
    snprintf(text, sizeof text, "%s\r\n", k.public_z85);
    write_file(path, text, 0644);
    ck_assert_msg(keys_load_public(path, pub, err, sizeof err) == 0, "%s", err);
    ck_assert_str_eq(pub, k.public_z85);
    snprintf(text, sizeof text, "%s", k.public_z85);
    write_file(path, text, 0644);
    ck_assert_int_eq(keys_load_public(path, pub, err, sizeof err), 0);

    /* .key files */
    struct {
        const char *what;
        char text[512];
    } cases[6];
    snprintf(cases[0].text, sizeof cases[0].text, "public %s\n", k.public_z85);
    cases[0].what = "not a key pair file";
    snprintf(cases[1].text, sizeof cases[1].text, "public %s\nsecret %.39s\n", k.public_z85,
             k.secret_z85);
    cases[1].what = "line 2";
    snprintf(cases[2].text, sizeof cases[2].text, "public %s\nsecret %s\n", other.public_z85,
             k.secret_z85);
    cases[2].what = "not the one its secret key gives";
    snprintf(cases[3].text, sizeof cases[3].text, "# c\n\nkey %s\n", k.secret_z85);
    cases[3].what = "line 3";
    snprintf(cases[4].text, sizeof cases[4].text, "public %s\npublic %s\nsecret %s\n", k.public_z85,
             k.public_z85, k.secret_z85);
    cases[4].what = "a second key";
    snprintf(cases[5].text, sizeof cases[5].text, "public %s\nsecret %s\n", k.public_z85,
             "########################################");
    cases[5].what = "line 2";
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        snprintf(path, sizeof path, "%s/bad%zu.key", dir, i);
        write_file(path, cases[i].text, 0600);
        ck_assert_int_eq(keys_load_secret(path, &back, err, sizeof err), -1);
        ck_assert_msg(strstr(err, path) && strstr(err, cases[i].what), "case %zu: want '%s' in: %s",
                      i, cases[i].what, err);
    }
    /* comments, blank lines, CR LF and the order of the lines are free */
    snprintf(path, sizeof path, "%s/ok.key", dir);
    snprintf(text, sizeof text, "# mine\r\n\r\nsecret %s\r\n  \npublic   %s  \n", k.secret_z85,
             k.public_z85);
    write_file(path, text, 0600);
    ck_assert_msg(keys_load_secret(path, &back, err, sizeof err) == 0, "%s", err);
    ck_assert_str_eq(back.public_z85, k.public_z85);
    remove_dir(dir);
}
END_TEST

START_TEST(test_directory)
{
    char dir[512], base[PATHLEN + 16], path[PATHLEN + 32], err[1024];
    scratch_dir(dir, sizeof dir, "dir");
    keys_pair_t k[3], outsider;
    static const char *const names[3] = {"alice", "bob", "carol"};
    for (int i = 0; i < 3; i++) {
        ck_assert_int_eq(keys_generate(&k[i], err, sizeof err), 0);
        snprintf(base, sizeof base, "%s/%s", dir, names[i]);
        ck_assert_int_eq(keys_write(base, &k[i], err, sizeof err),
                         0); /* the .key beside it is skipped */
    }
    ck_assert_int_eq(keys_generate(&outsider, err, sizeof err), 0);
    /* not .pub: skipped, whatever is inside */
    snprintf(path, sizeof path, "%s/README", dir);
    write_file(path, "the workers' keys\n", 0644);
    snprintf(path, sizeof path, "%s/dave.pub.bak", dir);
    write_file(path, outsider.public_z85, 0644);
    snprintf(path, sizeof path, "%s/.hidden.pub", dir);
    write_file(path, outsider.public_z85, 0644);
    snprintf(path, sizeof path, "%s/.pub", dir);
    write_file(path, "junk", 0644);
    /* the same key twice counts once */
    snprintf(path, sizeof path, "%s/alice-again.pub", dir);
    write_file(path, k[0].public_z85, 0644);

    keys_set_t *s = keys_set_load_dir(dir, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    ck_assert_uint_eq(keys_set_count(s), 3);
    for (int i = 0; i < 3; i++) {
        ck_assert(keys_set_contains(s, k[i].public_z85));
        ck_assert(!keys_set_contains(s, k[i].secret_z85));
    }
    ck_assert_str_eq(keys_set_name(s, k[1].public_z85), "bob");
    ck_assert_ptr_nonnull(keys_set_name(s, k[0].public_z85));
    ck_assert(!keys_set_contains(s, outsider.public_z85));
    ck_assert_ptr_null(keys_set_name(s, outsider.public_z85));
    ck_assert(!keys_set_contains(s, ""));
    ck_assert(!keys_set_contains(s, NULL));
    ck_assert(!keys_set_contains(NULL, k[0].public_z85));
    keys_set_destroy(&s);
    ck_assert_ptr_null(s);
    keys_set_destroy(&s); /* twice is harmless */

    /* a .pub that is not a key fails the load, by name */
    snprintf(path, sizeof path, "%s/typo.pub", dir);
    write_file(path, "not a key\n", 0644);
    ck_assert_ptr_null(keys_set_load_dir(dir, err, sizeof err));
    ck_assert_msg(strstr(err, "typo.pub") != NULL, "%s", err);
    unlink(path);

    /* empty: an empty set; missing: an error naming it */
    char empty[512];
    scratch_dir(empty, sizeof empty, "empty");
    s = keys_set_load_dir(empty, err, sizeof err);
    ck_assert_ptr_nonnull(s);
    ck_assert_uint_eq(keys_set_count(s), 0);
    ck_assert(!keys_set_contains(s, k[0].public_z85));
    keys_set_destroy(&s);
    remove_dir(empty);
    ck_assert_ptr_null(keys_set_load_dir(empty, err, sizeof err));
    ck_assert_ptr_nonnull(strstr(err, empty));
    remove_dir(dir);
}
END_TEST

static Suite *keys_suite(void)
{
    Suite *s = suite_create("keys");
    TCase *tc = tcase_create("keys");
    tcase_add_test(tc, test_round_trip);
    tcase_add_test(tc, test_mode_refused);
    tcase_add_test(tc, test_bad_z85);
    tcase_add_test(tc, test_directory);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(keys_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
