"""``placecelld --check-devices`` reports each configured device, OK or FAIL."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.daemon_harness import REPO, write_config


def test_check_devices_on_the_simulator(tmp_path: Path) -> None:
    config, _ = write_config(tmp_path)
    out = subprocess.run([sys.executable, "-m", "daemon", "--config", str(config),
                          "--check-devices"], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("OK   camera (sim)") and "640 x 480" in lines[0]
    assert lines[1].startswith("OK   base (sim)") and "50.0 Hz" in lines[1]


def test_check_devices_names_what_is_missing(tmp_path: Path) -> None:
    config, _ = write_config(tmp_path, {
        "camera": {"backend": "v4l2", "v4l2": {"device": "/dev/video-not-here"}},
        "base": {"backend": "xr4000-serial",
                 "xr4000_serial": {"port": str(tmp_path / "no-such-tty")}}})
    out = subprocess.run([sys.executable, "-m", "daemon", "--config", str(config),
                          "--check-devices"], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 1
    lines = out.stdout.splitlines()
    assert lines[0].startswith("FAIL camera (v4l2)") and "/dev/video-not-here" in lines[0]
    assert lines[1].startswith("FAIL base (xr4000-serial)") and "no-such-tty" in lines[1]
