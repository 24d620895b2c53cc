#!/bin/sh
# The compiler launcher of the quick-start tree (tools/product-tree.sh): runs one compile command
# as it is and keeps what the compiler printed beside the object, as <object>.warnings (removed
# when the compile is silent). The tree is a user's build, so warnings do not fail it; but
# tools/test.sh builds the system tests in the same tree and then fails if any object has a
# .warnings file: the -O2 build is held warning-free without compiling the product twice.
# Usage (by CMake): keep-warnings.sh COMPILER ARGS... (ARGS contain `-o OBJECT`).
object=""
previous=""
for arg in "$@"; do
  [ "$previous" = "-o" ] && object=$arg
  previous=$arg
done
if [ -z "$object" ]; then
  exec "$@"
fi
printed="$object.printed"
mkdir -p "$(dirname "$object")"
status=0
"$@" 2>"$printed" || status=$?
cat "$printed" >&2
if [ -s "$printed" ]; then
  mv -f "$printed" "$object.warnings"
else
  rm -f "$printed" "$object.warnings"
fi
exit "$status"
