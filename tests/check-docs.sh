#!/usr/bin/env bash
# Every `name()` that docs/ARCHITECTURE.md mentions must be defined in the
# code (a function definition or a macro), so the guide cannot name a
# function that was renamed or removed. Run by `make test`.
set -euo pipefail
cd "$(dirname "$0")/.."
doc=docs/ARCHITECTURE.md
names=$(grep -o '`[A-Za-z_][A-Za-z0-9_]*()`' "$doc" | tr -d '`()' | sort -u)
missing=0 checked=0
for n in $names; do
    checked=$((checked + 1))
    # a definition: the name at the start of a line or after a return type,
    # followed by '(' and not ending in ';' (a declaration or a call)
    if ! grep -rqE "^([A-Za-z_][A-Za-z0-9_ \*]*[ \*])?$n\(([^;]*)$" \
        --include='*.c' --include='*.h' common proto master worker client; then
        echo "check-docs: $doc names $n(), which no source file defines"
        missing=$((missing + 1))
    fi
done
# and every file it names must exist
for f in $(grep -oE '`(common|proto|master|worker|client|tests)/[A-Za-z0-9_./-]+`' "$doc" | tr -d '`' | sort -u); do
    checked=$((checked + 1))
    [ -e "$f" ] || { echo "check-docs: $doc names $f, which does not exist"; missing=$((missing + 1)); }
done
echo "check-docs: $checked names in $doc checked, $missing missing"
[ "$missing" -eq 0 ]
