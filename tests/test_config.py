"""Strict configuration: every mistake names its section and key and stops the daemon."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from daemon import config
from kernel.errors import ConfigError
from tests.daemon_harness import DEFAULT_CONFIG, REPO


def test_default_file_equals_builtin_defaults() -> None:
    assert config.load(DEFAULT_CONFIG) == config.load(None)


def test_print_config_round_trips() -> None:
    cfg = config.load(DEFAULT_CONFIG)
    assert config.from_dict(tomllib.loads(config.to_toml(cfg))) == cfg


@pytest.mark.parametrize(
    ("doc", "expected"),
    [
        ({"camera": {"bakend": "sim"}}, "[config.camera] unknown key 'bakend'"),
        ({"nonsense": {}}, "[config] unknown key 'nonsense'"),
        ({"base": {"sim": {"max_speed": 1.0}}}, "[config.base.sim] unknown key 'max_speed'"),
        ({"camera": {"sim": {"rate_hz": "fast"}}}, "config.camera.sim.rate_hz: expected a number"),
        ({"panorama": {"width": 720.5}}, "config.panorama.width: expected an integer"),
        ({"zenoh": {"multicast_scouting": "no"}}, "config.zenoh.multicast_scouting: expected true"),
        ({"zenoh": {"listen": "tcp/127.0.0.1:7447"}}, "config.zenoh.listen: expected a list"),
        ({"panorama": {"width": 10}}, "config.panorama.width: 10 is out of range (must be >= 64)"),
        ({"camera": {"sim": {"rate_hz": 0}}}, "config.camera.sim.rate_hz: 0.0 is out of range"),
        ({"zenoh": {"mode": "router"}}, "config.zenoh.mode: 'router' is not one of"),
        ({"camera": {"backend": "webcam"}}, "camera.backend 'webcam' is not one of"),
        ({"mirror": {"r_inner_px": 300.0}}, "r_outer_px (228.0) must be larger than r_inner_px"),
        ({"robot": {"name": "a/b"}}, "robot.name 'a/b' must be"),
    ],
)
def test_bad_values_name_the_key(doc: dict, expected: str) -> None:
    with pytest.raises(ConfigError) as e:
        config.from_dict(doc)
    assert expected in str(e.value)


def test_unreadable_and_invalid_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read configuration"):
        config.load(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera\nbackend = 'sim'\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        config.load(bad)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[camera]\nbakend = 'sim'\n", "unknown key 'bakend'"),
        ("[base.sim]\nodometry_rate_hz = 'x'\n", "config.base.sim.odometry_rate_hz"),
        ("[service]\nstatus_period_s = -1\n", "config.service.status_period_s: -1.0 is out of"),
    ],
)
def test_daemon_exits_nonzero_before_opening_devices(tmp_path: Path, text: str,
                                                     expected: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    proc = subprocess.run([sys.executable, "-m", "daemon", "--config", str(path)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert expected in proc.stderr
    assert "configuration error" in proc.stderr
    assert "zenoh session" not in proc.stderr  # nothing was opened


def test_print_config_cli() -> None:
    proc = subprocess.run([sys.executable, "-m", "daemon", "--config", str(DEFAULT_CONFIG),
                           "--print-config"], cwd=REPO, capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert config.from_dict(tomllib.loads(proc.stdout)) == config.load(DEFAULT_CONFIG)
