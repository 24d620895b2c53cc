#!/usr/bin/env bash
# Applies clang-format to the project's C++ sources; with --check, fails listing unformatted files.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
mapfile -t files < <(git ls-files '*.cpp' '*.hpp' 2>/dev/null || find . -name '*.[ch]pp' -not -path './build*')
if [[ ${1:-} == --check ]]; then
  bad=()
  for f in "${files[@]}"; do
    clang-format --dry-run -Werror "$f" >/dev/null 2>&1 || bad+=("$f")
  done
  if ((${#bad[@]})); then
    echo "format: not clang-formatted (run tools/format.sh): ${bad[*]}" >&2
    exit 1
  fi
else
  clang-format -i "${files[@]}"
fi
