#!/bin/sh
# SPDX-License-Identifier: MIT
# check_man_examples.sh MANDIR INCLUDEDIR: every man page's EXAMPLE compiles.
# The example is taken from the page's roff (between .nf and .fi under
# .SH EXAMPLE), its escapes undone; a whole program (one with main) is
# compiled as it stands, a fragment inside a function body that gives it
# the names the pages share: `ctx` (an opened modbus_t) and `line` (a
# pymb_line from pymb_line_new). Run by `make check-man-examples` and by
# .ci/check-c-install on the installed pages and headers.
# Uses CC and CPPFLAGS (libmodbus's -I) from the environment.
set -eu
mandir=$1 incdir=$2
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
rc=0 n=0
for page in "$mandir"/*.[37]; do
    name=$(basename "$page")
    sed -n '/^\.SH "\{0,1\}EXAMPLE/,/^\.SH/p' "$page" | sed -n '/^\.nf/,/^\.fi/p' \
        | sed -e '/^\.nf/d' -e '/^\.fi/d' -e '/^\.in/d' \
              -e 's/\\-/-/g' -e 's/\\(aq/'"'"'/g' -e 's/\\(dq/"/g' -e 's/\\e/\\/g' \
              -e 's/\\f[BIRP]//g' > "$tmp/body"
    if [ ! -s "$tmp/body" ]; then
        echo "check-man-examples: $name has no example" >&2
        rc=1
        continue
    fi
    if grep -q '^int main' "$tmp/body"; then
        cp "$tmp/body" "$tmp/ex.c"
    else
        {
            printf '#include <errno.h>\n#include <math.h>\n#include <stdio.h>\n'
            printf '#include <stdlib.h>\n#include <string.h>\n#include <pymb_modbus.h>\n'
            printf 'int example(modbus_t *ctx, pymb_line *line);\n'
            printf 'int example(modbus_t *ctx, pymb_line *line)\n{\n(void)ctx;\n(void)line;\n{\n'
            cat "$tmp/body"
            printf '}\nreturn 0;\n}\n'
        } > "$tmp/ex.c"
    fi
    if ! ${CC:-cc} -std=c99 -Wall -Wextra -Werror -Wno-unused -Wno-shadow ${CPPFLAGS:-} \
            -I"$incdir" -c "$tmp/ex.c" -o "$tmp/ex.o" 2> "$tmp/err"; then
        echo "check-man-examples: the example of $name does not compile:" >&2
        cat "$tmp/err" >&2
        rc=1
    fi
    n=$((n + 1))
done
[ $rc -ne 0 ] || echo "check-man-examples: $n examples compile"
exit $rc
