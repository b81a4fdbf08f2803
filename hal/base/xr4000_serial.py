"""The `xr4000-serial` base backend: the XR4000 link over a serial line (pyserial)."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Mapping
from typing import Any

import serial

from hal.base.settings import Xr4000SerialSettings
from hal.base.xr4000_link import Xr4000Link
from hal.base.xr4000_protocol import (
    AckMsg,
    Message,
    MovCmd,
    NakMsg,
    SerialLineParser,
    StpCmd,
    VelCmd,
    encode_message,
)
from kernel.errors import DeviceInitError, DeviceIOError, DeviceTimeoutError

log = logging.getLogger(__name__)


class Xr4000SerialBase(Xr4000Link):
    backend = "xr4000-serial"

    def __init__(self, settings: Xr4000SerialSettings, context: Any) -> None:
        rate = context.config.base.sim.odometry_rate_hz if context and context.config else 50.0
        super().__init__(settings.port, settings.silence_timeout_s, settings.command_timeout_s,
                         odometry_rate_hz=rate)
        self._settings = settings
        self._port: serial.Serial | None = None
        self._parser = SerialLineParser()
        self._write_lock = threading.Lock()
        self._answers: dict[int, AckMsg | NakMsg] = {}
        self._moves: set[int] = set()  # ids of moves not yet answered
        self._next_id = 1

    def _connect(self) -> None:
        try:
            self._port = serial.Serial(self._settings.port, self._settings.baud_rate,
                                       timeout=0.05, write_timeout=0.5)
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceInitError(f"cannot open serial port {self._settings.port}: {e}") from e
        self._parser = SerialLineParser()

    def _disconnect(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def _receive(self) -> list[object]:
        port = self._port
        if port is None:
            raise DeviceIOError(f"{self._settings.port} is closed")
        try:
            data = port.read(max(1, port.in_waiting))
        except (serial.SerialException, OSError) as e:
            raise DeviceIOError(f"serial port {self._settings.port} failed (unplugged?): "
                                f"{e}") from e
        return list(self._parser.feed(data)) if data else []

    def _parser_errors(self) -> Mapping[str, int]:
        return dict(self._parser.errors)

    def _answer(self, msg: object) -> None:
        if isinstance(msg, AckMsg | NakMsg):
            with self._cond:
                if isinstance(msg, AckMsg) and msg.id in self._moves:
                    self._moves.discard(msg.id)
                    self._move_accepted()
                self._answers[msg.id] = msg
                self._cond.notify_all()

    def _send(self, make: Any, what: str, move: bool = False) -> None:
        """Send a command and wait for its answer; unanswered within the command timeout
        it is sent again with the same id, up to ``command_retries`` times (the
        controller answers a repeated id again without executing it twice, design §12),
        then DeviceTimeoutError."""
        self._check_ready()
        with self._write_lock:
            cid = self._next_id
            self._next_id = self._next_id % 1_000_000 + 1
        msg: Message = make(cid)
        if move:
            with self._cond:
                self._moves.add(cid)
        for attempt in range(self._settings.command_retries + 1):
            if attempt:
                self.counters["command_resends"] += 1
                log.warning("%s: no answer to %s (id %d) within %.2f s: sent again",
                            self._settings.port, what, cid, self._command_timeout_s)
            with self._write_lock:
                try:
                    assert self._port is not None  # _check_ready passed
                    self._port.write(encode_message(msg))
                except (serial.SerialException, OSError) as e:
                    raise DeviceIOError(f"serial port {self._settings.port}: cannot send: "
                                        f"{e}") from e
            answer = self._await_answer(cid)
            if answer is not None:
                break
        else:
            with self._cond:
                self._moves.discard(cid)
            self.counters["command_timeouts"] += 1
            raise DeviceTimeoutError(
                f"{self._settings.port}: no ACK/NAK for {what} (id {cid}) within "
                f"{self._command_timeout_s:.2f} s, sent {self._settings.command_retries + 1} "
                "times")
        if isinstance(answer, NakMsg):
            raise self._rejected(what, answer.reason)
        self.counters["acks"] += 1

    def _await_answer(self, cid: int) -> AckMsg | NakMsg | None:
        end = time.monotonic() + self._command_timeout_s
        with self._cond:
            while cid not in self._answers:
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            return self._answers.pop(cid)

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        self._send(lambda i: MovCmd(i, round(dx * 1000), round(dy * 1000),
                                    round(dyaw * 1000), max(1, round(speed * 1000))),
                   f"move ({dx:.3f}, {dy:.3f}, {math.degrees(dyaw):.1f} deg)", move=True)

    def velocity(self, vx: float, vy: float, w: float) -> None:
        self._send(lambda i: VelCmd(i, round(vx * 1000), round(vy * 1000), round(w * 1000)),
                   "velocity")

    def stop(self) -> None:
        self._send(lambda i: StpCmd(i), "stop")
