"""The controller side of the XR4000 link, driven by the simulated base or a recording.

It sends odometry at the recorded or simulated rate (50 Hz), status on change and at 1 Hz,
executes motion commands on the simulated base and answers them (serial ACK/NAK, CAN answer
frames), and injects the faults of a :class:`FaultPlan`, counting each one.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hal.base.xr4000_protocol import (
    CMD_MOVE,
    CMD_STOP,
    CMD_VELOCITY,
    AckMsg,
    MovCmd,
    NakMsg,
    StpCmd,
    VelCmd,
    can_answer,
    can_heading,
    can_position,
    encode_line,
    encode_message,
)
from hal.recording import TOPIC_ODOMETRY, RecordingReader
from hal.sim.robot import SimRobot
from kernel.errors import CommandRejectedError
from tools.xr4000.faults import FaultInjector, FaultPlan
from tools.xr4000.transport import CanSide, SerialSide

log = logging.getLogger(__name__)

# Serial commands are answered by id: the last this many answers are kept, so a command
# the link sends again (its answer lost) is answered again and not executed twice.
ANSWERS_KEPT = 64

Sample = tuple[int, int, int, int, int]  # seq, t_ms, x_mm, y_mm, yaw_mrad


class SimSource:
    """Odometry and motion from a SimRobot running on the wall clock."""

    def __init__(self, robot: SimRobot) -> None:
        self.robot = robot
        self.can_move = robot.base.can_move

    def poll(self) -> list[tuple[Sample, dict[str, Any]]]:
        """New samples, each with what the truth log records: the true pose and the
        odometry before wire quantisation."""
        self.robot.advance_to(self.robot.wall_time_ns())
        out = []
        for s in self.robot.odometry_samples():
            t_ms = self.robot.elapsed_ns(s.stamp_ns) // 1_000_000  # controller time
            out.append(((s.seq, t_ms, round(s.x * 1000), round(s.y * 1000),
                         round(math.remainder(s.yaw, 2 * math.pi) * 1000)),
                        {"true": self.robot.true_pose(), "odo": (s.x, s.y, s.yaw)}))
        return out

    def flags(self) -> int:
        return self.robot.status().to_flags()

    def move(self, cmd: MovCmd) -> None:
        self.robot.move_relative(cmd.dx_mm / 1000, cmd.dy_mm / 1000, cmd.dyaw_mrad / 1000,
                                 cmd.v_mm_s / 1000)

    def velocity(self, cmd: VelCmd) -> None:
        self.robot.velocity(cmd.vx_mm_s / 1000, cmd.vy_mm_s / 1000, cmd.w_mrad_s / 1000)

    def stop(self) -> None:
        self.robot.stop()


class RecordingSource:
    """Odometry of an MCAP recording at its recorded rate (hardware-in-the-loop replay);
    it cannot move."""

    can_move = False

    def __init__(self, path: str | Path) -> None:
        self._messages: Iterator[Any] = RecordingReader(path).messages([TOPIC_ODOMETRY])
        self._pending = next(self._messages, None)
        self._t0_log = self._pending.log_time_ns if self._pending else 0
        self._t0_wall = time.monotonic_ns()
        self.finished = self._pending is None

    def poll(self) -> list[tuple[Sample, dict[str, Any]]]:
        now = time.monotonic_ns() - self._t0_wall + self._t0_log
        out = []
        while self._pending is not None and self._pending.log_time_ns <= now:
            b = self._pending.body
            t_ms = (int(b["stamp_ns"]) - self._t0_log) // 1_000_000
            out.append(((int(b["seq"]), t_ms, round(b["x"] * 1000), round(b["y"] * 1000),
                         round(b["yaw"] * 1000)), {"odo": (b["x"], b["y"], b["yaw"])}))
            self._pending = next(self._messages, None)
        self.finished = self._pending is None
        return out

    def flags(self) -> int:
        return 0

    def move(self, cmd: MovCmd) -> None:
        raise CommandRejectedError("replaying a recording: cannot move")

    def velocity(self, cmd: VelCmd) -> None:
        raise CommandRejectedError("replaying a recording: cannot move")

    def stop(self) -> None:
        """Nothing moves."""


class Emulator:
    def __init__(self, side: SerialSide | CanSide, source: SimSource | RecordingSource,
                 faults: FaultPlan | None = None, seed: int = 0,
                 truth_out: str | Path | None = None) -> None:
        self.side = side
        self.source = source
        self.faults = FaultInjector(faults or FaultPlan(), np.random.default_rng(seed))
        self.counts: Counter[str] = Counter()
        self.sent: list[Sample] = []  # odometry as put on the wire (before faults)
        self._truth = open(truth_out, "w") if truth_out else None  # noqa: SIM115
        self._status_seq = 0
        self._answered: dict[int, AckMsg | NakMsg] = {}  # serial: the last answers, by id
        self._answers_made = 0
        self.lost_seqs: list[int] = []  # CAN: samples a dropped frame made unusable
        self._last_flags = -1
        self._last_status = 0.0
        self._t0 = time.monotonic()

    # ------------------------------------------------------------------ loop
    def run(self, stop: threading.Event, duration_s: float | None = None) -> None:
        try:
            while not stop.is_set():
                t = time.monotonic() - self._t0
                if duration_s is not None and t >= duration_s:
                    break
                self.step(t)
                stop.wait(0.004)
        finally:
            if self._truth is not None:
                self._truth.close()

    def step(self, t: float) -> None:
        for sample, truth in self.source.poll():
            self._send_odometry(sample, t)
            if self._truth is not None:
                self._truth.write(json.dumps({"seq": sample[0], "t_ms": sample[1],
                                              "wire": sample[2:], **truth}) + "\n")
                self._truth.flush()
        flags = self.source.flags()
        if isinstance(self.side, SerialSide) and (
                flags != self._last_flags or time.monotonic() - self._last_status >= 1.0):
            self._status_seq += 1
            self._emit(encode_line("STA", self._status_seq, f"{flags:X}"), t, odometry=False)
            self._last_flags = flags
            self._last_status = time.monotonic()
        self._handle_commands(t)

    def _send_odometry(self, sample: Sample, t: float) -> None:
        seq, t_ms, x, y, yaw = sample
        self.sent.append(sample)
        self.counts["samples"] += 1
        if self.faults.silent(t):
            self.faults.injected["silenced_samples"] += 1
            return
        seq += self.faults.seq_offset(t)
        if isinstance(self.side, SerialSide):
            if self.faults.chance(self.faults.plan.time_backwards_rate):
                t_ms -= 100
                self.faults.injected["time_backwards"] += 1
            self._emit(encode_line("ODO", seq, t_ms, x, y, yaw), t, odometry=True)
        else:
            self._send_can_sample(seq, x, y, yaw)

    def _emit(self, line: bytes, t: float, odometry: bool) -> None:
        assert isinstance(self.side, SerialSide)
        if self.faults.silent(t):
            return
        self.side.write(self.faults.serial_line(line, odometry))

    def _send_can_sample(self, seq: int, x: int, y: int, yaw: int) -> None:
        assert isinstance(self.side, CanSide)
        ids, f = self.side.ids, self.faults
        drop_pos = f.chance(f.plan.drop_rate)
        drop_head = f.chance(f.plan.drop_rate)
        f.injected["dropped_frames"] += int(drop_pos) + int(drop_head)
        if drop_pos or drop_head:
            f.injected["samples_lost"] += 1
            self.lost_seqs.append(seq)
            if drop_pos != drop_head:
                f.injected["samples_half_lost"] += 1
        if not drop_pos:
            self.side.send(ids.odometry_position, can_position(x, y))
        if f.chance(f.plan.error_frame_rate):
            self.side.send(0, b"", error=True)
            f.injected["error_frames"] += 1
        if not drop_head:
            self.side.send(ids.odometry_heading, can_heading(yaw, seq, self.source.flags()))

    # ------------------------------------------------------------------ commands
    def _handle_commands(self, t: float) -> None:
        if isinstance(self.side, SerialSide):
            for cmd in self.side.commands():
                answer = self._answered.get(cmd.id)
                if answer is None:  # a repeated id is answered again, not executed again
                    reason = self._execute(cmd)
                    answer = AckMsg(cmd.id) if reason is None else NakMsg(cmd.id, reason)
                    self._answered[cmd.id] = answer
                    while len(self._answered) > ANSWERS_KEPT:
                        del self._answered[next(iter(self._answered))]
                else:
                    self.counts["repeated_commands"] += 1
                if not self._answer_dropped():
                    self.side.write(encode_message(answer))
        else:
            for kind, data in self.side.commands():
                reason = self._execute_can(kind, data)
                self.side.counter += 1
                code = 0 if reason is None else {"cannot-move": 4, "invalid": 3}.get(reason, 2)
                if not self._answer_dropped():
                    self.side.send(self.side.ids.answer,
                                   can_answer(self.side.counter, kind, code))

    def _answer_dropped(self) -> bool:
        """The fault plan's ``drop_answers``: this answer (counted from 1) is not sent."""
        self._answers_made += 1
        if self._answers_made in self.faults.plan.drop_answers:
            self.faults.injected["dropped_answers"] += 1
            return True
        return False

    def _execute(self, cmd: MovCmd | VelCmd | StpCmd) -> str | None:
        self.counts[type(cmd).__name__] += 1
        try:
            if isinstance(cmd, MovCmd):
                self.source.move(cmd)
            elif isinstance(cmd, VelCmd):
                self.source.velocity(cmd)
            else:
                self.source.stop()
        except CommandRejectedError:
            return "cannot-move"
        return None

    def _execute_can(self, kind: int, data: bytes) -> str | None:
        import struct

        try:
            if kind == CMD_MOVE:
                dx, dy, dyaw, v = struct.unpack("<hhhH", data)
                return self._execute(MovCmd(0, dx, dy, dyaw, v))
            if kind == CMD_VELOCITY:
                vx, vy, w = struct.unpack("<hhh", data)
                return self._execute(VelCmd(0, vx, vy, w))
            if kind == CMD_STOP and not data:
                return self._execute(StpCmd(0))
        except struct.error:
            pass
        return "invalid"

    def report(self) -> dict[str, Any]:
        return {"counts": dict(self.counts), "injected": dict(self.faults.injected),
                "lost_seqs": list(self.lost_seqs)}
