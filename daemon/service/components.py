"""The supervised components of the daemon: the camera, the base and the processing step."""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from daemon.localisation.belief import MapUpdates
from daemon.localisation.localiser import Belief, Localiser
from daemon.service.health import ComponentHealth
from hal.base.base import Base
from hal.camera.base import Camera
from kernel.types import Frame, Odometry

log = logging.getLogger(__name__)


class LatestFrame:
    """A one-slot mailbox: the processing step always takes the newest frame; frames it
    had no time for are counted as skipped, never queued up (latency stays low).

    In ``lockstep`` (a recording replayed as fast as it is processed) the camera waits
    for the slot to be taken instead, so no frame is skipped; after ``LOCKSTEP_WAIT_S``
    (processing stopped) it gives up and counts the frame skipped."""

    LOCKSTEP_WAIT_S = 5.0

    def __init__(self, lockstep: bool = False) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self.lockstep = lockstep
        self.skipped = 0

    def put(self, frame: Frame) -> None:
        with self._cond:
            if self.lockstep and self._frame is not None:
                self._cond.wait_for(lambda: self._frame is None, self.LOCKSTEP_WAIT_S)
            if self._frame is not None:
                self.skipped += 1
            self._frame = frame
            self._cond.notify_all()

    def take(self, timeout: float) -> Frame | None:
        with self._cond:
            if self._frame is None:
                self._cond.wait(timeout)
            frame, self._frame = self._frame, None
            self._cond.notify_all()
            return frame


class DeviceComponent:
    """A device (camera or base) in the supervised loop: opened by ``setup``, read by
    ``step`` with a timeout, each delivery handed to ``deliver``, closed by ``teardown``."""

    def __init__(self, name: str, make_device: Callable[[], Any], timeout_s: float,
                 deliver: Callable[[Any, Any], int], health: Callable[[], ComponentHealth],
                 on_open: Callable[[], None] | None = None) -> None:
        self.name = name
        self._make = make_device
        self._timeout_s = timeout_s
        self._deliver = deliver  # (what was read, device) -> how many items (for the rate)
        self._health = health
        self._on_open = on_open
        self.device: Any = None  # open between setup and teardown; others may command it

    def setup(self) -> None:
        device = self._make()
        device.open()
        self.device = device
        self._health().detail["device"] = _info(device)
        if self._on_open is not None:
            self._on_open()

    def step(self) -> None:
        assert self.device is not None  # set by setup(), which the supervisor runs first
        got = self.device.read(self._timeout_s)
        self._health().rate.tick(self._deliver(got, self.device))
        self._health().detail["stats"] = dict(self.device.stats())

    def teardown(self) -> None:
        if self.device is not None:
            self.device.close()
            self.device = None


def camera_component(make_camera: Callable[[], Camera], timeout_s: float,
                     mailbox: LatestFrame, health: Callable[[], ComponentHealth],
                     taps: Sequence[Callable[[Frame], None]]) -> DeviceComponent:
    def deliver(frame: Frame, camera: Camera) -> int:
        for tap in taps:
            tap(frame)
        mailbox.put(frame)
        return 1

    return DeviceComponent("camera", make_camera, timeout_s, deliver, health)


def base_component(make_base: Callable[[], Base], timeout_s: float,
                   sink: Callable[[list[Odometry]], None], health: Callable[[], ComponentHealth],
                   taps: Sequence[Callable[[list[Odometry], Base], None]],
                   on_open: Callable[[], None] | None = None) -> DeviceComponent:
    """The base device; ``on_open`` is told each time it is re-opened into an odometry
    frame that may start from anywhere (not the first time, and not for a base whose
    odometry survives a re-open)."""
    opened = [0]

    def reopened() -> None:
        opened[0] += 1
        device = component.device
        kept = device is not None and device.info.odometry_kept_on_reopen
        if opened[0] > 1 and not kept and on_open is not None:
            on_open()

    def deliver(samples: list[Odometry], base: Base) -> int:
        for tap in taps:
            tap(samples, base)
        sink(samples)
        health().detail["flags"] = base.status().to_flags()
        return len(samples)

    component = DeviceComponent("base", make_base, timeout_s, deliver, health, reopened)
    return component


class ProcessingComponent:
    """Feeds frames and odometry to the localiser and hands each belief on, with what the
    frame found that changes the map (for the map's owner); every frame
    and every odometry sample also goes to the taps (the mapper, a running job)."""

    name = "processing"
    LOCKSTEP_ODOMETRY_S = 1.0  # replay: how long a frame waits for its odometry

    def __init__(self, make_localiser: Callable[[], Localiser], mailbox: LatestFrame,
                 odometry_inbox: OdometryInbox,
                 on_belief: Callable[[Belief, MapUpdates], None],
                 health: Callable[[], ComponentHealth],
                 odometry_taps: Sequence[Callable[[list[Odometry]], None]] = (),
                 frame_taps: Sequence[Callable[[Frame], None]] = ()) -> None:
        self._make = make_localiser
        self._mailbox = mailbox
        self._odometry = odometry_inbox
        self._on_belief = on_belief
        self._health = health
        self._odometry_taps = odometry_taps
        self._frame_taps = frame_taps
        self.localiser: Localiser | None = None

    def setup(self) -> None:
        self.localiser = self._make()

    def step(self) -> None:
        assert self.localiser is not None  # set by setup(), which the supervisor runs first
        self._hand_over_odometry()
        frame = self._mailbox.take(timeout=0.2)
        if frame is None:
            return
        self._await_odometry(frame.stamp_ns)
        for frame_tap in self._frame_taps:
            frame_tap(frame)
        belief, updates = self.localiser.process_frame(frame)
        self._health().rate.tick()
        self._health().detail["timings_ms"] = belief.timings_ms
        self._health().detail["skipped_frames"] = self._mailbox.skipped
        self._on_belief(belief, updates)

    def _await_odometry(self, stamp_ns: int) -> None:
        """Wait (on the inbox's event) until odometry reaches the frame's stamp, so the
        localiser interpolates the pose at the frame instead of taking a sample from
        before it (a base's samples often arrive a few tens of ms after the frame taken
        beside them; under load, more) — as AMCL's message filter holds a scan until the
        transform at its stamp is there. Only while odometry flows (its newest sample
        within ``Localiser.ODOMETRY_STALE_NS`` of the frame) and for at most that long: a
        base that stopped is reported as missing odometry, as always, without slowing
        the frames. A replayed recording (lockstep) waits up to ``LOCKSTEP_ODOMETRY_S``."""
        assert self.localiser is not None
        stale_ns = self.localiser.ODOMETRY_STALE_NS
        latest = self.localiser.odometry.latest
        if self._mailbox.lockstep:
            timeout_s = self.LOCKSTEP_ODOMETRY_S
        elif latest is None or stamp_ns - latest.stamp_ns > stale_ns:
            return
        else:
            timeout_s = stale_ns / 1e9
        if latest is None or latest.stamp_ns < stamp_ns:
            self._odometry.wait_until(stamp_ns, timeout_s)
            self._hand_over_odometry()

    def _hand_over_odometry(self) -> None:
        """The samples the base delivered since: to the localiser and every tap."""
        assert self.localiser is not None
        samples = self._odometry.drain()
        self.localiser.add_odometry(samples)
        for odometry_tap in self._odometry_taps:
            odometry_tap(samples)

    def teardown(self) -> None:
        self.localiser = None


class OdometryInbox:
    """Thread-safe hand-over of odometry samples from the base thread to processing."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._samples: list[Odometry] = []
        self._newest_ns: int | None = None  # the newest stamp ever put

    def put(self, samples: list[Odometry]) -> None:
        with self._cond:
            self._samples.extend(samples)
            for sample in samples:
                if self._newest_ns is None or sample.stamp_ns > self._newest_ns:
                    self._newest_ns = sample.stamp_ns
            self._cond.notify_all()

    def drain(self) -> list[Odometry]:
        with self._cond:
            out, self._samples = self._samples, []
            return out

    def wait_until(self, stamp_ns: int, timeout_s: float) -> bool:
        """Wait until a sample stamped at or after ``stamp_ns`` has been put (True), or
        ``timeout_s`` passed (False)."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self._newest_ns is not None and self._newest_ns >= stamp_ns,
                timeout_s)


def _info(device: Any) -> dict[str, Any]:
    """A device's info dataclass as JSON-able data."""
    return {k: (dict(v) if isinstance(v, Mapping) else v)
            for k, v in dataclasses.asdict(device.info).items()}
