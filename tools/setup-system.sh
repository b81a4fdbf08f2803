#!/usr/bin/env bash
# Installs the Debian packages the project needs when they are missing.
#   setup-system.sh venv   python3 venv support (for `make run` / `make test`)
#   setup-system.sh test   tools the test suite drives: socat (pseudo-terminal pairs),
#                          systemd-analyze (the unit's security score and verification)
set -euo pipefail
want=()
case "${1:-}" in
  venv) python3.11 -c 'import ensurepip, venv' 2>/dev/null || want+=(python3-venv) ;;
  test) command -v socat >/dev/null || want+=(socat)
        command -v systemd-analyze >/dev/null || want+=(systemd) ;;
  *) echo "usage: $0 venv|test" >&2; exit 2 ;;
esac
[ ${#want[@]} -eq 0 ] && exit 0
sudo=""; [ "$(id -u)" -eq 0 ] || sudo="sudo"
echo "installing Debian packages: ${want[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${want[@]}"
