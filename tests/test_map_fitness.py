"""The map file's fitness is checked when the daemon starts (issue 32, point 2): a map that
mapping mode cannot write, a directory, an empty file, a path it cannot create — each
ends in a message naming the file and what to do, exit 2, no traceback, and the file's
bytes as they were; nothing is created unasked. Where configured, an unwritable map is
localised on read-only, and status says so."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.store.sqlite_store import MapStore
from tests.daemon_harness import REPO, client_session, running_daemon, wait_for, write_config
from tests.map_fixtures import synthetic_place

# The daemon exits before any device or zenoh session when its map is unfit: these runs
# take a second or two each. The read-only start below runs a whole daemon.
START_TIMEOUT_S = 120.0


def _unprivileged() -> list[str]:
    """A prefix that makes file permissions bind the command: root reads and writes any
    file, so as root the command runs without the capabilities that let it."""
    if os.geteuid() != 0:
        return []
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search"]


def _start(config: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*_unprivileged(), sys.executable, "-m", "daemon", "--config", str(config)],
        cwd=REPO, capture_output=True, text=True, timeout=START_TIMEOUT_S)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _map_with_a_place(path: Path) -> None:
    from daemon.config import load
    from kernel.panorama import geometry_checksum

    config = load(str(REPO / "config" / "placecell.toml"))
    with MapStore.open(path, geometry_checksum(config.projection, config.panorama)) as store:
        store.add_place(synthetic_place(np.random.default_rng(1), "dock"))


def _refused(result: subprocess.CompletedProcess[str], message: str) -> None:
    assert result.returncode == 2, result.stderr[-2000:]
    assert "Traceback" not in result.stderr, result.stderr[-2000:]
    assert message in result.stderr, result.stderr[-2000:]


def _config(tmp_path: Path, map_path: Path, **mapping: Any) -> Path:
    config, _ = write_config(tmp_path, {"map": {"path": str(map_path)},
                                        "mapping": mapping})
    return config


def test_a_read_only_map_in_mapping_mode_is_refused_untouched(tmp_path: Path) -> None:
    path = tmp_path / "maps" / "map.db"
    path.parent.mkdir()
    _map_with_a_place(path)
    path.chmod(0o444)
    before = _sha(path)
    result = _start(_config(tmp_path, path, mode="mapping"))
    _refused(result, "cannot be written")
    assert "make it writable" in result.stderr
    assert _sha(path) == before
    assert sorted(p.name for p in path.parent.iterdir()) == ["map.db"]


def test_a_map_in_a_read_only_directory_is_refused_in_mapping_mode(tmp_path: Path) -> None:
    folder = tmp_path / "maps"
    folder.mkdir()
    path = folder / "map.db"
    _map_with_a_place(path)
    before = _sha(path)
    folder.chmod(0o555)  # the file is writable, its journal cannot be made beside it
    try:
        result = _start(_config(tmp_path, path, mode="mapping"))
    finally:
        folder.chmod(0o755)
    _refused(result, "cannot be written")
    assert _sha(path) == before


def test_a_directory_as_the_map_path_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "maps"
    folder.mkdir()
    result = _start(_config(tmp_path, folder, mode="mapping"))
    _refused(result, "is a directory, not a map file")
    assert list(folder.iterdir()) == []


def test_an_empty_file_is_not_made_a_new_map(tmp_path: Path) -> None:
    path = tmp_path / "map.db"
    path.write_bytes(b"")
    result = _start(_config(tmp_path, path, mode="mapping"))
    _refused(result, "is empty (0 bytes)")
    assert path.read_bytes() == b""
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("map")) == ["map.db"]


def test_a_map_that_cannot_be_created_is_refused_and_nothing_made(tmp_path: Path) -> None:
    folder = tmp_path / "maps"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        result = _start(_config(tmp_path, folder / "map.db", mode="mapping"))
    finally:
        folder.chmod(0o755)
    _refused(result, "cannot create the map")
    assert list(folder.iterdir()) == []


def test_a_map_path_under_a_file_is_refused(tmp_path: Path) -> None:
    blocker = tmp_path / "var"
    blocker.write_text("not a folder")
    result = _start(_config(tmp_path, blocker / "map.db", mode="mapping"))
    _refused(result, "cannot create the map directory")
    assert blocker.read_text() == "not a folder"


def test_the_write_probe_leaves_a_writable_map_byte_for_byte(tmp_path: Path) -> None:
    path = tmp_path / "map.db"
    _map_with_a_place(path)
    before = _sha(path)
    with MapStore.open(path, None, readonly=False):
        pass
    assert _sha(path) == before


@pytest.mark.xdist_group("realtime")
def test_a_read_only_map_is_localised_on_where_configured(tmp_path: Path) -> None:
    """``[map] if_unwritable = "localisation"``: the daemon starts in localisation mode on
    the read-only map, says so in status, refuses mapping, and writes nothing."""
    path = tmp_path / "maps" / "map.db"
    path.parent.mkdir()
    _map_with_a_place(path)
    path.chmod(0o444)
    before = _sha(path)
    config, port = write_config(tmp_path, {"map": {"path": str(path),
                                                   "if_unwritable": "localisation",
                                                   "save_pose_period_s": 0.2},
                                           "mapping": {"mode": "mapping"}})
    with running_daemon(config, wrapper=_unprivileged()) as proc:
        session = client_session(port)
        try:
            status: dict[str, Any] = {}

            def up() -> bool:
                nonlocal status
                for reply in session.get("placecell/*/status", timeout=1.0):
                    if reply.ok is not None:
                        status = json.loads(reply.ok.payload.to_bytes())
                        return bool(status["belief"]["frames_ok"])
                return False

            assert wait_for(up, START_TIMEOUT_S), "no status from the daemon"
            assert status["map"]["mode"] == "localisation"
            assert status["map"]["writable"] is False
            assert "cannot be written" in status["map"]["readonly_reason"]
            replies = [json.loads(r.ok.payload.to_bytes()) for r in session.get(
                "placecell/*/cmd/mode", payload=b'{"mode": "mapping"}', timeout=5.0)
                if r.ok is not None]
            assert [(r["kind"], r["code"]) for r in replies] == [("error", "refused")]
            assert "writable map" in replies[0]["message"]
        finally:
            session.close()
        assert proc.poll() is None
    assert _sha(path) == before


def test_an_unwritable_map_is_told_apart_from_a_bad_one(tmp_path: Path) -> None:
    """The store's own error for it, which the daemon turns into the choice above."""
    path = tmp_path / "map.db"
    _map_with_a_place(path)
    path.chmod(0o444)
    code = ("from daemon.store.sqlite_store import MapStore\n"
            "from kernel.errors import MapNotWritableError\n"
            "try:\n"
            f"    MapStore.open({str(path)!r}, None)\n"
            "except MapNotWritableError as e:\n"
            "    print('not writable:', e)\n")
    result = subprocess.run([*_unprivileged(), sys.executable, "-c", code], cwd=REPO,
                            capture_output=True, text=True, timeout=START_TIMEOUT_S)
    assert result.stdout.startswith("not writable:"), result.stdout + result.stderr
