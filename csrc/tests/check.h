/* SPDX-License-Identifier: MIT */
/*
 * check.h - the C tests' check harness: CHECK(cond) counts a check and, when
 * cond is false, a failure with its file and line; check_report() prints the
 * totals and gives main's exit status. One test program per translation unit.
 */
#ifndef PYMB_TESTS_CHECK_H
#define PYMB_TESTS_CHECK_H

#include <stdio.h>

static int failures;
static int checks;

#define CHECK(cond)                                                                  \
    do {                                                                             \
        checks++;                                                                    \
        if (!(cond)) {                                                               \
            failures++;                                                              \
            fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                            \
    } while (0)

/* Print "N passed, M failed" and return main's exit status. */
static int check_report(void)
{
    printf("%d passed, %d failed\n", checks - failures, failures);
    return failures ? 1 : 0;
}

#endif
