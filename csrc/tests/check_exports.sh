#!/bin/sh
# SPDX-License-Identifier: MIT
# check_exports.sh LIBRARY MANDIR HEADER... : the shared library exports
# exactly the pymb_ functions the headers declare, and each of them has a man
# page in MANDIR (NAME.3) with every section a libmodbus page has. Run by
# `make check-exports` on the build tree and by .ci/run on an installed copy,
# so a function added later without its page fails the build.
# Uses CC, CPPFLAGS (libmodbus's -I) and NM from the environment.
set -eu
lib=$1 mandir=$2
shift 2
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# Declarations, after the preprocessor has removed the comments.
for h in "$@"; do printf '#include "%s"\n' "$h"; done > "$tmp/all.c"
${CC:-cc} ${CPPFLAGS:-} -I"$(dirname "$1")" -E -P "$tmp/all.c" \
    | tr -s ' \t\n' ' ' | grep -o 'pymb_[a-z0-9_]* *(' | tr -d ' (' | sort -u > "$tmp/declared"
# (sed, not awk: a minimal system, such as an extracted Debian root, may have no awk)
${NM:-nm} -D --defined-only "$lib" > "$tmp/nm"
sed -n 's/^[0-9a-fA-F]* T \([^@ ]*\).*/\1/p' "$tmp/nm" | sort -u > "$tmp/exported"
[ -s "$tmp/exported" ] || { echo "check-exports: no function exported by $lib" >&2; exit 1; }

rc=0
if ! cmp -s "$tmp/declared" "$tmp/exported"; then
    echo "check-exports: $lib exports other functions than the headers declare" \
         "(< declared only, > exported only):" >&2
    diff "$tmp/declared" "$tmp/exported" | grep '^[<>]' >&2
    rc=1
fi
[ -s "$tmp/declared" ] || { echo "check-exports: no pymb_ function found in $*" >&2; exit 1; }
while read -r f; do
    page=$mandir/$f.3
    if [ ! -f "$page" ]; then
        echo "check-exports: $f has no man page ($page)" >&2
        rc=1
        continue
    fi
    for s in NAME SYNOPSIS DESCRIPTION "RETURN VALUE" ERRORS EXAMPLE "SEE ALSO"; do
        grep -q "^\.SH \"\{0,1\}$s\"\{0,1\}\$" "$page" \
            || { echo "check-exports: $page has no $s section" >&2; rc=1; }
    done
    grep -q "\\\\fB$f\\\\fR *(" "$page" 2>/dev/null || grep -q "$f(" "$page" \
        || { echo "check-exports: $page does not show $f in its synopsis" >&2; rc=1; }
done < "$tmp/declared"
[ $rc -ne 0 ] || echo "check-exports: $(wc -l < "$tmp/declared") functions: exported, declared and documented alike"
exit $rc
