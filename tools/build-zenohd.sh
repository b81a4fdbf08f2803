#!/usr/bin/env bash
# Builds zenoh's router, zenohd, and its storage manager plugin from crates.io at the version
# of the eclipse-zenoh Python binding the project runs (routers and sessions of one version
# speak the same protocol; a plugin loads only into a zenohd of its own zenoh version and
# compiler), once per machine: cached under ~/.cache/placecell/zenohd-<version>/ (bin/zenohd,
# lib/libzenoh_plugin_storage_manager.so) and found there afterwards. The fleet's routers
# (config/fleet/, docs/fleet.md) load the plugin. On a 2-core machine the first time: zenohd
# about 5 minutes, the plugin about as long again.
#   build-zenohd.sh               build what is missing, print zenohd's path
#   build-zenohd.sh --path        print zenohd's path only (exit 1 if not built)
#   build-zenohd.sh --plugin-dir  print the plugin's directory only (exit 1 if not built)
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
python="${PYTHON:-$here/.venv/bin/python}"
version="$("$python" -c 'import importlib.metadata as m; print(m.version("eclipse-zenoh"))')"
cache="${PLACECELL_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/placecell}"
root="$cache/zenohd-$version"
binary="$root/bin/zenohd"
plugin="$root/lib/libzenoh_plugin_storage_manager.so"
case "${1:-}" in
  --path)
    [ -x "$binary" ] && echo "$binary" && exit 0
    echo "zenohd $version is not built: run tools/build-zenohd.sh" >&2; exit 1 ;;
  --plugin-dir)
    [ -f "$plugin" ] && dirname "$plugin" && exit 0
    echo "the storage manager plugin $version is not built: run tools/build-zenohd.sh" >&2
    exit 1 ;;
esac
mkdir -p "$cache"
exec 9>"$cache/.zenohd-$version.lock"
flock 9  # one build at a time on the machine
if [ ! -x "$binary" ] || [ ! -f "$plugin" ]; then
  command -v cargo >/dev/null || { echo "build-zenohd.sh: cargo (Rust) is needed to build zenohd" >&2; exit 1; }
fi
if [ ! -x "$binary" ]; then
  echo "building zenohd $version from crates.io into $root (once per machine)..." >&2
  start=$(date +%s)
  cargo install zenohd --version "=$version" --locked --root "$root" --quiet >&2
  echo "zenohd $version built in $(( $(date +%s) - start )) s" >&2
fi
if [ ! -f "$plugin" ]; then
  # `cargo install` installs binaries only: the plugin (a cdylib) is built from its crate's
  # own source and lock file, which cargo fetches from the registry as for any dependency.
  echo "building zenoh-plugin-storage-manager $version into $root/lib (once per machine)..." >&2
  start=$(date +%s)
  work="$(mktemp -d)"
  trap 'rm -rf "$work"' EXIT
  mkdir -p "$work/fetch/src"
  printf '[package]\nname = "fetch"\nversion = "0.0.0"\nedition = "2021"\n[dependencies]\nzenoh-plugin-storage-manager = "=%s"\n' \
    "$version" > "$work/fetch/Cargo.toml"
  : > "$work/fetch/src/lib.rs"
  manifest="$(cd "$work/fetch" && cargo metadata --format-version 1 --quiet | "$python" -c '
import json, sys
meta = json.load(sys.stdin)
print(next(p["manifest_path"] for p in meta["packages"]
           if p["name"] == "zenoh-plugin-storage-manager"))')"
  cp -r "$(dirname "$manifest")" "$work/plugin"
  cargo build --release --locked --quiet --manifest-path "$work/plugin/Cargo.toml" \
    --target-dir "$work/target" >&2
  mkdir -p "$root/lib"
  cp "$work/target/release/libzenoh_plugin_storage_manager.so" "$plugin.part"
  mv "$plugin.part" "$plugin"
  echo "zenoh-plugin-storage-manager $version built in $(( $(date +%s) - start )) s" >&2
fi
echo "$binary"
