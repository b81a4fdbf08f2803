#!/usr/bin/env bash
# Builds zenoh's router, zenohd, from crates.io at the version of the eclipse-zenoh Python
# binding the project runs (routers and sessions of one version speak the same protocol),
# once per machine: the binary is cached under ~/.cache/placecell/zenohd-<version>/ and
# found there afterwards. About 5 minutes on a 2-core machine the first time.
#   build-zenohd.sh          build if missing, print the binary's path
#   build-zenohd.sh --path   print the path only (exit 1 if not built)
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
python="${PYTHON:-$here/.venv/bin/python}"
version="$("$python" -c 'import importlib.metadata as m; print(m.version("eclipse-zenoh"))')"
cache="${PLACECELL_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/placecell}"
root="$cache/zenohd-$version"
binary="$root/bin/zenohd"
if [ "${1:-}" = "--path" ]; then
  [ -x "$binary" ] && echo "$binary" && exit 0
  echo "zenohd $version is not built: run tools/build-zenohd.sh" >&2; exit 1
fi
mkdir -p "$cache"
exec 9>"$cache/.zenohd-$version.lock"
flock 9  # one build at a time on the machine
if [ ! -x "$binary" ]; then
  command -v cargo >/dev/null || { echo "build-zenohd.sh: cargo (Rust) is needed to build zenohd" >&2; exit 1; }
  echo "building zenohd $version from crates.io into $root (once per machine)..." >&2
  start=$(date +%s)
  cargo install zenohd --version "=$version" --locked --root "$root" --quiet >&2
  echo "zenohd $version built in $(( $(date +%s) - start )) s" >&2
fi
echo "$binary"
