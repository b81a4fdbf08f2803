"""Learning a place as a job of the running daemon (design §3, §6, §11).

The job never reads a device: frames and odometry come through a :class:`FrameFeed` that
the processing component fills while the job is attached, and moves go through the base
component (:class:`BaseCommands`), which owns the base device. The loop is the one every
caller runs (daemon/service/learning.py: ``drive_tbl``). Progress and the result go to
``reply`` (the zenoh query that asked for it streams them).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from daemon.localisation.belief import PlaceScore
from daemon.localisation.odometry import OdometryBuffer
from daemon.mapping.place import Place
from daemon.mapping.settings import TblSettings
from daemon.mapping.tbl import Progress
from daemon.service import api
from daemon.service.api import ErrorCode
from daemon.service.learning import drive_tbl, frame_with_odometry
from daemon.service.mapper import Link, Seen
from daemon.service.mapping_session import Event, MappingSession
from daemon.service.memory import release_free_memory
from daemon.vision.unwarp import Unwarper
from hal.base.base import BaseInfo, BaseStatus
from hal.base.settings import BaseSettings
from kernel.errors import (
    CommandRejectedError,
    DeviceTimeoutError,
    HalError,
    LearningAbortedError,
    LearningError,
    LearningRefusedError,
)
from kernel.mount import Mount
from kernel.types import Frame, Odometry

log = logging.getLogger(__name__)


class FrameFeed:
    """Frames and odometry handed to a job by the processing component (thread-safe).
    Holds a few frames; when the job falls behind the oldest are dropped, as the daemon's
    own frame mailbox does."""

    def __init__(self, rate_hz: float, capacity: int = 4) -> None:
        self.rate_hz = rate_hz
        self._frames: queue.Queue[Frame] = queue.Queue(maxsize=capacity)
        self._odometry: queue.Queue[list[Odometry]] = queue.Queue()

    def put_frame(self, frame: Frame) -> None:
        while True:
            try:
                self._frames.put_nowait(frame)
                return
            except queue.Full:
                with contextlib.suppress(queue.Empty):
                    self._frames.get_nowait()

    def put_odometry(self, samples: list[Odometry]) -> None:
        if samples:
            self._odometry.put(samples)

    def next_frame(self, timeout_s: float) -> Frame:
        try:
            return self._frames.get(timeout=timeout_s)
        except queue.Empty:
            raise DeviceTimeoutError(f"no camera frame within {timeout_s:.1f} s") from None

    def odometry(self, timeout_s: float) -> list[Odometry]:
        try:
            out = self._odometry.get(timeout=timeout_s)
        except queue.Empty:
            raise DeviceTimeoutError(f"no odometry within {timeout_s:.1f} s") from None
        while True:
            try:
                out += self._odometry.get_nowait()
            except queue.Empty:
                return out


class FeedSensors:
    """:class:`daemon.service.learning.Sensors` over a :class:`FrameFeed`: each wait for
    odometry is the base's read timeout, and a late sample is told from a dead link by
    ``link_up`` (the base component running)."""

    def __init__(self, feed: FrameFeed, settings: TblSettings, odometry_timeout_s: float,
                 link_up: Callable[[], bool]) -> None:
        self.feed = feed
        self.settings = settings
        self.rate_hz = feed.rate_hz
        self.buffer = OdometryBuffer()
        self._odometry_timeout_s = odometry_timeout_s
        self._link_up = link_up

    def frame(self) -> tuple[Frame, Odometry]:
        return frame_with_odometry(
            self.feed.next_frame, self.buffer,
            lambda: self.feed.odometry(self._odometry_timeout_s), self.settings, self._link_up)


class BaseCommands:
    """Moves for a job, sent to the base device that the base component owns."""

    def __init__(self, device: Callable[[], Any]) -> None:
        self._device = device  # the open device, or None while the component restarts

    def _open(self) -> Any:
        device = self._device()
        if device is None:
            raise CommandRejectedError("the base is not running (see status)")
        return device

    @property
    def info(self) -> BaseInfo:
        info: BaseInfo = self._open().info
        return info

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        self._open().move_relative(dx, dy, dyaw, speed)

    def status(self) -> BaseStatus:
        status: BaseStatus = self._open().status()
        return status

    def stop(self) -> None:
        self._open().stop()


Reply = Callable[[str, dict[str, Any]], None]  # (kind, fields): progress | result | error
Recogniser = Callable[[np.ndarray, list[int]], list[PlaceScore]]  # panorama, place ids


@dataclass(frozen=True)
class LearnOutcome:
    place: Place | None
    error: ErrorCode | None
    message: str
    lookalikes: list[int] = field(default_factory=list)  # places it was told apart from
    reference_stamp_ns: int = 0  # the odometry stamp at the place's reference pose
    events: list[Event] = field(default_factory=list)  # what storing it did to the map
    compute_s: float = 0.0  # from the end of the drive to the place in the map


class LearnJob:
    """One Turn-Back-and-Look in its own thread. ``attach``/``detach`` connect its feed
    to the processing component; ``reply`` gets progress, then one result or error."""

    kind = "learn_place"

    def __init__(self, *, label: str, settings: TblSettings, unwarper: Unwarper,
                 feed: FrameFeed, mover: BaseCommands, session: MappingSession, reply: Reply,
                 on_done: Callable[[LearnJob, LearnOutcome], None],
                 seen: Callable[[], Seen | None] = lambda: None,
                 profile: Callable[[np.ndarray | None], np.ndarray | None] = lambda _: None,
                 odometry_timeout_s: float = BaseSettings().read_timeout_s,
                 link_up: Callable[[], bool] = lambda: True,
                 started_by: str = "operator", mount: Mount | None = None,
                 recognise: Recogniser = lambda _panorama, _ids: []) -> None:
        """``seen``: the localiser's reliable estimate of the robot now, if any (it joins
        the new place to the map, design §6); ``session``: the map's owner, which stores
        the place (daemon/service/mapping_session.py); ``profile``: the local space
        profile of a reference panorama (design §4), None while the localiser cannot tell;
        ``odometry_timeout_s`` and ``link_up``: see :class:`FeedSensors`; ``started_by``:
        ``operator`` or ``autopilot`` (autonomous acquisition, which an operator's learn
        pre-empts); ``mount``: where the camera sits (the feed's odometry is the camera's,
        the moves the robot's); ``recognise``: places' leads in a panorama
        (Localiser.recognise_view): an autopilot's learn stores nothing where a place
        taken from the fleet meanwhile stands out (MappingSession.taken_meanwhile)."""
        self.label = label
        self.mount = mount or Mount()
        self.started_by = started_by
        self._odometry_timeout_s = odometry_timeout_s
        self._link_up = link_up
        self._profile = profile
        self._recognise = recognise
        self._seen = seen
        self.settings = settings
        self.unwarper = unwarper
        self.feed = feed
        self.mover = mover
        self.session = session
        self._reply = reply
        self._on_done = on_done
        self.abort_requested = threading.Event()
        self.progress = Progress("starting", 0.0)
        self._links: list[Link] = []
        self._last_sent = (-1.0, "")
        self._thread = threading.Thread(target=self._run, name="placecell-learn", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def abort(self) -> None:
        """Stop the robot now (not at the next frame) and end the job storing nothing."""
        self.abort_requested.set()
        try:
            self.mover.stop()
        except HalError as e:
            log.error("abort: could not stop the base: %s", e)

    def join(self, timeout_s: float) -> bool:
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _on_progress(self, step: Progress) -> None:
        self.progress = step
        # A reply per leg and per 5 % of the cross: enough for a progress bar.
        if step.phase != self._last_sent[1] or step.fraction - self._last_sent[0] >= 0.05:
            self._last_sent = (step.fraction, step.phase)
            self._reply("progress", {"phase": step.phase, "fraction": round(step.fraction, 3)})

    def _begin(self, start: Odometry) -> None:
        self._links = self.session.begin_place(start, self._seen())

    def _run(self) -> None:
        outcome = LearnOutcome(None, ErrorCode.FAILED, "learning did not finish")
        try:
            self._reply("progress", {"phase": "starting", "fraction": 0.0})
            sensors = FeedSensors(self.feed, self.settings, self._odometry_timeout_s,
                                  self._link_up)
            tbl = drive_tbl(sensors, self.mover, self.unwarper,
                            self.settings, progress=self._on_progress,
                            abort=self.abort_requested, on_start=self._begin,
                            mount=self.mount, ahead=self.session.learn_ahead())
            if self.abort_requested.is_set():
                raise LearningAbortedError("learning aborted on request")
            if self.started_by == "autopilot":
                here = self.session.taken_meanwhile(
                    lambda ids: self._recognise(tbl.reference_panorama, ids))
                if here is not None:
                    raise LearningRefusedError(
                        f"place {here[0]}, robot {here[1]}'s, was taken from the fleet here "
                        "while this one was driven; nothing stored: the robot goes on in it")
            driven = time.perf_counter()  # what the robot waits for after the drive
            self._reply("progress", {"phase": "storing", "fraction": 1.0})
            place = Place(tbl.result(), tbl.reference_panorama, label=self.label,
                          created_unix_s=time.time(),
                          local_space=self._profile(tbl.reference_panorama))
            learned = self.session.store_place(
                place, self._links, tbl.views,
                on_stored=lambda _: self._reply("progress", {"phase": "lookalikes",
                                                             "fraction": 1.0}),
                seen_at_end=self._seen())
            stored, transitions = learned.place, learned.transitions
            outcome = LearnOutcome(stored, None, "", learned.lookalikes, tbl.start.stamp_ns,
                                   learned.events, time.perf_counter() - driven)
            self._reply("result", {
                "place": {"id": stored.id, "label": stored.label,
                          "landmarks": stored.landmark_count,
                          "reference_stamp_ns": tbl.start.stamp_ns},
                "transitions": [{"from": t.from_id, "to": t.to_id} for t in transitions]})
        except LearningAbortedError as e:
            outcome = LearnOutcome(None, ErrorCode.ABORTED, f"{e}; nothing was stored")
        except LearningRefusedError as e:
            outcome = LearnOutcome(None, ErrorCode.REFUSED, str(e))
        except LearningError as e:
            outcome = LearnOutcome(None, ErrorCode.FAILED, str(e))
        except HalError as e:
            outcome = LearnOutcome(None, ErrorCode.FAILED, f"the base failed: {e}")
        except Exception as e:  # noqa: BLE001 - a job must end with a reply, whatever happens
            log.exception("learning failed")
            outcome = LearnOutcome(None, ErrorCode.FAILED, f"{type(e).__name__}: {e}")
        finally:
            if outcome.place is None:
                self.session.cancel_place()
                self._reply("error", api.error_fields(outcome.error or ErrorCode.FAILED,
                                                      outcome.message))
            self._on_done(self, outcome)
            release_free_memory()  # this thread's temporaries (daemon/service/memory.py)


def job_settings(settings: TblSettings, extent_m: float | None) -> TblSettings:
    return settings if extent_m is None else replace(settings, extent_m=extent_m)
