"""The `xr4000-can` base backend: the XR4000 link over CAN (python-can).

Any python-can interface: ``socketcan`` on the robot, ``slcan`` (a USB-CAN adapter's serial
protocol; a socat pseudo-terminal pair in tests) or ``virtual`` inside one process.
Commands are confirmed by the controller's answer frame (0x182, see xr4000_protocol).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Mapping
from typing import Any

import can

from hal.base.settings import Xr4000CanSettings
from hal.base.xr4000_link import Xr4000Link
from hal.base.xr4000_protocol import (
    CMD_MOVE,
    CMD_STOP,
    CMD_VELOCITY,
    NAK_REASONS,
    CanAnswer,
    CanFrameDecoder,
    CanIds,
    can_move,
    can_velocity,
)
from kernel.errors import (
    BackendUnavailableError,
    DeviceInitError,
    DeviceIOError,
    DeviceTimeoutError,
)

FORBIDDEN_INTERFACES = {"udp_multicast"}  # its traffic leaves the machine


def _clamp16(v: int, signed: bool = True) -> int:
    lo, hi = (-(1 << 15), (1 << 15) - 1) if signed else (0, (1 << 16) - 1)
    if not lo <= v <= hi:
        raise ValueError(f"{v} does not fit the 16-bit CAN field")
    return v


log = logging.getLogger(__name__)


class Xr4000CanBase(Xr4000Link):
    backend = "xr4000-can"

    def __init__(self, settings: Xr4000CanSettings, context: Any) -> None:
        rate = context.config.base.sim.odometry_rate_hz if context and context.config else 50.0
        super().__init__(f"{settings.interface}:{settings.channel}", settings.silence_timeout_s,
                         settings.command_timeout_s, odometry_rate_hz=rate, seq_modulo=1 << 16)
        if settings.interface in FORBIDDEN_INTERFACES:
            raise DeviceInitError(f"base.xr4000_can.interface {settings.interface!r} is not "
                                  "allowed: its traffic leaves the machine")
        self._settings = settings
        self._ids = CanIds(settings.odometry_position_id, settings.odometry_heading_id,
                           settings.answer_id, settings.move_id, settings.velocity_id,
                           settings.stop_id)
        self._bus: can.BusABC | None = None
        self._decoder = CanFrameDecoder(self._ids)
        self._write_lock = threading.Lock()
        self._answers: list[CanAnswer] = []

    def _connect(self) -> None:
        s = self._settings
        try:
            self._bus = can.Bus(interface=s.interface, channel=s.channel, bitrate=s.bitrate,
                                receive_own_messages=False)
        except ImportError as e:
            raise BackendUnavailableError(f"python-can interface {s.interface!r} needs a "
                                          f"package that is missing: {e}") from e
        except (can.CanError, OSError, ValueError) as e:
            raise DeviceInitError(f"cannot open CAN {s.interface}:{s.channel}: {e}") from e
        self._decoder = CanFrameDecoder(self._ids)

    def _disconnect(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def _receive(self) -> list[object]:
        bus = self._bus
        if bus is None:
            raise DeviceIOError(f"{self._device} is closed")
        out: list[object] = []
        try:
            msg = bus.recv(timeout=0.05)
            while msg is not None:
                out += self._decoder.feed(msg.arbitration_id, bytes(msg.data),
                                          timestamp=msg.timestamp,
                                          is_error=msg.is_error_frame,
                                          is_remote=msg.is_remote_frame)
                msg = bus.recv(timeout=0.0)
        except (can.CanError, OSError, ValueError) as e:
            raise DeviceIOError(f"CAN {self._device} failed (bus-off or unplugged?): {e}") from e
        if bus.state == can.BusState.ERROR:
            raise DeviceIOError(f"CAN {self._device} is bus-off")
        return out

    def _parser_errors(self) -> Mapping[str, int]:
        return dict(self._decoder.errors)

    def _answer(self, msg: object) -> None:
        if isinstance(msg, CanAnswer):
            with self._cond:
                if msg.command == CMD_MOVE and msg.result == 0:
                    self._move_accepted()
                self._answers.append(msg)
                self._cond.notify_all()

    def _send(self, arbitration_id: int, data: bytes, command: int, what: str) -> None:
        """Send a command and wait for its answer. Stop and velocity say where the base
        should be, so an unanswered one is sent again, up to ``command_retries`` times; a
        move is relative, and a CAN frame has no id to tell its repeat from a second move,
        so an unanswered move stops the base and raises DeviceTimeoutError (the learn
        that sent it fails saying so, design §12)."""
        self._check_ready()
        retries = 0 if command == CMD_MOVE else self._settings.command_retries
        with self._write_lock:
            for attempt in range(retries + 1):
                if attempt:
                    self.counters["command_resends"] += 1
                    log.warning("CAN %s: no answer to %s within %.2f s: sent again",
                                self._device, what, self._command_timeout_s)
                answer = self._send_once(arbitration_id, data, command, what)
                if answer is not None:
                    break
            else:
                self.counters["command_timeouts"] += 1
                if command == CMD_MOVE:
                    self._stop_quietly()
                raise DeviceTimeoutError(
                    f"CAN {self._device}: no answer to {what} within "
                    f"{self._command_timeout_s:.2f} s"
                    + (", not sent again (a repeated move could be driven twice); the base "
                       "was stopped" if command == CMD_MOVE else f", sent {retries + 1} times"))
        if answer.result != 0:
            raise self._rejected(what, NAK_REASONS.get(answer.result, str(answer.result)))
        self.counters["acks"] += 1

    def _send_once(self, arbitration_id: int, data: bytes, command: int, what: str
                   ) -> CanAnswer | None:
        with self._cond:
            self._answers.clear()
        try:
            assert self._bus is not None  # _check_ready passed
            self._bus.send(can.Message(arbitration_id=arbitration_id, data=data,
                                       is_extended_id=False), timeout=0.2)
        except can.CanError as e:
            raise DeviceIOError(f"CAN {self._device}: cannot send {what}: {e}") from e
        end = time.monotonic() + self._command_timeout_s
        with self._cond:
            while not any(a.command == command for a in self._answers):
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            return next(a for a in self._answers if a.command == command)

    def _stop_quietly(self) -> None:
        """After a move that went unanswered: stop the base, whatever it made of it."""
        for _ in range(self._settings.command_retries + 1):
            try:
                if self._send_once(self._ids.stop, b"", CMD_STOP, "stop") is not None:
                    return
            except DeviceIOError as e:
                log.error("CAN %s: could not stop the base: %s", self._device, e)
                return

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        try:
            data = can_move(_clamp16(round(dx * 1000)), _clamp16(round(dy * 1000)),
                            _clamp16(round(dyaw * 1000)),
                            _clamp16(max(1, round(speed * 1000)), signed=False))
        except ValueError as e:
            raise DeviceIOError(f"move too large for one CAN frame: {e}") from e
        self._send(self._ids.move, data, CMD_MOVE,
                   f"move ({dx:.3f}, {dy:.3f}, {math.degrees(dyaw):.1f} deg)")

    def velocity(self, vx: float, vy: float, w: float) -> None:
        data = can_velocity(_clamp16(round(vx * 1000)), _clamp16(round(vy * 1000)),
                            _clamp16(round(w * 1000)))
        self._send(self._ids.velocity, data, CMD_VELOCITY, "velocity")

    def stop(self) -> None:
        self._send(self._ids.stop, b"", CMD_STOP, "stop")
