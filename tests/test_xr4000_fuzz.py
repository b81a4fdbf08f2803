"""Fuzzing the wire parsers (issue 4, point 4): >= 100,000 inputs each, no exception
escapes, and nothing invalid is ever accepted.

Hypothesis chooses each example's seed and mix (noise, mutated valid lines, lines cut and
joined); a batch of inputs is then made from that seed with numpy, which keeps 100,000
inputs per parser within seconds."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hal.base.xr4000_protocol import (
    MAX_POS_MM,
    MAX_YAW_MRAD,
    CanAnswer,
    CanFrameDecoder,
    OdometryValidator,
    OdoMsg,
    SerialLineParser,
    StaMsg,
    can_heading,
    can_position,
    encode_message,
)

BATCH = 100
EXAMPLES = 1_050  # x BATCH = 105,000 inputs per parser
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=True,
                suppress_health_check=list(HealthCheck))  # deterministic: same inputs each run

VALID_LINES = [encode_message(OdoMsg(s, 20 * s, 10 * s, -5 * s, (s * 37) % 3000 - 1500))
               for s in range(1, 40)]


def _valid_odometry(m: OdoMsg) -> bool:
    return (abs(m.x_mm) <= MAX_POS_MM and abs(m.y_mm) <= MAX_POS_MM
            and abs(m.yaw_mrad) <= MAX_YAW_MRAD and m.seq >= 0)


def _serial_inputs(rng: np.random.Generator, mix: tuple[float, float, float]) -> list[bytes]:
    out = []
    kinds = rng.choice(3, size=BATCH, p=mix)
    for kind in kinds:
        if kind == 0:  # raw noise
            out.append(rng.integers(0, 256, int(rng.integers(0, 120)), dtype=np.uint8).tobytes())
        elif kind == 1:  # a valid line with 1-3 bytes changed
            buf = bytearray(VALID_LINES[int(rng.integers(len(VALID_LINES)))])
            for _ in range(int(rng.integers(1, 4))):
                buf[int(rng.integers(len(buf)))] = int(rng.integers(256))
            out.append(bytes(buf))
        else:  # two lines joined and cut anywhere
            a = VALID_LINES[int(rng.integers(len(VALID_LINES)))]
            b = VALID_LINES[int(rng.integers(len(VALID_LINES)))]
            out.append((a + b)[: int(rng.integers(0, len(a) + len(b) + 1))])
    return out


mixes = st.sampled_from([(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (0.3, 0.4, 0.3)])


def test_serial_parser_fuzz() -> None:
    seen = [0]

    @FUZZ
    @given(st.integers(0, 2**63), mixes)
    def run(seed: int, mix: tuple[float, float, float]) -> None:
        parser = SerialLineParser()
        validator = OdometryValidator(period_ms=20.0)
        stream = b""
        last: OdoMsg | None = None
        last_resyncs = [0]
        for data in _serial_inputs(np.random.default_rng(seed), mix):
            seen[0] += 1
            stream += data
            for msg in parser.feed(data):
                if not isinstance(msg, OdoMsg):
                    continue
                assert _valid_odometry(msg)
                # What is accepted was on the wire as one whole, correctly summed line.
                assert encode_message(msg).rstrip(b"\r\n") + b"\n" in stream.replace(
                    b"\r\n", b"\n")
                resyncs = validator.errors["resync"]
                if validator.accept(msg):
                    if last is not None and resyncs == last_resyncs[0]:
                        # accepted samples move forward in seq and time (unless the
                        # validator followed a restarted controller in between)
                        assert msg.seq != last.seq
                        assert msg.t_ms is not None and last.t_ms is not None
                        assert msg.t_ms >= last.t_ms
                    last = msg
                    last_resyncs[0] = validator.errors["resync"]

    run()
    assert seen[0] >= 100_000


def _can_frames(rng: np.random.Generator) -> list[tuple[int, bytes, bool, bool, float]]:
    out = []
    t = 0.0
    for _ in range(BATCH):
        t += float(rng.uniform(0.0, 0.03))
        kind = int(rng.integers(4))
        if kind == 0:
            arb = int(rng.choice([0x181, 0x281, 0x182, 0x200, 0x7FF, 0]))
            data = rng.integers(0, 256, int(rng.integers(0, 10)), dtype=np.uint8).tobytes()
            out.append((arb, data, bool(rng.random() < 0.1), bool(rng.random() < 0.1), t))
        elif kind == 1:
            x, y = (int(v) for v in rng.integers(-(1 << 31), 1 << 31, 2))
            out.append((0x181, can_position(x, y), False, False, t))
        else:
            yaw = int(rng.integers(-(1 << 31), 1 << 31)) if kind == 2 else int(
                rng.integers(-4000, 4000))
            out.append((0x281, can_heading(yaw, int(rng.integers(65536)),
                                           int(rng.integers(256))), False, False, t))
    return out


def test_can_decoder_fuzz() -> None:
    seen = [0]

    @FUZZ
    @given(st.integers(0, 2**63))
    def run(seed: int) -> None:
        decoder = CanFrameDecoder()
        validator = OdometryValidator(period_ms=20.0, seq_modulo=1 << 16)
        for arb, data, err, remote, t in _can_frames(np.random.default_rng(seed)):
            seen[0] += 1
            for msg in decoder.feed(arb, data, timestamp=t, is_error=err, is_remote=remote):
                assert isinstance(msg, OdoMsg | StaMsg | CanAnswer)
                if isinstance(msg, OdoMsg):
                    assert _valid_odometry(msg) and arb == 0x281 and not err
                    validator.accept(msg)
                if isinstance(msg, StaMsg):
                    assert 0 <= msg.flags <= 0x0F and 0 <= msg.seq <= 65535

    run()
    assert seen[0] >= 100_000
