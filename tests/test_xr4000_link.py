"""The base link end to end through the emulator over real pseudo-terminals (serial) and
python-can (slcan on a socat pair between processes; virtual in-process) (issue 4)."""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from hal.base.base import Odometry
from hal.base.settings import Xr4000CanSettings, Xr4000SerialSettings
from hal.base.xr4000_can import Xr4000CanBase
from hal.base.xr4000_serial import Xr4000SerialBase
from hal.sim.factory import build_sim_robot
from kernel.errors import DeviceIOError, DeviceTimeoutError
from tests.daemon_harness import busy_loops
from tests.links import emulator, pty_pair, stop
from tests.sim_helpers import lockstep_config
from tools.xr4000.emulator import Emulator, SimSource
from tools.xr4000.faults import FaultPlan
from tools.xr4000.transport import CanSide

# Held to wall-clock limits: one worker runs these modules one after another (tests/conftest.py).
pytestmark = pytest.mark.xdist_group("realtime")


CROSS = [(0.5, 0.0), (-0.5, 0.0), (-0.5, 0.0), (0.5, 0.0), (0.0, 0.5), (0.0, -0.5),
         (0.0, -0.5), (0.0, 0.5)]


def _serial(path: Path) -> Xr4000SerialBase:
    return Xr4000SerialBase(Xr4000SerialSettings(port=str(path), command_timeout_s=1.0), None)


def _slcan(path: Path) -> Xr4000CanBase:
    return Xr4000CanBase(Xr4000CanSettings(interface="slcan", channel=str(path),
                                           command_timeout_s=1.0), None)


def _collect(base: Any, seconds: float, into: list[Odometry]) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        with contextlib.suppress(DeviceTimeoutError):
            into += base.read(0.5)


def _wait_for_link(base: Any, into: list[Odometry], limit_s: float = 20.0) -> None:
    """Until the emulator (a separate process) is up and odometry flows."""
    end = time.monotonic() + limit_s
    while not into:
        assert time.monotonic() < end, "no odometry from the emulator"
        _collect(base, 0.2, into)


def _run_cross(base: Any, into: list[Odometry]) -> None:
    """Each leg once the last is done. A read may time out on a busy machine (the
    emulator starved for a moment); the leg's own limit is what fails the test."""
    for dx, dy in CROSS:
        base.move_relative(dx, dy, 0.0, 0.2)
        end = time.monotonic() + 10
        while not (base.status().move_done and not base.status().moving):
            assert time.monotonic() < end, "move did not finish"
            with contextlib.suppress(DeviceTimeoutError):
                into += base.read(0.5)


def _truth(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _check_quantisation(delivered: list[Odometry], truth: list[dict[str, Any]], base: Any
                        ) -> None:
    by_seq = {t["seq"]: t for t in truth}
    ok = sum(1 for o in delivered
             if abs(o.x - by_seq[o.seq]["odo"][0]) <= 0.001
             and abs(o.y - by_seq[o.seq]["odo"][1]) <= 0.001
             and abs(math.remainder(o.yaw - by_seq[o.seq]["odo"][2], 2 * math.pi)) <= 0.001)
    assert ok / len(delivered) >= 0.999
    # Every sample sent between the first and last delivered one is delivered or counted.
    seqs = [o.seq for o in delivered]
    missing = (seqs[-1] - seqs[0] + 1) - len(set(seqs))
    assert missing == base.stats()["lost"]
    assert seqs[-1] >= max(by_seq) - 3  # nothing lost at the end but the line in flight


def _check_cross(truth: list[dict[str, Any]]) -> None:
    x0, y0, yaw0 = truth[0]["true"]
    c, s = math.cos(yaw0), math.sin(yaw0)
    worst = 0.0
    reach = {"+x": 0.0, "-x": 0.0, "+y": 0.0, "-y": 0.0}
    for t in truth:
        x, y, _ = t["true"]
        u = c * (x - x0) + s * (y - y0)
        v = -s * (x - x0) + c * (y - y0)
        worst = max(worst, min(abs(v) + max(0.0, abs(u) - 0.5), abs(u) + max(0.0, abs(v) - 0.5)))
        reach["+x"], reach["-x"] = max(reach["+x"], u), min(reach["-x"], u)
        reach["+y"], reach["-y"] = max(reach["+y"], v), min(reach["-y"], v)
    assert worst <= 0.005, f"true path left the commanded cross by {worst * 1000:.1f} mm"
    assert reach["+x"] > 0.495 and reach["-x"] < -0.495
    assert reach["+y"] > 0.495 and reach["-y"] < -0.495


@pytest.mark.parametrize("transport", ["serial", "slcan"])
def test_end_to_end_and_tbl_cross(tmp_path: Path, transport: str) -> None:
    """With two busy loops beside it (issue 32): every leg of the cross driven to 0.5 m."""
    truth_path, stats_path = tmp_path / "truth.jsonl", tmp_path / "stats.json"
    with busy_loops(), pty_pair(tmp_path) as pair:
        base = _serial(pair.b) if transport == "serial" else _slcan(pair.b)
        base.open()
        link = ["--serial", str(pair.a)] if transport == "serial" else [
            "--can", f"slcan:{pair.a}"]
        emu = emulator([*link, "--truth-out", str(truth_path), "--stats-out", str(stats_path)])
        delivered: list[Odometry] = []
        try:
            _wait_for_link(base, delivered)
            _collect(base, 0.5, delivered)
            _run_cross(base, delivered)
            _collect(base, 0.5, delivered)
        finally:
            out = stop(emu)
            _collect(base, 0.3, delivered)
            base.close()
    assert len(delivered) > 300, out
    _check_quantisation(delivered, _truth(truth_path), base)
    _check_cross(_truth(truth_path))
    assert json.loads(stats_path.read_text())["counts"]["MovCmd"] == 8


def test_a_dropped_acknowledgement_is_resent_on_serial_and_never_driven_twice(
        tmp_path: Path) -> None:
    """The third move's ACK is lost: the link sends the move again with its id, the
    controller answers the repeat without driving it again, and the cross is exact."""
    truth_path, stats_path = tmp_path / "truth.jsonl", tmp_path / "stats.json"
    with pty_pair(tmp_path) as pair:
        base = _serial(pair.b)
        base.open()
        emu = emulator(["--serial", str(pair.a), "--drop-answer", "3", "--truth-out",
                        str(truth_path), "--stats-out", str(stats_path)])
        delivered: list[Odometry] = []
        try:
            _wait_for_link(base, delivered)
            _run_cross(base, delivered)
            _collect(base, 0.5, delivered)
        finally:
            stop(emu)
            base.close()
    stats = json.loads(stats_path.read_text())
    assert stats["injected"]["dropped_answers"] == 1
    assert stats["counts"]["MovCmd"] == 8 and stats["counts"]["repeated_commands"] == 1
    assert base.stats()["command_resends"] == 1 and base.stats()["acks"] == 8
    _check_cross(_truth(truth_path))


def test_an_unanswered_move_on_can_fails_clearly_and_stops_the_base(tmp_path: Path
                                                                     ) -> None:
    """CAN frames carry no id, so a repeated move could be driven twice: an unanswered
    move is not sent again; the base is stopped and the caller told. A stop whose answer
    is lost is sent again (stopping twice is stopping)."""
    stats_path = tmp_path / "stats.json"
    with pty_pair(tmp_path) as pair:
        base = _slcan(pair.b)
        base.open()
        # Answers: 1 the first move, 2 a stop (lost), 3 its repeat, 4 the second move (lost),
        # 5 the stop after it.
        emu = emulator(["--can", f"slcan:{pair.a}", "--drop-answer", "2", "--drop-answer",
                        "4", "--stats-out", str(stats_path)])
        delivered: list[Odometry] = []
        try:
            _wait_for_link(base, delivered)
            base.move_relative(0.2, 0.0, 0.0, 0.2)
            base.stop()
            with pytest.raises(DeviceTimeoutError, match="not sent again.*stopped"):
                base.move_relative(0.2, 0.0, 0.0, 0.2)
            _collect(base, 0.5, delivered)
        finally:
            stop(emu)
            base.close()
    stats = json.loads(stats_path.read_text())
    assert stats["injected"]["dropped_answers"] == 2
    assert stats["counts"]["MovCmd"] == 2 and stats["counts"]["StpCmd"] == 3
    assert base.stats()["command_resends"] == 1 and base.stats()["command_timeouts"] == 1


def test_serial_corruption_never_reaches_odometry(tmp_path: Path) -> None:
    truth_path, stats_path = tmp_path / "truth.jsonl", tmp_path / "stats.json"
    with pty_pair(tmp_path) as pair:
        base = _serial(pair.b)
        base.open()
        emu = emulator(["--serial", str(pair.a), "--corrupt-rate", "0.05", "--seed", "3",
                        "--truth-out", str(truth_path), "--stats-out", str(stats_path),
                        "--scenario", "config/scenarios/tbl-cross.toml", "--duration", "6"])
        delivered: list[Odometry] = []
        _collect(base, 7.0, delivered)
        stop(emu)
        _collect(base, 0.3, delivered)
        base.close()
    injected = json.loads(stats_path.read_text())["injected"]
    truth = {t["seq"]: t for t in _truth(truth_path)}
    for o in delivered:  # exact wire values: nothing corrupted got through
        assert [round(o.x * 1000), round(o.y * 1000), round(o.yaw * 1000)] == truth[o.seq]["wire"]
    stats = base.stats()
    assert injected["corrupted_lines"] > 10
    assert stats["malformed_bad_checksum"] == injected["corrupted_lines"]
    seqs = [o.seq for o in delivered]
    gaps = (seqs[-1] - seqs[0] + 1) - len(seqs)
    assert stats["lost"] == gaps
    assert gaps <= injected["corrupted_odometry"] <= gaps + 1  # + the first line maybe
    last = max(truth)
    assert seqs[-1] == last or truth[last]["seq"] - seqs[-1] <= 1
    assert [round(delivered[-1].x * 1000), round(delivered[-1].y * 1000)] == \
        truth[seqs[-1]]["wire"][:2]


def test_can_drops_are_counted_exactly(tmp_path: Path) -> None:
    truth_path, stats_path = tmp_path / "truth.jsonl", tmp_path / "stats.json"
    with pty_pair(tmp_path) as pair:
        base = _slcan(pair.b)
        base.open()
        emu = emulator(["--can", f"slcan:{pair.a}", "--drop-rate", "0.05", "--seed", "4",
                        "--truth-out", str(truth_path), "--stats-out", str(stats_path),
                        "--scenario", "config/scenarios/tbl-cross.toml", "--duration", "5"])
        delivered: list[Odometry] = []
        _wait_for_link(base, delivered)
        while emu.poll() is None:  # to its --duration, however long its start took
            _collect(base, 0.5, delivered)
        _collect(base, 0.3, delivered)
        stop(emu)
        base.close()
    report = json.loads(stats_path.read_text())
    injected = report["injected"]
    truth = {t["seq"]: t for t in _truth(truth_path)}
    for o in delivered:
        assert [round(o.x * 1000), round(o.y * 1000), round(o.yaw * 1000)] == truth[o.seq]["wire"]
    stats = base.stats()
    assert injected["dropped_frames"] > 10
    assert stats["malformed_unpaired"] == injected["samples_half_lost"]
    # A loss shows as a gap between samples that arrived: those before the first or
    # after the last delivered sample cannot be seen, whenever the run started or ended.
    first, last = delivered[0].seq, delivered[-1].seq
    assert stats["lost"] == sum(first < s < last for s in report["lost_seqs"])
    arrived_last = max(s for s in truth if s not in report["lost_seqs"])
    assert last == arrived_last  # absolute pose: the final one is right
    assert [round(delivered[-1].x * 1000), round(delivered[-1].y * 1000)] == \
        truth[arrived_last]["wire"][:2]


def test_virtual_can_error_frames_and_seq_jump_in_process() -> None:
    robot = build_sim_robot(lockstep_config(realtime=True), camera=False)
    side = CanSide("virtual", "xr4000-test-bus")
    emu = Emulator(side, SimSource(robot), FaultPlan(error_frame_rate=0.1, seq_jump_at_s=(1.0,)),
                   seed=5)
    base = Xr4000CanBase(Xr4000CanSettings(interface="virtual", channel="xr4000-test-bus"),
                         None)
    base.open()
    stop_event = threading.Event()
    thread = threading.Thread(target=emu.run, args=(stop_event, 2.5))
    thread.start()
    delivered: list[Odometry] = []
    _collect(base, 3.0, delivered)
    thread.join()
    base.close()
    side.close()
    stats = base.stats()
    assert stats["malformed_error_frame"] == emu.faults.injected["error_frames"] > 0
    # CAN carries a 16-bit sequence; a jump of 1000 is rejected, then followed (resync).
    assert stats["rejected_seq_jump"] >= 1 and stats["rejected_resync"] == 1
    assert delivered[-1].seq > 1000


def test_serial_port_unplugged_and_back(tmp_path: Path) -> None:
    with pty_pair(tmp_path) as pair:
        base = _serial(pair.b)
        base.open()
        emu = emulator(["--serial", str(pair.a)])
        got: list[Odometry] = []
        _wait_for_link(base, got)
        pair.stop()  # the cable is pulled
        t0 = time.monotonic()
        with pytest.raises((DeviceIOError, DeviceTimeoutError)):
            while True:
                base.read(0.2)
        assert time.monotonic() - t0 < 1.0
        base.close()
        stop(emu)
        pair.start()  # plugged back in at the same paths
        t_back = time.monotonic()
        emu = emulator(["--serial", str(pair.a)])
        while True:
            try:
                base.open()
                break
            except Exception:
                time.sleep(0.1)
        samples = base.read(2.0)
        assert samples and time.monotonic() - t_back < 2.0 + 1.5  # + the emulator's start-up
        base.close()
        stop(emu)
