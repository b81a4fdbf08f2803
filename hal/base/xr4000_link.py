"""What the serial and CAN XR4000 backends share: a reader thread turning wire messages
into validated odometry, status flags, command answers, and counters for ``status``.

A transport subclass provides ``_connect``, ``_disconnect``, ``_receive`` (wire messages,
blocking at most ~50 ms) and ``_command`` (send one command, wait for its answer).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from collections.abc import Mapping

from hal.base.base import BaseInfo, BaseStatus, Odometry
from hal.base.xr4000_protocol import OdometryValidator, OdoMsg, StaMsg
from kernel.errors import (
    CommandRejectedError,
    DeviceIOError,
    DeviceTimeoutError,
    HalError,
)

log = logging.getLogger(__name__)

MM = 1e-3
MRAD = 1e-3


class Xr4000Link:
    backend = "xr4000"

    def __init__(self, device: str, silence_timeout_s: float, command_timeout_s: float,
                 odometry_rate_hz: float = 50.0, seq_modulo: int = 1 << 32) -> None:
        self._device = device
        self._silence_timeout_s = silence_timeout_s
        self._command_timeout_s = command_timeout_s
        self._rate_hz = odometry_rate_hz
        self._seq_modulo = seq_modulo
        self._cond = threading.Condition()
        self._samples: collections.deque[Odometry] = collections.deque(maxlen=5000)
        self._status = BaseStatus()
        self._fault: HalError | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._last_rx = 0.0
        self._offset_ns: collections.deque[int] = collections.deque(maxlen=200)
        self.counters: collections.Counter[str] = collections.Counter()
        self.validator = OdometryValidator(1000.0 / odometry_rate_hz, seq_modulo=seq_modulo)

    # -------------------------------------------------------- transport hooks
    def _connect(self) -> None:
        raise NotImplementedError

    def _disconnect(self) -> None:
        raise NotImplementedError

    def _receive(self) -> list[object]:
        raise NotImplementedError

    def _parser_errors(self) -> Mapping[str, int]:
        raise NotImplementedError

    # -------------------------------------------------------- Base protocol
    def open(self) -> None:
        self._connect()
        self.validator = OdometryValidator(1000.0 / self._rate_hz, seq_modulo=self._seq_modulo)
        with self._cond:
            self._fault = None
            self._samples.clear()
        self._last_rx = time.monotonic()
        self._running = True
        self._thread = threading.Thread(target=self._reader, name=f"{self.backend}-reader",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(1.0)
            self._thread = None
        try:
            self._disconnect()
        except Exception as e:  # noqa: BLE001 - closing a dead device must not raise
            log.debug("%s close: %s", self._device, e)

    @property
    def info(self) -> BaseInfo:
        return BaseInfo(self.backend, self._device, True, self._rate_hz)

    def read(self, timeout: float) -> list[Odometry]:
        end = time.monotonic() + timeout
        with self._cond:
            while not self._samples and self._fault is None:
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            if self._fault is not None and not self._samples:
                raise self._fault
            out = list(self._samples)
            self._samples.clear()
        if not out:
            silent = time.monotonic() - self._last_rx
            raise DeviceTimeoutError(
                f"{self._device}: no odometry for {silent:.2f} s (link silent or all frames "
                "rejected)")
        return out

    def status(self) -> BaseStatus:
        return self._status

    def stats(self) -> Mapping[str, float]:
        out: dict[str, float] = dict(self.counters)
        out.update({f"malformed_{k}": v for k, v in self._parser_errors().items()})
        out.update({f"rejected_{k}": v for k, v in self.validator.errors.items()})
        out["lost"] = self.validator.lost
        return out

    # -------------------------------------------------------- reader thread
    def _reader(self) -> None:
        while self._running:
            try:
                messages = self._receive()
            except HalError as e:
                self._set_fault(e)
                return
            except Exception as e:  # noqa: BLE001 - any transport failure is a device fault
                self._set_fault(DeviceIOError(f"{self._device}: {type(e).__name__}: {e}"))
                return
            now_ns = time.monotonic_ns()
            for msg in messages:
                self._handle(msg, now_ns)
            if time.monotonic() - self._last_rx > self._silence_timeout_s:
                self.counters["silences"] += 1 if self._last_rx else 0
                self._last_rx = time.monotonic()  # count each silence period once
                log.warning("%s: no valid odometry for %.2f s", self._device,
                            self._silence_timeout_s)

    def _set_fault(self, fault: HalError) -> None:
        log.warning("%s: %s", self._device, fault)
        self.counters["faults"] += 1
        with self._cond:
            self._fault = fault
            self._cond.notify_all()

    def _handle(self, msg: object, now_ns: int) -> None:
        if isinstance(msg, OdoMsg):
            self.counters["received"] += 1
            if not self.validator.accept(msg):
                return
            self._last_rx = time.monotonic()
            stamp = self._stamp(msg, now_ns)
            sample = Odometry(msg.x_mm * MM, msg.y_mm * MM, msg.yaw_mrad * MRAD, stamp, msg.seq)
            self.counters["delivered"] += 1
            with self._cond:
                self._samples.append(sample)
                self._cond.notify_all()
        elif isinstance(msg, StaMsg):
            self._status = BaseStatus.from_flags(msg.flags)
        else:
            self._answer(msg)

    def _stamp(self, msg: OdoMsg, now_ns: int) -> int:
        """Controller time mapped onto our monotonic clock through the smallest recent
        transport delay (serial); reception time where the wire carries no time (CAN)."""
        if msg.t_ms is None:
            return now_ns
        self._offset_ns.append(now_ns - msg.t_ms * 1_000_000)
        return msg.t_ms * 1_000_000 + min(self._offset_ns)

    def _answer(self, msg: object) -> None:
        """A command answer (transport-specific type)."""

    def _move_accepted(self) -> None:
        """The controller answered a move: it is under way from here. Set on the reader
        thread, in the order of the wire, so the status the controller sent before it
        took the move (move_done from the last leg) is never read as this move's end; a
        status sent after the answer says what the move does next."""
        self._status = dataclasses.replace(self._status, moving=True, move_done=False)

    # -------------------------------------------------------- commands
    def _check_ready(self) -> None:
        if self._fault is not None:
            raise self._fault
        if not self._running:
            raise DeviceIOError(f"{self._device} is not open")

    def _rejected(self, what: str, reason: str) -> CommandRejectedError:
        self.counters["naks"] += 1
        return CommandRejectedError(f"{self._device}: {what} refused by the controller: "
                                    f"{reason}")
