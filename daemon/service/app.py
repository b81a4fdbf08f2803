"""The daemon: devices, the supervised loop, zenoh, and systemd integration (design §11).

What it answers and publishes is built elsewhere: ``queries`` (a guarded handler per
queryable, the answer for unserved keys), ``wire`` (the JSON bodies of pose, belief and
place), ``map_file`` (the map opened for the mode), ``learn_job`` (a learn)."""

from __future__ import annotations

import json
import logging
import math
import signal
import sqlite3
import threading
import time
from typing import Any

import numpy as np
import zenoh

from daemon.config import PlacecellConfig
from daemon.localisation.belief import MapUpdates, PlaceScore
from daemon.localisation.localiser import Belief, Localiser
from daemon.service import access, api, queries, status, wire, zenoh_link
from daemon.service.components import (
    LatestFrame,
    OdometryInbox,
    ProcessingComponent,
    base_component,
    camera_component,
)
from daemon.service.fleet import FleetLink
from daemon.service.foxglove_view import FoxgloveView
from daemon.service.learn_job import (
    BaseCommands,
    FrameFeed,
    LearnJob,
    LearnOutcome,
    job_settings,
)
from daemon.service.live_view import TOPICS, LiveScene, Sink
from daemon.service.map_file import open_map
from daemon.service.map_queries import MapQueries
from daemon.service.mapper import Mapper, Seen
from daemon.service.mapping_session import Event, MappingSession
from daemon.service.notify import Notifier
from daemon.service.pipeline import make_localiser, resume
from daemon.service.ros2 import Ros2PosePublisher
from daemon.service.supervisor import Supervisor
from daemon.store.sqlite_store import SavedPose
from daemon.vision.unwarp import Unwarper
from hal.registry import HalContext, create_base, create_camera
from kernel.errors import PlacecellError
from kernel.panorama import geometry_checksum
from kernel.se2 import SE2, turned_covariance

log = logging.getLogger(__name__)


class Daemon:
    """One running placecell service. ``run()`` blocks until ``request_stop()``."""

    def __init__(self, config: PlacecellConfig, notifier: Notifier | None = None,
                 recorder: Any = None) -> None:
        self.config = config
        self.notifier = notifier or Notifier()
        self.recorder = recorder
        self.robot = config.robot.name
        self._stop = threading.Event()
        self._started_ns = time.monotonic_ns()
        self._session: zenoh.Session | None = None
        self._publishers: dict[str, Any] = {}
        self._ros2: Ros2PosePublisher | None = None
        self._access: access.AccessWatch | None = None
        self._link_listener: Any = None
        self._view: FoxgloveView | None = None
        self._fleet: FleetLink | None = None
        self._scene: LiveScene | None = None
        self._belief: Belief | None = None
        self._belief_received_ns = 0
        self.hal = HalContext(config)
        # The map first: a map made with another geometry, or one mapping mode cannot
        # write, stops the daemon before any device (design §11).
        opened = open_map(config)
        self.map = opened.store
        self.map_readonly_reason = opened.readonly_reason
        try:
            self.mapper = Mapper(self.map, config.odometry, config.mapping.learn_threads)
        except BaseException:
            self.map.close()
            raise
        self._unwarper = Unwarper(config.projection, config.panorama)
        self._map_queries = MapQueries(self.robot, self.mapper)
        self._job_lock = threading.Lock()
        self._job: LearnJob | None = None
        self._queryables: list[Any] = []
        self._acquire_after = 0.0  # monotonic s: no autonomous learning before
        # The map's one owner (design §6); cmd/mode changes its mode until the daemon
        # stops; a read-only map only localises.
        self.session = MappingSession(
            self.mapper, config.mapping.acquisition, config.localisation,
            config.mapping.mode if self.map_readonly_reason is None else "localisation")
        self._tracked: SavedPose | None = None  # the last pose tracked, to save
        self._saved: SavedPose | None = None  # the one saved last
        self._site_tie = self._load_site_tie()  # the map frame in the site's map (ROS 2)
        self.supervisor = Supervisor(
            config.service.restart_backoff_initial_s, config.service.restart_backoff_max_s,
            on_event=self.publish_event, fault_summary_s=config.service.fault_summary_s,
        )
        self._build_components()

    @property
    def mode(self) -> str:
        return self.session.mode

    # ------------------------------------------------------------------ set-up
    def _build_components(self) -> None:
        cfg = self.config
        # A recording replayed as fast as it is processed: no frame skipped (design §10).
        mailbox = LatestFrame(lockstep=cfg.camera.backend == "replay"
                              and cfg.camera.replay.speed == 0)
        inbox = OdometryInbox()
        # A learn job reads frames and odometry as the devices deliver them, not as the
        # processing step gets round to them: a busy CPU slows the pose, not the learn.
        frame_taps: list[Any] = [self._job_frame]
        odo_taps: list[Any] = [self._job_odometry]
        if self.recorder is not None:
            frame_taps.append(self.recorder.write_frame)
            odo_taps.append(self._record_odometry)
        sup = self.supervisor
        self.camera = camera_component(
            lambda: create_camera(cfg.camera, self.hal), cfg.camera.read_timeout_s, mailbox,
            lambda: sup.health["camera"], frame_taps)
        # The method sees the camera's odometry (kernel/mount.py); the recorder the base's.
        self.base = base_component(
            lambda: create_base(cfg.base, self.hal), cfg.base.read_timeout_s,
            lambda samples: inbox.put(cfg.mount.camera_odometry(samples)),
            lambda: sup.health["base"], odo_taps, on_open=self.mapper.odometry_restarted)
        # Built whatever the mode: cmd/mode may switch to mapping; nothing is learned or
        # stored while the mode is localisation (_maybe_acquire).
        self.processing = ProcessingComponent(
            lambda: self._localiser(cfg.mapping.acquisition),
            mailbox, inbox, self._on_belief, lambda: sup.health["processing"],
            odometry_taps=[self.mapper.on_odometry])
        for c in (self.camera, self.base, self.processing):
            sup.add(c)

    def _localiser(self, acquisition: Any) -> Localiser:
        with self.mapper.lock:
            localiser = make_localiser(self.config, self.session.holder, self.mapper.graph,
                                       acquisition)
        last = self.mapper.last_place
        if last is not None:  # a restarted processing component goes on watching it
            localiser.watch_place(last)
        saved = self._saved_pose()
        if saved is not None and not self.config.localisation.initial_place:
            resume(localiser, saved)
            log.info("resuming in place %d at (%.3f, %.3f, %.3f), saved %.0f s ago",
                     saved.place_id, *saved.pose, time.time() - saved.saved_unix_s)
        return localiser

    def _saved_pose(self) -> SavedPose | None:
        """Where to resume: the pose tracked last in this run, else the map file's."""
        if not self.config.map.resume:
            return None
        if self._tracked is not None:
            return self._tracked
        try:
            return self.map.saved_pose()
        except PlacecellError as e:
            log.error("not resuming: %s", e)
            return None

    def _save_pose(self) -> None:
        tracked = self._tracked
        if tracked is None or tracked is self._saved or self.map.readonly:
            return
        try:
            self.map.save_pose(tracked)
            self._saved = tracked
        except (PlacecellError, sqlite3.Error) as e:
            log.error("could not save the pose: %s", e)

    def _record_odometry(self, samples: list[Any], base: Any) -> None:
        for s in samples:
            self.recorder.write_odometry(s)

    # ------------------------------------------------------------------ zenoh
    def _open_zenoh(self) -> None:
        z = self.config.zenoh
        conf = zenoh_link.make_config(z.mode, z.listen, z.connect, z.multicast_scouting,
                                      timestamping=True, config_file=z.config_file,
                                      zid=zenoh_link.robot_zid(self.robot, z.id))
        self._session = s = zenoh_link.open_configured(conf, z.listen, z.connect)
        acl = access.acl_of(conf)
        if acl is not None:  # who connects, in which role (docs/security.md)
            self._access = access.AccessWatch(acl)
            self._link_listener = s.info.declare_link_events_listener(
                self._access.on_link, history=True)
        self._token = s.liveliness().declare_token(zenoh_link.key(self.robot, "alive"))
        for leaf in ("status", "belief", "pose"):
            self._publishers[leaf] = s.declare_publisher(zenoh_link.key(self.robot, leaf))
        self._publishers["events"] = zenoh_link.declare_event_publisher(
            s, zenoh_link.key(self.robot, "events"))
        if self.config.ros2.enabled:  # the pose for ROS 2 nodes (design §11)
            self._ros2 = Ros2PosePublisher(s, self.config.ros2)
            self._ros2.on_initial_pose(self._initial_pose)
            self._ros2.serve(self._ros2_relocalise, self._initial_pose)  # AMCL's services
            log.info("ROS 2: publishing %s on %s", self.config.ros2.topic, self._ros2.key)
        # Late joiners (placecellctl status) get the latest status at once by query.
        answers = (("status", self._answer_status),
                   ("cmd/learn_place", self._answer_learn),
                   ("cmd/abort", self._answer_abort),
                   ("cmd/set_pose", self._answer_set_pose),
                   ("cmd/relocalise", self._answer_relocalise),
                   ("cmd/mode", self._answer_mode),
                   ("map/places", self._map_queries.places),
                   ("map/transitions", self._map_queries.transitions),
                   ("map/place/**", self._map_queries.place))
        for leaf, handler in answers:
            self._queryables.append(s.declare_queryable(
                zenoh_link.key(self.robot, leaf), queries.guarded(leaf, handler)))
        # Every other key under the robot's prefix is answered too, with what it asked
        # wrong, not left to the client's timeout (design §11).
        self._queryables.append(s.declare_queryable(
            zenoh_link.key(self.robot, "**"),
            queries.unknown_key(self.robot, [leaf for leaf, _ in answers])))
        log.info("zenoh session %s: listening on %s, connecting to %s, multicast scouting %s",
                 s.zid(), z.listen, z.connect, "on" if z.multicast_scouting else "off")

    def _join_fleet(self) -> None:
        """The fleet's places taken before the robot acts on its map (docs/fleet.md)."""
        if not self.config.fleet.enabled or self._session is None:
            return
        self._fleet = FleetLink(
            self.session, self._session, self.config.fleet, self.robot,
            geometry_checksum(self.config.projection, self.config.panorama),
            self._publish_events)
        self._fleet.start()

    def _answer_status(self, query: zenoh.Query) -> None:
        api.parse(api.NoParameters, queries.payload(query), "status")
        query.reply(query.key_expr, self.status_payload())

    # ------------------------------------------------------------------ learning
    def _answer_learn(self, query: zenoh.Query) -> None:
        """cmd/learn_place: progress replies, then one result or error (design §11)."""
        def reply(kind: str, fields: dict[str, Any]) -> None:
            try:
                query.reply(query.key_expr, zenoh_link.encode(api.REPLY_SCHEMA,
                                                              {"kind": kind, **fields}))
            except Exception as e:  # noqa: BLE001 - the client may have gone
                log.debug("learn reply failed: %s", e)
            if kind in ("result", "error"):
                query.drop()

        try:
            request = api.parse(api.LearnRequest, queries.payload(query), "learn_place")
            self._operator_acted()
            job = self._start_learning(request, reply, "operator")
        except api.RequestError as e:
            reply("error", api.error_fields(e.code, str(e), e.reason))
            return
        log.info("learning a place (label %r) at the operator's request", job.label)

    def _operator_acted(self) -> None:
        """An operator's command: the autopilot keeps off the job for a while, so a
        person's next command is not met by a learn of its own (design §11)."""
        quiet = self.config.mapping.acquisition.operator_quiet_s
        self._acquire_after = max(self._acquire_after, time.monotonic() + quiet)

    # ------------------------------------------------------------ autonomous acquisition
    def _maybe_acquire(self, belief: Belief) -> None:
        """Learn a place on the robot's own when the map's owner wants one (design §6:
        MappingSession.wants_place), unless an operator acted a moment ago."""
        localiser = self.processing.localiser
        why = self.session.wants_place(belief, None if localiser is None
                                       else localiser.odometry.latest, self._job is not None)
        if why is None or time.monotonic() < self._acquire_after:
            if belief.acquisition is not None:  # not now: acquisition watches on, asks again
                self._learning_not_started()
            return

        def log_reply(kind: str, fields: dict[str, Any]) -> None:
            if kind == "error":
                log.warning("autonomous learning: %s", fields.get("message"))

        try:
            self._start_learning(api.LearnRequest(), log_reply, "autopilot")
            self.session.learning_started()
            log.info("learning a place on my own (%s)", why)
        except api.RequestError as e:
            log.warning("autonomous learning not started: %s", e)
            self._acquire_after = time.monotonic() + \
                self.config.mapping.acquisition.retry_after_s
            self._learning_not_started()

    def _learning_not_started(self) -> None:
        localiser = self.processing.localiser
        if localiser is not None:
            localiser.learning_not_started()

    def _start_learning(self, request: api.LearnRequest, reply: Any,
                        started_by: str) -> LearnJob:
        """Start a learn job. One job at a time: an operator's learn pre-empts the
        autopilot's (that one stops the robot and stores nothing); any other running job
        makes the request busy."""
        if self.mode != "mapping":
            raise api.RequestError(api.ErrorCode.REFUSED, "the daemon is in localisation "
                                   "mode: the map is read-only, no places are learned",
                                   api.Reason.LOCALISATION_MODE)
        device = self.base.device
        if device is None or self.supervisor.health["base"].state != "running":
            raise api.RequestError(api.ErrorCode.REFUSED, "the base is not running: "
                                   f"{self.supervisor.health['base'].last_error or 'starting'}",
                                   api.Reason.BASE_NOT_RUNNING)
        camera = self.supervisor.health["camera"]
        if camera.state != "running":  # refused now, not after the cross is driven
            raise api.RequestError(api.ErrorCode.REFUSED, "the camera is not running: "
                                   f"{camera.last_error or 'starting'}",
                                   api.Reason.CAMERA_NOT_RUNNING)
        if not device.info.can_move:
            raise api.RequestError(api.ErrorCode.REFUSED, f"the base ({device.info.backend}) "
                                   "cannot move: Turn Back and Look needs to drive the cross",
                                   api.Reason.BASE_CANNOT_MOVE)
        camera = self.camera.device
        # A camera that cannot say its rate yet (0) counts as 10 Hz, as learning does.
        rate = (float(camera.info.rate_hz) if camera is not None else 0.0) or 10.0
        if started_by == "operator":
            self._preempt_autopilot()
        with self._job_lock:
            if self._job is not None:
                raise api.RequestError(api.ErrorCode.BUSY, "a place is being learned already "
                                       f"(started by {self._job.started_by}, "
                                       f"{self._job.progress.phase}, "
                                       f"{self._job.progress.fraction:.0%}): wait for it or "
                                       "send cmd/abort", api.Reason.JOB_RUNNING)
            job = LearnJob(label=request.label,
                           settings=job_settings(self.config.tbl, request.extent_m),
                           unwarper=self._unwarper, feed=FrameFeed(rate),
                           mover=BaseCommands(lambda: self.base.device), session=self.session,
                           reply=reply, on_done=self._learning_done, seen=self._seen,
                           profile=self._place_profile,
                           odometry_timeout_s=self.config.base.read_timeout_s,
                           link_up=lambda: self.supervisor.health["base"].state == "running",
                           started_by=started_by, mount=self.config.mount,
                           recognise=self._recognise_view)
            self._job = job
            job.start()
        localiser = self.processing.localiser
        if localiser is not None:
            localiser.learning(True)
        return job

    def _preempt_autopilot(self) -> None:
        """Stop the autopilot's learn, if one runs, and wait until it has ended (it
        notices within a frame, or when frames stop: the TBL frame timeout)."""
        job = self._job
        if job is None or job.started_by != "autopilot":
            return
        log.info("an operator's learn pre-empts the autopilot's (%s, %.0f%%)",
                 job.progress.phase, 100 * job.progress.fraction)
        job.abort()
        if not job.join(self.config.tbl.frame_timeout_s + self.config.service.stop_timeout_s):
            raise api.RequestError(api.ErrorCode.BUSY, "the autopilot's learn did not stop in "
                                   "time: try again", api.Reason.JOB_RUNNING)

    def _place_profile(self, reference_panorama: np.ndarray | None) -> np.ndarray | None:
        localiser = self.processing.localiser
        return None if localiser is None else localiser.place_profile(reference_panorama)

    def _recognise_view(self, panorama: np.ndarray, place_ids: list[int]
                        ) -> list[PlaceScore]:
        localiser = self.processing.localiser
        return [] if localiser is None else localiser.recognise_view(panorama, place_ids)

    def _seen(self) -> Seen | None:
        localiser = self.processing.localiser
        return None if localiser is None else localiser.reliable_estimate()

    def _learning_done(self, job: LearnJob, outcome: LearnOutcome) -> None:
        with self._job_lock:
            if self._job is job:
                self._job = None
        acq = self.config.mapping.acquisition
        if outcome.place is None and acq.enabled and job.started_by == "autopilot":
            self._acquire_after = max(self._acquire_after,  # do not retry at once
                                      time.monotonic() + acq.retry_after_s)
        localiser = self.processing.localiser
        if localiser is not None:
            localiser.learning(False)
        if outcome.place is None:
            self._learning_not_started()
        if outcome.place is not None:
            p = outcome.place
            if localiser is not None:  # the map's owner has shown it the place already
                localiser.place_learned(p.id)
            segments = [e for e in outcome.events if e[0] != "transition_added"]
            self._publish_events(segments)
            self.publish_event("place_learned", place=p.id, label=p.label,
                               landmarks=p.landmark_count, lookalikes=outcome.lookalikes,
                               reference_stamp_ns=outcome.reference_stamp_ns,
                               compute_s=round(outcome.compute_s, 4))
            self._publish_events([e for e in outcome.events if e not in segments])
        else:
            self.publish_event("learning_ended", code=str(outcome.error),
                               message=outcome.message, started_by=job.started_by)

    def _publish_events(self, events: list[Event]) -> None:
        for kind, fields in events:
            self.publish_event(kind, **fields)

    def _job_odometry(self, samples: list[Any], base: Any) -> None:
        job = self._job
        if job is not None:
            job.feed.put_odometry(self.config.mount.camera_odometry(samples))

    def _job_frame(self, frame: Any) -> None:
        job = self._job
        if job is not None:
            job.feed.put_frame(frame)

    def _answer_abort(self, query: zenoh.Query) -> None:
        received_ns = time.monotonic_ns()
        api.parse(api.NoParameters, queries.payload(query), "abort")
        self._operator_acted()
        job = self._job
        if job is None:
            query.reply(query.key_expr, api.error(api.ErrorCode.NOTHING_TO_ABORT,
                                                  "no job is running"))
            return
        job.abort()
        stop_sent_ns = time.monotonic_ns()
        log.info("abort: stopped the %s job started by %s", job.kind, job.started_by)
        query.reply(query.key_expr, api.result(aborted=job.kind, started_by=job.started_by,
                                               label=job.label, received_ns=received_ns,
                                               stop_sent_ns=stop_sent_ns))

    # ------------------------------------------------------------------ pose
    def _answer_set_pose(self, query: zenoh.Query) -> None:
        """cmd/set_pose: track from a pose the operator gives (design §7)."""
        request = api.parse(api.SetPoseRequest, queries.payload(query), "set_pose")
        self._operator_acted()
        localiser = self._running_localiser()
        if request.place is None or not self.mapper.has_place(request.place):
            raise api.RequestError(api.ErrorCode.NOT_FOUND, f"place {request.place} is not in "
                                   f"the map ({self.mapper.place_count()} places)")
        camera = self.config.mount.camera_pose(SE2(request.x, request.y, request.yaw))
        localiser.set_pose(request.place, camera.as_tuple(), request.sigma_xy,
                           request.sigma_yaw)
        log.info("pose set: place %d (%.3f, %.3f, %.3f)", request.place, request.x, request.y,
                 request.yaw)
        query.reply(query.key_expr, api.result(place=request.place, x=request.x, y=request.y,
                                               yaw=request.yaw))

    def _load_site_tie(self) -> SE2 | None:
        """The map frame's pose in the site's map ([ros2] frame_id) stored with the map;
        one stored for another frame name is not applied (said once)."""
        tie = self.session.site_tie()
        if tie is None:
            return None
        frame, T = tie
        if frame != self.config.ros2.frame_id:
            log.warning("the map is tied to a site frame %r, not [ros2] frame_id %r: "
                        "ROS 2 poses are in placecell's own map frame", frame,
                        self.config.ros2.frame_id)
            return None
        log.info("the map frame stands at %s in the site's %r (ROS 2 poses are there)", T, frame)
        return T

    def _tie_site(self, pose: SE2, source: str) -> None:
        """The operator says where the robot is in the site's map while placecell tracks
        it in its own: the tie of the two, stored with the map (design §11)."""
        belief = self._belief
        frame = self.mapper.map_frame
        if belief is None or belief.state != "tracking" or belief.place_id not in frame \
                or belief.pose_in_place is None:
            log.warning("%s ignored: the map frame is tied to the site's map only while "
                        "tracking (state %s)", source, None if belief is None else belief.state)
            return
        here = self.config.mount.robot_pose(frame[belief.place_id].compose(
            SE2.of(belief.pose_in_place)))
        tie = pose.compose(here.inverse())  # T_site_map
        try:
            self.session.tie_site(self.config.ros2.frame_id, tie)
        except PlacecellError as e:
            log.warning("the tie to the site's map holds until the daemon stops: %s", e)
        self._site_tie = tie
        log.info("the map frame tied to the site's %r at %s (from %s)",
                 self.config.ros2.frame_id, tie, source)
        self.publish_event("site_tied", frame=self.config.ros2.frame_id, x=round(tie.x, 4),
                           y=round(tie.y, 4), yaw=round(tie.yaw, 5), source=source)

    def _initial_pose(self, pose: SE2, covariance: np.ndarray, frame_id: str,
                      source: str | None = None) -> None:
        """A pose in the map frame from ROS 2 (``source``: /initialpose, rviz's 2D Pose
        Estimate, by default; or the set_initial_pose service): tracked from there, in the
        place the map puts nearest it (design §11)."""
        settings = self.config.ros2
        source = source or settings.initial_pose_topic
        localiser = self.processing.localiser
        if frame_id != settings.frame_id:
            log.warning("%s in frame %r ignored: poses are set in %r", source, frame_id,
                        settings.frame_id)
            return
        if self._site_tie is None and settings.tie_site_map:
            self._tie_site(pose, source)
            return
        if self._site_tie is not None:  # from the site's map into placecell's
            pose = self._site_tie.inverse().compose(pose)
            covariance = turned_covariance(covariance, -self._site_tie.yaw)
        frame = self.mapper.map_frame
        if localiser is None or not frame:
            log.warning("%s ignored: %s", source,
                        "the localiser is not running" if localiser is None
                        else "no place is in the map frame yet")
            return
        pose = self.config.mount.camera_pose(pose)  # the method tracks the camera
        place = min(frame, key=lambda p: math.hypot(frame[p].x - pose.x, frame[p].y - pose.y))
        in_place = frame[place].inverse().compose(pose)
        sigma_xy = math.sqrt(max(covariance[0, 0], covariance[1, 1], 0.0)) or None
        sigma_yaw = math.sqrt(max(covariance[2, 2], 0.0)) or None
        self._operator_acted()
        localiser.set_pose(place, in_place.as_tuple(), sigma_xy, sigma_yaw)
        in_place = self.config.mount.robot_pose(in_place)  # told as the robot's
        log.info("pose set from %s: place %d at %s", source, place,
                 in_place)
        self.publish_event("pose_set", source=source, place=place,
                           x=round(in_place.x, 4), y=round(in_place.y, 4),
                           yaw=round(in_place.yaw, 5))

    def _running_localiser(self) -> Localiser:
        """The processing step's localiser; refused while the step (re)starts."""
        localiser = self.processing.localiser
        if localiser is None:
            why = self.supervisor.health["processing"].last_error or "starting"
            raise api.RequestError(api.ErrorCode.REFUSED, f"the localiser is not running: {why}",
                                   api.Reason.LOCALISER_NOT_RUNNING)
        return localiser

    def _answer_relocalise(self, query: zenoh.Query) -> None:
        """cmd/relocalise: search the whole map for the robot (design §9)."""
        api.parse(api.NoParameters, queries.payload(query), "relocalise")
        self._operator_acted()
        localiser = self._running_localiser()
        if self.mapper.place_count() == 0:
            raise api.RequestError(api.ErrorCode.REFUSED, "the map has no places to "
                                   "relocalise in", api.Reason.EMPTY_MAP)
        localiser.relocalise()
        log.info("relocalisation requested")
        query.reply(query.key_expr, api.result(relocalising=True,
                                               places=self.mapper.place_count()))

    def _ros2_relocalise(self) -> None:
        """ROS 2's reinitialize_global_localization (as AMCL's): cmd/relocalise."""
        localiser = self.processing.localiser
        if localiser is None or self.mapper.place_count() == 0:
            log.warning("reinitialize_global_localization ignored: %s", "the localiser is "
                        "not running" if localiser is None else "the map has no places")
            return
        self._operator_acted()
        localiser.relocalise()
        log.info("relocalisation requested over ROS 2")

    def _answer_mode(self, query: zenoh.Query) -> None:
        """cmd/mode: switch between mapping and localisation (design §11); refused while
        a place is being learned (abort it first)."""
        request = api.parse(api.ModeRequest, queries.payload(query), "mode")
        if request.mode == "mapping" and self.map_readonly_reason is not None:
            raise api.RequestError(api.ErrorCode.REFUSED, "mapping needs a writable map: "
                                   f"{self.map_readonly_reason}", api.Reason.MAP_READONLY)
        if request.mode and request.mode != self.mode:
            self._operator_acted()
            with self._job_lock:
                if self._job is not None:
                    raise api.RequestError(api.ErrorCode.BUSY, "a place is being learned: "
                                           "wait for it or send cmd/abort, then switch",
                                           api.Reason.JOB_RUNNING)
                previous, self.session.mode = self.mode, request.mode
            log.info("mode %s -> %s at the operator's request", previous, self.mode)
            self.publish_event("mode_changed", mode=self.mode, previous=previous)
        query.reply(query.key_expr, api.result(mode=self.mode))

    def publish(self, leaf: str, payload: bytes) -> None:
        pub = self._publishers.get(leaf)
        if pub is not None:
            try:
                pub.put(payload)
            except Exception as e:  # noqa: BLE001 - zenoh shutting down
                log.debug("publish %s failed: %s", leaf, e)

    def _open_view(self) -> None:
        """The live scene's sinks: the Foxglove server when enabled, the recording."""
        sinks: list[Sink] = []
        if self.config.foxglove.enabled:
            self._view = FoxgloveView(self.config.foxglove, self.robot, TOPICS)
            sinks.append(self._view)
            log.info("Foxglove live view on ws://%s", self.config.foxglove.listen)
        if self.recorder is not None:
            sinks.append(self.recorder)
        self._scene = LiveScene(sinks) if sinks else None

    def _show(self, belief: Belief, body: dict[str, Any], in_map: SE2 | None) -> None:
        assert self._scene is not None
        localiser = self.processing.localiser  # this is its thread: the frame just done
        tracker = None if localiser is None else localiser.tracker
        place_in_map = None if tracker is None else self.mapper.map_frame.get(tracker.place.id)
        try:
            self._scene.show(belief.stamp_ns, body, in_map, place_in_map,
                             None if tracker is None
                             else self.config.mount.robot_poses(tracker.filter.particles),
                             None if localiser is None else localiser.panorama,
                             self.mapper.drawn)
        except Exception as e:  # noqa: BLE001 - a viewer never stops localisation
            log.warning("live view: %s", e)

    def _publish_ros2(self, belief: Belief, place: SE2, in_map: SE2) -> None:
        """The tracked pose for ROS 2 (daemon/service/ros2.py), stamped on the UNIX clock."""
        assert self._ros2 is not None and belief.covariance is not None
        odo = belief.odometry
        epoch_ns = belief.stamp_ns + time.time_ns() - time.monotonic_ns()
        if self._site_tie is not None:  # every ROS 2 pose in the site's map
            place, in_map = self._site_tie.compose(place), self._site_tie.compose(in_map)
        localiser = self.processing.localiser  # this is its thread: the frame just done
        tracker = None if localiser is None else localiser.tracker
        try:
            self._ros2.publish_tracked(
                in_map, place, np.array(belief.covariance).reshape(3, 3), epoch_ns,
                None if odo is None else SE2(odo.x, odo.y, odo.yaw))
            if tracker is not None and tracker.place.id == belief.place_id:
                self._ros2.publish_particles(
                    self.config.mount.robot_poses(tracker.filter.particles), place, epoch_ns)
        except Exception as e:  # noqa: BLE001 - zenoh shutting down
            log.debug("publish ROS 2 pose failed: %s", e)

    def _resend_map_odom(self) -> None:
        """map -> odom again while tracking (Ros2PosePublisher.resend_map_odom)."""
        belief = self._belief
        if self._ros2 is None or belief is None or belief.state != "tracking":
            return
        try:
            self._ros2.resend_map_odom()
        except Exception as e:  # noqa: BLE001 - zenoh shutting down
            log.debug("publish map -> odom failed: %s", e)

    def publish_event(self, kind: str, **fields: Any) -> None:
        body = {"event": kind, "stamp_ns": time.monotonic_ns(), **fields}
        log.info("event %s", json.dumps(body))
        self.publish("events", zenoh_link.encode("placecell.event", body))
        if self._fleet is not None:
            self._fleet.on_event(kind, fields)

    def _on_belief(self, belief: Belief, updates: MapUpdates) -> None:
        self._belief = belief
        self._belief_received_ns = time.monotonic_ns()
        if belief.state == "tracking" and belief.place_id is not None \
                and belief.pose_in_place is not None and belief.covariance is not None:
            self._tracked = SavedPose(belief.place_id, belief.pose_in_place,
                                      np.array(belief.covariance).reshape(3, 3), time.time())
        robot = belief.of_robot(self.config.mount)  # what is given out is the robot's
        body = wire.belief_body(robot)
        in_map = place = None
        if robot.place_id is not None and robot.pose_in_place is not None:
            place = self.mapper.map_frame.get(robot.place_id)
            if place is not None:
                in_map = place.compose(SE2.of(robot.pose_in_place))
        segments = self.mapper.segment_of
        self.publish("pose", zenoh_link.encode("placecell.pose", wire.pose_body(
            robot, in_map, None if robot.place_id is None else segments.get(robot.place_id),
            min(segments.values(), default=None))))
        if self._ros2 is not None and place is not None and in_map is not None \
                and robot.state == "tracking" and robot.covariance is not None:
            self._publish_ros2(robot, place, in_map)
        self.publish("belief", zenoh_link.encode("placecell.belief", body))
        try:  # what the frame does to the map, through its one owner (design §6)
            self._publish_events(self.session.observe(belief, updates))
        except PlacecellError as e:  # the map file refused: say so, keep localising
            log.error("the map was not changed: %s", e)
        event = belief.event
        if event is not None and event.kind == "lost":
            self.publish_event("lost", place=event.place_id, reason=event.how)
        elif event is not None:
            self.publish_event("relocalised", place=event.place_id, how=event.how,
                               took_s=round(event.took_s, 3), frames=event.frames)
        told = belief.disambiguation
        if told is not None:
            self.publish_event("disambiguated", place=told.place_id, other=told.other_id,
                               ncc_place=round(told.ncc_place, 4),
                               ncc_other=round(told.ncc_other, 4), vote=round(told.vote, 4))
        try:
            self._maybe_acquire(belief)
        except PlacecellError as e:  # the map file refused: say so, keep localising
            log.error("autonomous acquisition: %s", e)
            self._acquire_after = time.monotonic() + \
                self.config.mapping.acquisition.retry_after_s
        if self._scene is not None:
            self._show(belief, body, in_map)

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """The ``status`` answer (daemon/service/status.py)."""
        now = time.monotonic_ns()
        health = self.supervisor.health
        components, rates = status.components_and_rates(
            health, now, self.config.service.min_processed_share)
        return {
            "robot": self.robot,
            "stamp_ns": now,
            "uptime_s": round((now - self._started_ns) / 1e9, 3),
            "healthy": all(c["state"] == "running" for c in components.values()),
            "components": components,
            "rates": rates,
            "belief": status.belief_summary(self._belief, now - self._belief_received_ns,
                                            self.config.service.stale_after_s, health),
            "map": {"path": self.config.map.path, "places": self.mapper.place_count(),
                    "transitions": self.mapper.transition_count(),
                    "segments": len(set(self.mapper.segment_of.values())),
                    "mode": self.mode, "writable": not self.map.readonly,
                    "readonly_reason": self.map_readonly_reason},
            "job": status.job_summary(self._job),
            "access": (self._access.summary() if self._access is not None
                       else access.disabled_summary()),
            "versions": status.versions(),
        }

    def status_payload(self) -> bytes:
        return zenoh_link.encode("placecell.status", self.status())

    # ------------------------------------------------------------------ run
    def request_stop(self, *_: Any) -> None:
        self._stop.set()

    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)

    def run(self) -> int:
        self._open_zenoh()
        self._join_fleet()
        self._open_view()
        self.supervisor.start()
        ready = False
        period = self.config.service.status_period_s
        watchdog_s = self.notifier.watchdog_interval_s
        tick = min(0.1, period, self.config.ros2.tf_period_s,
                   watchdog_s / 2 if watchdog_s else 0.1)
        next_status = time.monotonic()
        next_watchdog = time.monotonic()
        next_save = time.monotonic() + self.config.map.save_pose_period_s
        next_tf = time.monotonic()
        startup_deadline = time.monotonic() + 30.0
        while not self._stop.is_set():
            now = time.monotonic()
            if not ready and (self.supervisor.all_running() or now > startup_deadline):
                # READY once devices are up (or after a grace period: a missing device is
                # then reported through status and retried, not a reason to hang start-up).
                self.notifier.ready("devices up" if self.supervisor.all_running()
                                    else "running with device faults")
                self.publish_event("started", healthy=self.supervisor.all_running())
                ready = True
            if now >= next_status:
                self.publish("status", self.status_payload())
                next_status = now + period
            if now >= next_tf:
                self._resend_map_odom()
                next_tf = now + self.config.ros2.tf_period_s
            if now >= next_save:
                self._save_pose()
                next_save = now + self.config.map.save_pose_period_s
            if ready and watchdog_s and now >= next_watchdog:
                # WATCHDOG only while the loop is healthy: every component thread alive and
                # cycling (devices in backoff are reported in status, not fatal).
                if self.supervisor.threads_alive(max_silence_s=max(5.0, watchdog_s)):
                    self.notifier.watchdog()
                next_watchdog = now + watchdog_s / 2
            self._stop.wait(tick)
        return self._shutdown()

    def _shutdown(self) -> int:
        log.info("stopping")
        self.notifier.stopping()
        job = self._job
        if job is not None:  # stop the robot; the job ends storing nothing
            job.abort()
            job.join(1.0)
        self.supervisor.stop(self.config.service.stop_timeout_s)
        self._save_pose()  # where the next start resumes (design §11)
        self.publish_event("stopped")
        if self.recorder is not None:
            self.recorder.close()
        self.map.close()
        if self._view is not None:
            self._view.close()
        if self._session is not None:
            try:
                if self._fleet is not None:
                    self._fleet.close()
                self._token.undeclare()
                if self._ros2 is not None:
                    self._ros2.close()
                self._session.close()
            except Exception as e:  # noqa: BLE001 - best effort at exit
                log.warning("closing zenoh: %s", e)
        self.notifier.close()
        log.info("stopped")
        return 0
