"""The processing step and the odometry at a frame's stamp (daemon/service/components.py):
a frame whose odometry is still on its way is held until the sample past its stamp
arrives, so the localiser interpolates the pose at the frame instead of using a sample
from before it; a base that stopped never holds the frames up."""

from __future__ import annotations

import threading
from types import SimpleNamespace
from typing import Any

import numpy as np

from daemon.localisation.odometry import OdometryBuffer
from daemon.service.components import LatestFrame, OdometryInbox, ProcessingComponent
from daemon.service.health import ComponentHealth
from kernel.types import Frame, Odometry

MS = 1_000_000


class RecordingLocaliser:
    """Stands in for the Localiser: it records the odometry it would interpolate at each
    frame's stamp (what the method is handed), nothing more."""

    ODOMETRY_STALE_NS = 5000 * MS  # long: a busy machine never turns the wait into a miss

    def __init__(self) -> None:
        self.odometry = OdometryBuffer()
        self.seen: list[Odometry | None] = []

    def add_odometry(self, samples: list[Odometry]) -> None:
        self.odometry.extend(samples)

    def process_frame(self, frame: Frame) -> tuple[Any, Any]:
        self.seen.append(self.odometry.at(frame.stamp_ns,
                                          max_extrapolation_ns=self.ODOMETRY_STALE_NS))
        return SimpleNamespace(timings_ms={}), None


class CountingInbox(OdometryInbox):
    def __init__(self) -> None:
        super().__init__()
        self.waits = 0

    def wait_until(self, stamp_ns: int, timeout_s: float) -> bool:
        self.waits += 1
        return super().wait_until(stamp_ns, timeout_s)


def _odometry(t_ms: int) -> Odometry:
    """A base driving at 1 m/s along x: x = t."""
    return Odometry(t_ms / 1000.0, 0.0, 0.0, t_ms * MS, t_ms)


def _processing(inbox: OdometryInbox) -> tuple[ProcessingComponent, LatestFrame,
                                                 RecordingLocaliser]:
    localiser = RecordingLocaliser()
    mailbox = LatestFrame()
    health = ComponentHealth("processing")
    step = ProcessingComponent(lambda: localiser, mailbox, inbox,  # type: ignore[arg-type, return-value]
                               lambda belief, updates: None, lambda: health)
    step.setup()
    return step, mailbox, localiser


def test_a_frame_waits_for_the_odometry_past_its_stamp_and_gets_it_interpolated() -> None:
    inbox = CountingInbox()
    step, mailbox, localiser = _processing(inbox)
    inbox.put([_odometry(t) for t in range(0, 981, 20)])  # up to 0.98 s
    mailbox.put(Frame(np.zeros((4, 4), np.uint8), 990 * MS, 1))

    def deliver_late() -> None:  # the sample past the frame comes ~50 ms later
        threading.Event().wait(0.05)
        inbox.put([_odometry(1000)])

    late = threading.Thread(target=deliver_late)
    late.start()
    step.step()
    late.join()
    assert inbox.waits == 1
    odo = localiser.seen[-1]
    assert odo is not None and abs(odo.x - 0.990) < 1e-9, odo  # not 0.98: interpolated


def test_a_base_that_stopped_does_not_hold_the_frames() -> None:
    inbox = CountingInbox()
    step, mailbox, localiser = _processing(inbox)
    inbox.put([_odometry(t) for t in range(0, 501, 20)])  # stopped at 0.5 s
    mailbox.put(Frame(np.zeros((4, 4), np.uint8), 6000 * MS, 1))  # 5.5 s later
    step.step()
    assert inbox.waits == 0 and localiser.seen == [None]


def test_the_inbox_wakes_a_waiter_when_the_stamp_is_reached() -> None:
    inbox = OdometryInbox()
    assert inbox.wait_until(5 * MS, 0.0) is False
    inbox.put([_odometry(4)])
    assert inbox.wait_until(5 * MS, 0.0) is False
    waiting = threading.Event()
    result: list[bool] = []

    def waiter() -> None:
        waiting.set()
        result.append(inbox.wait_until(5 * MS, 30.0))

    thread = threading.Thread(target=waiter)
    thread.start()
    waiting.wait(30.0)
    inbox.put([_odometry(5)])
    thread.join(30.0)
    assert result == [True]
    assert [o.stamp_ns for o in inbox.drain()] == [4 * MS, 5 * MS]
