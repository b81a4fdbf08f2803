"""Fault injection for the emulator, with counters of exactly what was injected."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class FaultPlan:
    corrupt_rate: float = 0.0  # serial: one byte of the line body changed (checksum fails)
    drop_rate: float = 0.0  # a line / CAN frame not sent
    garbage_rate: float = 0.0  # serial: random non-'$' bytes before a line
    truncate_rate: float = 0.0  # serial: a line cut short
    time_backwards_rate: float = 0.0  # serial: an ODO line whose t_ms went back 100 ms
    error_frame_rate: float = 0.0  # CAN: an error frame sent
    seq_jump_at_s: tuple[float, ...] = ()  # the sequence counter jumps by 1000 at these times
    silences: tuple[tuple[float, float], ...] = ()  # (start_s, duration_s): nothing sent
    drop_answers: tuple[int, ...] = ()  # these answers to commands (1 = the first) not sent


@dataclass
class FaultInjector:
    plan: FaultPlan
    rng: np.random.Generator
    injected: Counter[str] = field(default_factory=Counter)

    def chance(self, rate: float) -> bool:
        return rate > 0 and float(self.rng.random()) < rate

    def silent(self, t_s: float) -> bool:
        return any(start <= t_s < start + dur for start, dur in self.plan.silences)

    def seq_offset(self, t_s: float) -> int:
        return 1000 * sum(1 for t in self.plan.seq_jump_at_s if t_s >= t)

    def serial_line(self, line: bytes, is_odometry: bool) -> bytes:
        """The bytes actually sent for ``line`` (maybe nothing), counting what was done."""
        out = b""
        if self.chance(self.plan.garbage_rate):
            n = int(self.rng.integers(1, 12))
            junk = bytes(int(b) for b in self.rng.integers(0, 256, n) if b != 0x24)
            self.injected["garbage_bytes"] += sum(1 for b in junk if b not in (0x0D, 0x0A))
            out += junk
        if self.chance(self.plan.drop_rate):
            self.injected["dropped_lines"] += 1
            self.injected["dropped_odometry" if is_odometry else "dropped_other"] += 1
            return out
        if self.chance(self.plan.corrupt_rate):
            body_end = line.rindex(b"*")
            i = int(self.rng.integers(1, body_end))
            new = line[i]
            while new in (line[i], 0x24, 0x2A, 0x0A, 0x0D):
                new = int(self.rng.integers(0x20, 0x7F))
            line = line[:i] + bytes([new]) + line[i + 1:]
            self.injected["corrupted_lines"] += 1
            self.injected["corrupted_odometry" if is_odometry else "corrupted_other"] += 1
        elif self.chance(self.plan.truncate_rate):
            line = line[: int(self.rng.integers(2, len(line) - 2))]
            self.injected["truncated_lines"] += 1
            self.injected["truncated_odometry" if is_odometry else "truncated_other"] += 1
        return out + line
