"""The shipped unit (systemd/placecelld.service) is hardened and well-formed, as systemd
itself judges it offline: `systemd-analyze security` scores it at most 2.0 and `verify`
finds nothing wrong but the binary not being installed on this machine."""

from __future__ import annotations

import re
import subprocess

from tests.daemon_harness import REPO

UNIT = REPO / "systemd" / "placecelld.service"


def _analyze(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["systemd-analyze", *args, str(UNIT)], capture_output=True,
                          text=True, timeout=60)


def test_the_unit_scores_at_most_2_in_systemd_analyze_security() -> None:
    out = _analyze("security", "--offline=true", "--no-pager")
    found = re.search(r"Overall exposure level for placecelld\.service: ([0-9.]+)", out.stdout)
    assert found, out.stdout + out.stderr
    assert float(found.group(1)) <= 2.0, out.stdout
    for directive in ("CapabilityBoundingSet=", "DevicePolicy=closed", "SystemCallFilter=",
                      "RestrictAddressFamilies=", "ProtectSystem=strict"):
        assert directive in UNIT.read_text(), directive


def test_systemd_analyze_verify_finds_only_the_uninstalled_binary() -> None:
    out = _analyze("verify")
    problems = [line for line in (out.stdout + out.stderr).splitlines() if line.strip()
                and "/opt/placecell/.venv/bin/placecelld is not executable" not in line]
    assert problems == [], problems
