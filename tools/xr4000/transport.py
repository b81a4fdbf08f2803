"""The emulator's side of the wire: a serial port or a CAN bus."""

from __future__ import annotations

import can
import serial

from hal.base.xr4000_protocol import (
    CMD_MOVE,
    CMD_STOP,
    CMD_VELOCITY,
    CanIds,
    MovCmd,
    SerialLineParser,
    StpCmd,
    VelCmd,
)


class SerialSide:
    def __init__(self, port: str, baud_rate: int = 115200) -> None:
        self.port = serial.Serial(port, baud_rate, timeout=0.0, write_timeout=1.0)
        self.parser = SerialLineParser()

    def write(self, data: bytes) -> None:
        if data:
            self.port.write(data)

    def commands(self) -> list[MovCmd | VelCmd | StpCmd]:
        data = self.port.read(4096)
        return [m for m in self.parser.feed(data) if isinstance(m, MovCmd | VelCmd | StpCmd)]

    def close(self) -> None:
        self.port.close()


class CanSide:
    def __init__(self, interface: str, channel: str, bitrate: int = 500_000,
                 ids: CanIds | None = None) -> None:
        if interface == "udp_multicast":
            raise ValueError("udp_multicast is not allowed: its traffic leaves the machine")
        self.bus = can.Bus(interface=interface, channel=channel, bitrate=bitrate)
        self.ids = ids or CanIds()
        self.counter = 0

    def send(self, arbitration_id: int, data: bytes, *, error: bool = False) -> None:
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=data,
                                  is_extended_id=False, is_error_frame=error))

    def commands(self) -> list[tuple[int, bytes]]:
        """(command kind, payload) of the command frames received."""
        out = []
        msg = self.bus.recv(timeout=0.0)
        while msg is not None:
            kind = {self.ids.move: CMD_MOVE, self.ids.velocity: CMD_VELOCITY,
                    self.ids.stop: CMD_STOP}.get(msg.arbitration_id)
            if kind is not None and not msg.is_error_frame:
                out.append((kind, bytes(msg.data)))
            msg = self.bus.recv(timeout=0.0)
        return out

    def close(self) -> None:
        self.bus.shutdown()
