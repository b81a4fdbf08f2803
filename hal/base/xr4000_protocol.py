"""The XR4000 base-controller link (docs/design.md §12): codec, parsers and validation, both
transports. Pure: bytes and frames in, messages and counters out.

Serial (115200 8N1): ASCII lines ``$TYPE,f1,f2,...*HH\\r\\n``, HH = XOR of the bytes between
``$`` and ``*`` (NMEA style).
  controller -> daemon: ``$ODO,seq,t_ms,x_mm,y_mm,yaw_mrad``, ``$STA,seq,flags_hex``,
                        ``$ACK,id``, ``$NAK,id,reason``
  daemon -> controller: ``$MOV,id,dx_mm,dy_mm,dyaw_mrad,v_mm_s``, ``$VEL,id,vx,vy,w``,
                        ``$STP,id``
CAN (500 kbit/s, little-endian):
  0x181 odometry position  int32 x_mm, int32 y_mm
  0x281 heading and status int32 yaw_mrad, uint16 seq, uint8 flags, uint8 reserved
  0x201 relative move      int16 dx_mm, int16 dy_mm, int16 dyaw_mrad, uint16 v_mm_s
  0x202 velocity           int16 vx_mm_s, int16 vy_mm_s, int16 w_mrad_s
  0x200 stop               (empty)
  0x182 command answer     uint16 counter, uint8 command (0 stop, 1 move, 2 velocity),
                           uint8 result (0 accepted, else the NAK reason code)
  docs/design.md §12 gives CAN no acknowledgement; 0x182 is this project's: the controller answers
  every command frame, counting them, so the daemon knows each was received and accepted.

Anything malformed is counted by reason and dropped, never trusted.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from dataclasses import dataclass

MAX_LINE = 96  # longest valid line is about 60 bytes
MAX_POS_MM = 10_000_000  # 10 km: anything beyond is corrupt
MAX_YAW_MRAD = 3142  # wrapped to (-pi, pi]
MAX_SEQ = 1 << 32


@dataclass(frozen=True)
class OdoMsg:
    seq: int
    t_ms: int | None  # None on CAN (no controller time on the wire)
    x_mm: int
    y_mm: int
    yaw_mrad: int


@dataclass(frozen=True)
class StaMsg:
    seq: int
    flags: int


@dataclass(frozen=True)
class AckMsg:
    id: int


@dataclass(frozen=True)
class NakMsg:
    id: int
    reason: str


@dataclass(frozen=True)
class MovCmd:
    id: int
    dx_mm: int
    dy_mm: int
    dyaw_mrad: int
    v_mm_s: int


@dataclass(frozen=True)
class VelCmd:
    id: int
    vx_mm_s: int
    vy_mm_s: int
    w_mrad_s: int


@dataclass(frozen=True)
class StpCmd:
    id: int


Message = OdoMsg | StaMsg | AckMsg | NakMsg | MovCmd | VelCmd | StpCmd


# ---------------------------------------------------------------------------- serial
def checksum(body: bytes) -> int:
    """XOR of the bytes between ``$`` and ``*``."""
    c = 0
    for b in body:
        c ^= b
    return c


def encode_line(kind: str, *fields: int | str) -> bytes:
    body = ",".join([kind, *(str(f) for f in fields)]).encode("ascii")
    return b"$" + body + b"*" + f"{checksum(body):02X}".encode() + b"\r\n"


def encode_message(msg: Message) -> bytes:
    match msg:
        case OdoMsg():
            return encode_line("ODO", msg.seq, msg.t_ms if msg.t_ms is not None else 0,
                               msg.x_mm, msg.y_mm, msg.yaw_mrad)
        case StaMsg():
            return encode_line("STA", msg.seq, f"{msg.flags:X}")
        case AckMsg():
            return encode_line("ACK", msg.id)
        case NakMsg():
            return encode_line("NAK", msg.id, msg.reason)
        case MovCmd():
            return encode_line("MOV", msg.id, msg.dx_mm, msg.dy_mm, msg.dyaw_mrad, msg.v_mm_s)
        case VelCmd():
            return encode_line("VEL", msg.id, msg.vx_mm_s, msg.vy_mm_s, msg.w_mrad_s)
        case StpCmd():
            return encode_line("STP", msg.id)
    raise TypeError(f"not an XR4000 message: {msg!r}")


def _int(text: str, lo: int, hi: int) -> int:
    """A decimal integer in [lo, hi]; ValueError otherwise (no '+', no spaces, no '_')."""
    if not text or len(text) > 12 or not (text.isdigit() or (text[0] == "-" and
                                                               text[1:].isdigit())):
        raise ValueError(text)
    value = int(text)
    if not lo <= value <= hi:
        raise OverflowError(text)
    return value


_I32 = (-(1 << 31), (1 << 31) - 1)
_I16 = (-(1 << 15), (1 << 15) - 1)
_U16 = (0, (1 << 16) - 1)


def decode_fields(kind: str, fields: list[str]) -> Message:
    """One checksummed line's fields into a message; ValueError (bad field) or
    OverflowError (out of range) when they do not fit the type."""
    n = len(fields)
    if kind == "ODO" and n == 5:
        return OdoMsg(_int(fields[0], 0, MAX_SEQ - 1), _int(fields[1], 0, (1 << 63) - 1),
                      _int(fields[2], -MAX_POS_MM, MAX_POS_MM),
                      _int(fields[3], -MAX_POS_MM, MAX_POS_MM),
                      _int(fields[4], -MAX_YAW_MRAD, MAX_YAW_MRAD))
    if kind == "STA" and n == 2:
        flags = fields[1]
        if not flags or len(flags) > 2 or any(c not in "0123456789ABCDEFabcdef" for c in flags):
            raise ValueError(flags)
        return StaMsg(_int(fields[0], 0, MAX_SEQ - 1), int(flags, 16))
    if kind == "ACK" and n == 1:
        return AckMsg(_int(fields[0], 0, MAX_SEQ - 1))
    if kind == "NAK" and n == 2:
        return NakMsg(_int(fields[0], 0, MAX_SEQ - 1), fields[1][:32])
    if kind == "MOV" and n == 5:
        return MovCmd(_int(fields[0], 0, MAX_SEQ - 1), _int(fields[1], *_I32),
                      _int(fields[2], *_I32), _int(fields[3], *_I32), _int(fields[4], 0, 10_000))
    if kind == "VEL" and n == 4:
        return VelCmd(_int(fields[0], 0, MAX_SEQ - 1), _int(fields[1], *_I32),
                      _int(fields[2], *_I32), _int(fields[3], *_I32))
    if kind == "STP" and n == 1:
        return StpCmd(_int(fields[0], 0, MAX_SEQ - 1))
    raise ValueError(f"{kind} with {n} fields")


class SerialLineParser:
    """Bytes in (any chunking), messages out. Malformed input is counted by reason:
    ``garbage`` (bytes outside a line), ``too_long``, ``truncated`` (a line cut short by
    the next ``$``), ``bad_checksum``, ``bad_format``, ``non_ascii``, ``bad_fields``,
    ``out_of_range``, ``unknown``."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._in_line = False
        self.errors: Counter[str] = Counter()
        self.lines = 0

    def feed(self, data: bytes) -> list[Message]:
        out: list[Message] = []
        for byte in data:
            if byte == 0x24:  # '$'
                if self._in_line:
                    self.errors["truncated"] += 1
                self._buf.clear()
                self._in_line = True
            elif not self._in_line:
                if byte not in (0x0D, 0x0A):
                    self.errors["garbage"] += 1  # counted per byte outside any line
            elif byte == 0x0A:  # '\n' ends a line
                self._in_line = False
                msg = self._line(bytes(self._buf))
                self._buf.clear()
                if msg is not None:
                    out.append(msg)
            elif len(self._buf) >= MAX_LINE:
                self.errors["too_long"] += 1
                self._in_line = False
                self._buf.clear()
            else:
                self._buf.append(byte)
        return out

    def _line(self, line: bytes) -> Message | None:
        self.lines += 1
        line = line.rstrip(b"\r")
        star = line.rfind(b"*")
        if star < 0 or len(line) - star != 3:
            self.errors["bad_format"] += 1
            return None
        body, given = line[:star], line[star + 1:]
        if any(c not in b"0123456789ABCDEF" for c in given):  # two upper-case hex digits
            self.errors["bad_format"] += 1
            return None
        expected = int(given, 16)
        if checksum(body) != expected:
            self.errors["bad_checksum"] += 1
            return None
        try:
            text = body.decode("ascii")
        except UnicodeDecodeError:
            self.errors["non_ascii"] += 1
            return None
        kind, *fields = text.split(",")
        if kind not in ("ODO", "STA", "ACK", "NAK", "MOV", "VEL", "STP"):
            self.errors["unknown"] += 1
            return None
        try:
            return decode_fields(kind, fields)
        except OverflowError:
            self.errors["out_of_range"] += 1
        except ValueError:
            self.errors["bad_fields"] += 1
        return None


# ---------------------------------------------------------------------------- CAN
@dataclass(frozen=True)
class CanIds:
    odometry_position: int = 0x181
    odometry_heading: int = 0x281
    answer: int = 0x182
    move: int = 0x201
    velocity: int = 0x202
    stop: int = 0x200


CMD_STOP, CMD_MOVE, CMD_VELOCITY = 0, 1, 2
NAK_REASONS = {1: "estop", 2: "busy", 3: "invalid", 4: "cannot-move"}


@dataclass(frozen=True)
class CanAnswer:
    counter: int
    command: int
    result: int


def can_position(x_mm: int, y_mm: int) -> bytes:
    return struct.pack("<ii", x_mm, y_mm)


def can_heading(yaw_mrad: int, seq: int, flags: int) -> bytes:
    return struct.pack("<iHBB", yaw_mrad, seq & 0xFFFF, flags & 0xFF, 0)


def can_move(dx_mm: int, dy_mm: int, dyaw_mrad: int, v_mm_s: int) -> bytes:
    return struct.pack("<hhhH", dx_mm, dy_mm, dyaw_mrad, v_mm_s)


def can_velocity(vx: int, vy: int, w: int) -> bytes:
    return struct.pack("<hhh", vx, vy, w)


def can_answer(counter: int, command: int, result: int) -> bytes:
    return struct.pack("<HBB", counter & 0xFFFF, command, result)


class CanFrameDecoder:
    """CAN frames in, odometry/status/answers out.

    The position frame (0x181) carries no sequence number, so it is paired with the heading
    frame (0x281) that follows it (the controller sends both back to back; CAN keeps their
    order). When that heading's sequence number is the one after the last heading's, the
    position arrived inside its sample and pairs whatever the host's receive timestamps
    say (a loaded host or an slcan adapter read byte by byte spreads them). Only after a
    lost heading could the position belong to the lost sample; then it must lie within
    ``max_pair_gap_s`` of the heading (samples are a period apart). A heading without a
    fresh position, or a position overtaken by another or gone stale, is counted
    (``unpaired``) and dropped, so one sample's position is never joined to another's
    heading. Wrong lengths
    (``bad_length``), out-of-range values (``out_of_range``), error frames (``error_frame``),
    remote frames and unknown ids (``unknown``) are counted too."""

    def __init__(self, ids: CanIds | None = None, max_pair_gap_s: float = 0.008) -> None:
        self.ids = ids or CanIds()
        self.max_pair_gap_s = max_pair_gap_s
        self._position: tuple[int, int, float] | None = None
        self._last_heading_seq: int | None = None
        self.errors: Counter[str] = Counter()

    def feed(self, arbitration_id: int, data: bytes, *, timestamp: float = 0.0,
             is_error: bool = False, is_remote: bool = False) -> list[Message | CanAnswer]:
        if is_error:
            self.errors["error_frame"] += 1
            return []
        if is_remote:
            self.errors["unknown"] += 1
            return []
        ids = self.ids
        if arbitration_id == ids.odometry_position:
            if len(data) != 8:
                self.errors["bad_length"] += 1
                return []
            x, y = struct.unpack("<ii", data)
            if abs(x) > MAX_POS_MM or abs(y) > MAX_POS_MM:
                self.errors["out_of_range"] += 1
                self._position = None
                return []
            if self._position is not None:
                self.errors["unpaired"] += 1
            self._position = (x, y, timestamp)
            return []
        if arbitration_id == ids.odometry_heading:
            if len(data) != 8:
                self.errors["bad_length"] += 1
                return []
            yaw, seq, flags, reserved = struct.unpack("<iHBB", data)
            position, self._position = self._position, None
            if abs(yaw) > MAX_YAW_MRAD or reserved != 0 or flags > 0x0F:
                self.errors["out_of_range"] += 1
                return []
            out: list[Message | CanAnswer] = [StaMsg(seq, flags)]
            previous, self._last_heading_seq = self._last_heading_seq, seq
            next_in_line = previous is not None and (seq - previous) & 0xFFFF == 1
            if position is not None and not next_in_line \
                    and timestamp - position[2] > self.max_pair_gap_s:
                self.errors["unpaired"] += 1  # a stale position: another sample's
                position = None
            if position is None:
                self.errors["unpaired"] += 1
            else:
                out.insert(0, OdoMsg(seq, None, position[0], position[1], yaw))
            return out
        if arbitration_id == ids.answer:
            if len(data) != 4:
                self.errors["bad_length"] += 1
                return []
            return [CanAnswer(*struct.unpack("<HBB", data))]
        self.errors["unknown"] += 1
        return []


# ---------------------------------------------------------------------------- validation
class OdometryValidator:
    """Sequence and time checks on decoded odometry (both transports).

    Accepts a sample whose sequence number advances by k >= 1 and, on serial, whose
    controller time advances by about k odometry periods: k − 1 samples were lost on the
    wire (counted as ``lost``). Rejects and counts a repeated or backward sequence number
    (``seq_backwards``), controller time going backwards (``time_backwards``), and a jump
    whose time does not match (``seq_jump``). A controller that really restarted its
    counters is followed again after ``resync_after`` mutually consistent samples
    (``resync``). Positions that move faster than physically possible are rejected
    (``implausible``)."""

    def __init__(self, period_ms: float, max_speed_mm_s: float = 3000.0,
                 resync_after: int = 5, seq_modulo: int = MAX_SEQ) -> None:
        self.period_ms = period_ms
        self.max_speed_mm_s = max_speed_mm_s
        self.resync_after = resync_after
        self.seq_modulo = seq_modulo
        self.last: OdoMsg | None = None
        self.errors: Counter[str] = Counter()
        self.lost = 0
        self._candidate: list[OdoMsg] = []

    def _step(self, a: OdoMsg, b: OdoMsg) -> int:
        return (b.seq - a.seq) % self.seq_modulo

    def _consistent(self, a: OdoMsg, b: OdoMsg) -> str | None:
        k = self._step(a, b)
        if k == 0 or k > self.seq_modulo // 2:
            return "seq_backwards"
        if a.t_ms is not None and b.t_ms is not None:
            dt = b.t_ms - a.t_ms
            if dt < 0:
                return "time_backwards"
            if abs(dt - k * self.period_ms) > 0.5 * self.period_ms + 5:
                return "seq_jump"
            elapsed_ms = max(dt, self.period_ms)
        else:
            if k > 1000:  # CAN: no time on the wire; a jump this large is no loss
                return "seq_jump"
            elapsed_ms = k * self.period_ms
        moved = math.hypot(b.x_mm - a.x_mm, b.y_mm - a.y_mm)
        if moved > self.max_speed_mm_s * elapsed_ms / 1000.0 + 20:
            return "implausible"
        return None

    def accept(self, msg: OdoMsg) -> bool:
        if self.last is None:
            self.last = msg
            return True
        problem = self._consistent(self.last, msg)
        if problem is None:
            self.lost += self._step(self.last, msg) - 1
            self.last = msg
            self._candidate.clear()
            return True
        self.errors[problem] += 1
        # A restarted controller: follow the new sequence once it is self-consistent.
        if self._candidate and self._consistent(self._candidate[-1], msg) is not None:
            self._candidate.clear()
        self._candidate.append(msg)
        if len(self._candidate) >= self.resync_after:
            self.errors["resync"] += 1
            self.last = msg
            self._candidate.clear()
        return False
