"""The XR4000 wire protocol: codec, parsers and validation, piece by piece (docs/design.md §12)."""

from __future__ import annotations

import pytest

from hal.base.xr4000_protocol import (
    AckMsg,
    CanFrameDecoder,
    MovCmd,
    NakMsg,
    OdometryValidator,
    OdoMsg,
    SerialLineParser,
    StaMsg,
    StpCmd,
    VelCmd,
    can_heading,
    can_position,
    checksum,
    encode_message,
)

MESSAGES = [OdoMsg(7, 140, -1200, 35, -3141), StaMsg(3, 0x0B), AckMsg(12), NakMsg(13, "estop"),
            MovCmd(14, 500, -500, 0, 200), VelCmd(15, 100, 0, -300), StpCmd(16)]


def test_checksum_is_nmea_xor() -> None:
    line = encode_message(OdoMsg(1, 20, 0, 0, 0))
    body = line[1:line.index(b"*")]
    x = 0
    for b in body:
        x ^= b
    assert line.endswith(f"*{x:02X}\r\n".encode())
    assert line.startswith(b"$ODO,1,20,0,0,0*")


@pytest.mark.parametrize("msg", MESSAGES)
def test_round_trip_in_any_chunking(msg: object) -> None:
    data = encode_message(msg)  # type: ignore[arg-type]
    for size in (1, 3, len(data)):
        parser = SerialLineParser()
        out = []
        for i in range(0, len(data), size):
            out += parser.feed(data[i:i + size])
        assert out == [msg] and not parser.errors


@pytest.mark.parametrize(("data", "reason"), [
    (b"xx\x00\xff", "garbage"),
    (b"$ODO,1,20,0,0,0*00\r\n", "bad_checksum"),
    (b"$ODO,1,20,0,0$ODO,1,20,0,0,0*6B\r\n", "truncated"),
    (b"$" + b"1" * 200 + b"\r\n", "too_long"),
    (b"$ODO,1,20,0,0,0\r\n", "bad_format"),
    (b"$ODO,1,20,0,0,0*Z1\r\n", "bad_format"),
    (b"$ODO,1,20,0,0,0*6b\r\n", "bad_format"),  # the checksum is upper-case hex
])
def test_malformed_lines_are_counted(data: bytes, reason: str) -> None:
    parser = SerialLineParser()
    out = parser.feed(data)
    # Only the complete line after a truncated one gets through.
    assert out == ([OdoMsg(1, 20, 0, 0, 0)] if reason == "truncated" else [])
    assert parser.errors[reason] >= 1


def _line(body: str) -> bytes:
    b = body.encode()
    return b"$" + b + f"*{checksum(b):02X}\r\n".encode()


@pytest.mark.parametrize(("body", "reason"), [
    ("ODO,1,20,0,0", "bad_fields"),  # too few fields
    ("ODO,1,20,0,0,x", "bad_fields"),
    ("ODO,1,20,+5,0,0", "bad_fields"),
    ("ODO,1,20,0,0,4000", "out_of_range"),  # yaw beyond pi
    ("ODO,1,20,99999999999,0,0", "out_of_range"),
    ("STA,1,1FF", "bad_fields"),
    ("FOO,1", "unknown"),
])
def test_checksummed_but_invalid_lines(body: str, reason: str) -> None:
    parser = SerialLineParser()
    assert parser.feed(_line(body)) == []
    assert parser.errors[reason] == 1


def test_non_ascii_body_is_refused() -> None:
    parser = SerialLineParser()
    assert parser.feed(_line("ACK,1").replace(b"ACK", b"A\xc3K")) == []
    assert sum(parser.errors.values()) == 1


def _odo(seq: int, t_ms: int | None, x: int = 0) -> OdoMsg:
    return OdoMsg(seq, t_ms, x, 0, 0)


def test_validator_counts_losses_and_rejects_inconsistencies() -> None:
    v = OdometryValidator(period_ms=20.0)
    assert v.accept(_odo(1, 0))
    assert v.accept(_odo(2, 20))
    assert v.accept(_odo(5, 80)) and v.lost == 2  # two lines lost on the wire
    assert not v.accept(_odo(5, 80)) and v.errors["seq_backwards"] == 1
    assert not v.accept(_odo(4, 100)) and v.errors["seq_backwards"] == 2
    assert not v.accept(_odo(6, 40)) and v.errors["time_backwards"] == 1
    assert not v.accept(_odo(1006, 100)) and v.errors["seq_jump"] == 1
    assert not v.accept(_odo(6, 100, x=5000)) and v.errors["implausible"] == 1
    assert v.accept(_odo(6, 100))


def test_validator_follows_a_restarted_controller() -> None:
    v = OdometryValidator(period_ms=20.0, resync_after=3)
    for i in range(1, 5):
        assert v.accept(_odo(i, 20 * i))
    results = [v.accept(_odo(i, 20 * i)) for i in range(1, 6)]  # counters restarted
    assert results == [False, False, False, True, True]
    assert v.errors["resync"] == 1


def test_can_pairs_position_with_the_next_heading_only() -> None:
    d = CanFrameDecoder()
    assert d.feed(0x181, can_position(100, -200), timestamp=0.0) == []
    out = d.feed(0x281, can_heading(50, 7, 0x2), timestamp=0.001)
    assert out == [OdoMsg(7, None, 100, -200, 50), StaMsg(7, 0x2)]
    # A heading without a position: status only, counted.
    assert d.feed(0x281, can_heading(50, 8, 0), timestamp=0.02) == [StaMsg(8, 0)]
    assert d.errors["unpaired"] == 1
    # A stale position (its heading was lost, the next position too) is not reused.
    d.feed(0x181, can_position(1, 1), timestamp=0.04)
    assert d.feed(0x281, can_heading(0, 10, 0), timestamp=0.061) == [StaMsg(10, 0)]
    assert d.errors["unpaired"] == 3
    # The next sample in line pairs however late its heading is received (a loaded host).
    d.feed(0x181, can_position(2, 2), timestamp=0.08)
    assert d.feed(0x281, can_heading(0, 11, 0), timestamp=0.2)[0] == OdoMsg(11, None, 2, 2, 0)
    assert d.errors["unpaired"] == 3


@pytest.mark.parametrize(("frame", "reason"), [
    ((0x181, b"\x00" * 7), "bad_length"),
    ((0x281, b"\x00" * 9), "bad_length"),
    ((0x281, can_heading(5000, 1, 0)), "out_of_range"),
    ((0x281, bytes(can_heading(0, 1, 0)[:7]) + b"\x01"), "out_of_range"),  # reserved != 0
    ((0x123, b""), "unknown"),
])
def test_can_malformed_frames_are_counted(frame: tuple[int, bytes], reason: str) -> None:
    d = CanFrameDecoder()
    d.feed(0x181, can_position(0, 0))
    assert not [m for m in d.feed(*frame) if isinstance(m, OdoMsg)]
    assert d.errors[reason] == 1


def test_can_error_and_remote_frames() -> None:
    d = CanFrameDecoder()
    assert d.feed(0x181, b"", is_error=True) == [] and d.errors["error_frame"] == 1
    assert d.feed(0x181, b"", is_remote=True) == [] and d.errors["unknown"] == 1
