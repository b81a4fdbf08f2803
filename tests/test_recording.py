"""MCAP recordings: a 60 s scenario replays bit-exact through the replay backends
(issue 3, point 5), and the daemon can record and replay."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader

from hal.recording import (
    TOPIC_FRAMES,
    TOPIC_GROUND_TRUTH,
    TOPIC_ODOMETRY,
    Recorder,
    RecordingReader,
)
from hal.registry import HalContext, create_base, create_camera
from hal.sim.factory import shared_sim_robot
from kernel.errors import DeviceInitError, DeviceIOError
from tests.daemon_harness import (
    REPO,
    client_session,
    running_daemon,
    venv_bin,
    wait_for,
    write_config,
)
from tests.sim_helpers import lockstep_config, with_sections

SCENARIO = REPO / "config" / "scenarios" / "record-60s.toml"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list, list]:
    """Simulate the 60 s scenario through the sim backends, record it, keep what was fed."""
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    config = lockstep_config(scenario=str(SCENARIO))
    ctx = HalContext(config)
    camera, base = create_camera(config.camera, ctx), create_base(config.base, ctx)
    camera.open()
    base.open()
    robot = shared_sim_robot(ctx)
    rec = Recorder(path, {"scenario": str(SCENARIO)})
    frames, odometry = [], []
    while robot.now_ns() < 60e9:
        frame = camera.read(1.0)
        rec.write_frame(frame)
        rec.write_ground_truth(*robot.ground_truth())
        frames.append(frame)
        for odo in base.read(1.0):
            rec.write_odometry(odo)
            odometry.append(odo)
    rec.close()
    return path, frames, odometry


def test_replay_gives_the_same_frames_and_odometry(recorded: tuple[Path, list, list]) -> None:
    path, frames, odometry = recorded
    assert len(frames) == 61 and len(odometry) == 3000  # 0..60 s at 1 Hz; 50 Hz odometry
    config = with_sections(lockstep_config(), camera={"backend": "replay"},
                           base={"backend": "replay"})
    config = dataclasses.replace(config, camera=dataclasses.replace(
        config.camera, replay=dataclasses.replace(config.camera.replay, file=str(path),
                                                  speed=0.0)))
    ctx = HalContext(config)
    camera, base = create_camera(config.camera, ctx), create_base(config.base, ctx)
    camera.open()
    base.open()
    replayed_odometry = []
    for original in frames:
        frame = camera.read(1.0)
        assert frame.seq == original.seq and frame.stamp_ns == original.stamp_ns
        assert np.array_equal(frame.image, original.image)  # PNG: bit-exact
        replayed_odometry += base.read(1.0)
    with pytest.raises(DeviceIOError, match="end of recording"):
        camera.read(1.0)
    with pytest.raises(DeviceInitError, match="end of recording"):
        camera.open()  # a finished recording stays finished (loop = false)
    while True:
        try:
            replayed_odometry += base.read(0.05)
        except DeviceIOError:
            break
    assert replayed_odometry == odometry


def test_file_is_valid_mcap(recorded: tuple[Path, list, list]) -> None:
    path, frames, odometry = recorded
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {summary.channels[cid].topic: n
              for cid, n in summary.statistics.channel_message_counts.items()}
    assert counts == {TOPIC_FRAMES: len(frames), TOPIC_GROUND_TRUTH: len(frames),
                      TOPIC_ODOMETRY: len(odometry)}
    schemas = {s.name: s.encoding for s in summary.schemas.values()}
    assert schemas["foxglove.CompressedImage"] == "jsonschema"
    # Independent of the summary and index: stream every record, check every message.
    n = 0
    with open(path, "rb") as f:
        for record in StreamReader(f, validate_crcs=True).records:
            if isinstance(record, McapMessage):
                body = json.loads(record.data)
                assert body["stamp_ns"] == record.log_time
                n += 1
    assert n == 2 * len(frames) + len(odometry)
    meta = RecordingReader(path).metadata()
    assert meta["scenario"] == str(SCENARIO)


def test_bad_recordings_are_refused(tmp_path: Path) -> None:
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_bytes(b"definitely not an mcap file")
    with pytest.raises(DeviceInitError, match="not an MCAP file"):
        RecordingReader(not_mcap)
    with pytest.raises(DeviceInitError, match="does not exist"):
        RecordingReader(tmp_path / "missing.mcap")


def test_sim_record_cli(tmp_path: Path) -> None:
    out = tmp_path / "tbl.mcap"
    proc = subprocess.run([venv_bin("placecell-sim"), "record",
                           str(REPO / "config" / "scenarios" / "tbl-cross.toml"),
                           "--out", str(out), "--duration", "3", "--jpeg"],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    topics = {m.topic for m in RecordingReader(out).messages()}
    assert topics >= {TOPIC_FRAMES, TOPIC_ODOMETRY, TOPIC_GROUND_TRUTH}


def test_daemon_records_and_replays(tmp_path: Path) -> None:
    rec = tmp_path / "daemon.mcap"
    config, _ = write_config(tmp_path)
    with running_daemon(config, extra_args=["--record", str(rec)]) as proc:
        # A few seconds of recording: the replaying daemon below must be up before it ends.
        assert wait_for(lambda: rec.exists() and rec.stat().st_size > 6_000_000, 120)
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
    topics: dict[str, int] = {}
    for m in RecordingReader(rec).messages():
        topics[m.topic] = topics.get(m.topic, 0) + 1
    assert topics[TOPIC_FRAMES] >= 3 and topics[TOPIC_ODOMETRY] >= 50
    assert topics["/placecell/belief"] >= 1
    # The same daemon on the recording, at the recorded rate (the frames looped: on a busy
    # machine the daemon may come up after a short recording's end).
    replay_dir = tmp_path / "replay"
    replay_dir.mkdir()
    config2, port = write_config(replay_dir, {
        "camera": {"backend": "replay", "replay": {"file": str(rec), "speed": 1.0,
                                                   "loop": True}},
        "base": {"backend": "replay"}})
    session = client_session(port)
    try:
        with running_daemon(config2) as proc:
            def status() -> dict:
                replies = [json.loads(r.ok.payload.to_bytes())
                           for r in session.get("placecell/*/status", timeout=2.0)
                           if r.ok is not None]
                return replies[0] if replies else {}
            assert wait_for(lambda: status().get("rates", {}).get("frames_hz", 0) > 0
                            and status()["rates"]["odometry_hz"] > 0, 60)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(10) == 0
    finally:
        session.close()
