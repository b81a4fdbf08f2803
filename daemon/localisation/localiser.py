"""The localiser: the one pipeline that the daemon, the evaluator and the benchmarks drive.

Per frame (design §1): unwarp the raw image to a panorama (one ``cv2.remap``), take the
odometry motion since the previous frame, track the current place's landmarks and update
the particle filter with them (daemon/localisation/local_positioning.py), and every few
frames recognise the current place's neighbours and, in turn, other places to pass the
estimate on or close a cycle (daemon/localisation/place_switching.py); autonomous place
acquisition watches the place learned last (daemon/localisation/acquisition_watch.py). The grey
panorama and its preparation for matching are computed once per frame and shared.

Global localisation (design §9, daemon/localisation/global_localisation.py): with no pose
the map is searched for the most likely place and tracking starts there; a loss (the
confidence low for a few frames) is recovered from in the order of §9.3.2 — particles
redistributed around the estimate, over the whole place, then global relocalisation —
and a place clearly ahead of the current one in the background search sends recovery
straight to the last step. States: ``uninitialised`` (no map), ``relocalising`` (searching,
or tracking from a place the search chose until the estimate is reliable), ``tracking``,
``lost`` (recovering).

It is pure: the caller hands in frames and odometry samples with their stamps; nothing
here reads a clock (``perf_counter`` only times the steps) or a device, and the random
generator is seeded from the settings.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from daemon.localisation.acquisition_watch import AcquisitionWatch, Tracked, WatchStep
from daemon.localisation.belief import (
    Belief,
    BeliefState,
    Disambiguation,
    LocalisationEvent,
    MapUpdates,
    PlaceScore,
)
from daemon.localisation.global_localisation import PlaceSearch
from daemon.localisation.known_map import KnownMap, MapHolder
from daemon.localisation.local_positioning import LocalResult, PlaceTracker
from daemon.localisation.odometry import OdometryBuffer, relative_motion
from daemon.localisation.place_switching import (
    CycleClosure,
    PlaceSwitcher,
    beyond,
    carried_over,
    reliable,
)
from daemon.localisation.relocalisation import Mode, Relocalisation, contradicted
from daemon.localisation.sensor_models import make_model
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.acquisition import (
    AcquisitionDecision,
)
from daemon.mapping.odometry_chain import OdometryChain
from daemon.mapping.settings import AcquisitionSettings, OdometryNoiseSettings
from daemon.mapping.transition import Transition
from daemon.vision.disambiguation import Feature, can_decide, choose
from daemon.vision.floor import FloorModel
from daemon.vision.local_space import CAP_M, LocalSpace, match_many
from daemon.vision.recognition import FastMatcher, PreparedPanorama
from daemon.vision.signature import signature, similarity
from daemon.vision.unwarp import Unwarper
from kernel.camera_models import Projection
from kernel.errors import PlacecellError
from kernel.mount import Mount
from kernel.panorama import core_of, to_grey
from kernel.se2 import SE2, UncertainSE2
from kernel.sensor_settings import PanoramaSettings
from kernel.types import Frame, Odometry

__all__ = ["Belief", "BeliefState", "Localiser", "PlaceScore"]

# How sure the pose is at a place's reference right after Turn Back and Look.
AFTER_LEARNING_SIGMA_M = 0.03
AFTER_LEARNING_SIGMA_RAD = 0.03


# A place recognised by acquisition's certain lead (design §6) is within about this of
# the robot: in the reference views of offices 1 and 3, places nearer than 0.3 m stood
# 0.20-0.23 above their backgrounds, those 0.3-0.75 m away 0.113 at most.
REVISIT_SIGMA_M = 0.3

# Handed over through a path of transitions: particles at least this far around where
# the path puts the robot (its drift is not all in its covariance).
GRAPH_MIN_SIGMA_M = 0.3

# Places nearest the tracked one by transitions that recognition and the bridge consider.
THROUGH_GRAPH_PLACES = 64

MAX_RIVALS = 7  # look-alikes of the pick within the margin that take part in a decision


@dataclass(frozen=True)
class PoseRequest:
    place_id: int
    pose: tuple[float, float, float]
    sigma_xy: float
    sigma_yaw: float
    confirm: str | None = None  # None: the operator knows; else how the pose came (resumed)


def _near_reference(tracker: PlaceTracker | None, within_m: float) -> bool:
    """The estimate stands within ``within_m`` of its place's reference (or is unknown)."""
    if tracker is None or tracker.estimate is None:
        return True
    return math.hypot(tracker.estimate.pose[0], tracker.estimate.pose[1]) < within_m


@dataclasses.dataclass(frozen=True)
class Fix:
    """A reliable estimate while tracking (place, T_place_robot) and the odometry since."""

    place_id: int
    T_place_robot: UncertainSE2
    odometry: OdometryChain


class Localiser:
    """Frames and odometry in, beliefs out."""

    # Odometry older than this at a frame's stamp counts as missing (docs/design.md §11: no invented
    # motion while the base is silent).
    ODOMETRY_STALE_NS = 250_000_000

    def __init__(self, projection: Projection, panorama: PanoramaSettings,
                 acquisition: AcquisitionSettings | None = None,
                 settings: LocalisationSettings | None = None,
                 odometry_noise: OdometryNoiseSettings | None = None,
                 known_map: MapHolder | None = None, mount: Mount | None = None) -> None:
        """``known_map``: the map's holder, whose owner (the service's MappingSession)
        changes it; the localiser only reads it (daemon/localisation/known_map.py).
        ``mount``: where the camera sits on the robot; the odometry handed in is the
        camera's (kernel/mount.py), the motion model's noise the robot's."""
        self.mount = (mount or Mount()).robot_camera.as_tuple()
        self.unwarper = Unwarper(projection, panorama)
        self.settings = settings or LocalisationSettings()
        self.odometry_noise = odometry_noise or OdometryNoiseSettings()
        self.odometry = OdometryBuffer()
        self.panorama: np.ndarray | None = None
        self._last_odometry: Odometry | None = None
        self._last_stamp_ns: int | None = None
        self.matcher = FastMatcher()
        # Autonomous acquisition's watch (design §6), when enabled.
        self.watch = AcquisitionWatch(acquisition, self.matcher,
                                      self.unwarper.panorama.wrap_margin,
                                      self.settings.background_lrp) \
            if acquisition is not None and acquisition.enabled else None
        self._learning = False  # a place is being learned (see learning())
        self._holder = known_map or MapHolder()
        self.map: KnownMap = self._holder.current  # the snapshot this frame reads
        self.rng = np.random.default_rng(self.settings.seed)
        self.model = make_model(self.settings)
        self.tracker: PlaceTracker | None = None
        self.switcher = PlaceSwitcher(self.settings)
        self._pose_request: PoseRequest | None = None
        self._closure: CycleClosure | None = None
        # The last reliable estimate while tracking and the odometry since: after a loss
        # out of the place's view, the start of a transition to the place relocalisation
        # finds (_bridge).
        self._fix: Fix | None = None
        self._told_apart: Disambiguation | None = None  # in this frame
        self._floor_learned: FloorModel | None = None  # in this frame
        self._frames = 0
        # Search, loss and recovery (design §9): daemon/localisation/relocalisation.py.
        self.reloc = Relocalisation(self.settings)
        self._relocalise_requested = False
        p = self.unwarper.panorama
        self.local_space = LocalSpace((p.height, p.width),
                                      int(math.floor(self.unwarper.horizon_row())),
                                      self.unwarper.floor_distance_of_rows()
                                      ) if self.settings.local_space else None

    @property
    def mode(self) -> Mode:
        """What the localiser is doing: search, confirm, track, recover (design §9)."""
        return self.reloc.mode

    @property
    def search(self) -> PlaceSearch:
        return self.reloc.search

    # ------------------------------------------------------------------ the map
    @property
    def known_map(self) -> MapHolder:
        """The holder of the map this localiser reads (its owner changes it)."""
        return self._holder

    def watch_place(self, place_id: int) -> None:
        """Autonomous acquisition watches ``place_id`` (the one just learned, already in
        the map) from the next frame on. Safe to call from another thread."""
        if self.watch is not None:
            self.watch.watch_next(place_id)

    def learning(self, driving: bool) -> None:
        """A place is being learned (``driving``: the robot drives the Turn Back and Look
        cross, away from the place it is tracked in) or no longer is: meanwhile travel
        without evidence is no loss — the pose starts again in the new place. Safe to
        call from another thread."""
        self._learning = driving

    def learning_not_started(self) -> None:
        """The place acquisition asked for was not learned (refused, failed, aborted, or
        the daemon had a job already): acquisition watches the place the robot is
        tracked in again, and asks again once that one has faded. Safe to call from
        another thread."""
        if self.watch is not None:
            self.watch.not_started()

    def place_learned(self, place_id: int) -> None:
        """A place just learned and in the map with its transitions: acquisition watches
        it, and tracking starts at its reference — Turn Back and Look ends where it
        began, to within the cross's own error (AFTER_LEARNING_SIGMA). Safe to call from
        another thread."""
        self.watch_place(place_id)
        self.set_pose(place_id, (0.0, 0.0, 0.0), AFTER_LEARNING_SIGMA_M,
                      AFTER_LEARNING_SIGMA_RAD)

    def know_floor(self, floor: FloorModel) -> None:
        """The floor model stored with the map (design §4): the places' profiles were
        made with it, so it is used instead of learning one from the first frame. Call
        before the first frame."""
        if self.local_space is not None:
            self.local_space.know_floor(floor)

    def place_profile(self, reference_panorama: np.ndarray | None) -> np.ndarray | None:
        """The local space profile (design §4) of a place being learned, from its colour
        reference panorama through the floor learned on this run; None before the floor
        is (no colour frame yet) or without a colour panorama."""
        local = self.local_space
        if local is None or local.floor is None or reference_panorama is None \
                or reference_panorama.ndim != 3:
            return None
        return local.profile_of(core_of(reference_panorama, self.unwarper.panorama.wrap_margin))

    def set_pose(self, place_id: int, pose: tuple[float, float, float],
                 sigma_xy: float | None = None, sigma_yaw: float | None = None) -> None:
        """Start tracking at ``pose`` in place ``place_id`` from the next frame on (design
        §7: particles spread by the sigmas, the settings' defaults when None). Safe to call
        from another thread; PlacecellError for a place the map does not hold."""
        known = self._holder.current
        if place_id not in known:
            raise PlacecellError(f"place {place_id} is not in the map "
                                 f"({len(known)} places)")
        if not all(math.isfinite(v) for v in pose):
            raise PlacecellError(f"a pose is three finite numbers, got {pose}")
        s = self.settings
        self._pose_request = PoseRequest(
            place_id, (float(pose[0]), float(pose[1]), float(pose[2])),
            s.initial_sigma_xy_m if sigma_xy is None else float(sigma_xy),
            s.initial_sigma_yaw_rad if sigma_yaw is None else float(sigma_yaw))

    def resume(self, place_id: int, pose: tuple[float, float, float], sigma_xy: float,
               sigma_yaw: float) -> None:
        """Start from the pose saved when the daemon last stopped (design §11): tracked
        at once, but ``relocalising`` until the view confirms it as it confirms a global
        pick (event ``relocalised``, how ``resumed``); not confirmed within
        ``confirm_frames``, the whole map is searched without that place first."""
        self.set_pose(place_id, pose, sigma_xy, sigma_yaw)
        assert self._pose_request is not None
        self._pose_request = dataclasses.replace(self._pose_request, confirm="resumed")

    def relocalise(self) -> None:
        """Forget the pose and search the whole map from the next frame on (cmd/relocalise).
        Safe to call from another thread."""
        self._relocalise_requested = True

    def reliable_estimate(self) -> tuple[int, UncertainSE2] | None:
        """(place, T_place_robot) when the current estimate is reliable (σ_xy and
        confidence as for closing a cycle), else None. Safe to call from another thread."""
        tracker = self.tracker
        if tracker is None or tracker.estimate is None or self.mode != "track" \
                or self.reloc.guessing:
            return None  # not while lost, before a relocalisation is confirmed, while
            # the sensor output is low (a robot carried off keeps a tight covariance), or
            # while a tracker started from a guess has not yet found the robot
        est = tracker.estimate
        if not reliable(est.covariance, tracker.confidence, self.settings):
            return None
        # The place's depths were measured over its cross with the base's odometry, so
        # its whole frame shares the odometry's unknown scale error: a position r from the
        # reference is off by scale_sigma·r along r, for every landmark alike (the filter,
        # taking them as independent, cannot see it). Fused with odometry as if
        # independent of it, a link would otherwise claim more than it knows.
        r = np.array([est.pose[0], est.pose[1], 0.0])
        covariance = est.covariance + self.odometry_noise.scale_sigma ** 2 * np.outer(r, r)
        return tracker.place.id, UncertainSE2(SE2.of(est.pose), covariance)

    def add_odometry(self, samples: list[Odometry]) -> None:
        self.odometry.extend(samples)
        for chain in (c.odometry for c in (self._closure, self._fix) if c is not None):
            for sample in samples:
                chain.add(sample)

    # ------------------------------------------------------------------ per frame
    def process_frame(self, frame: Frame) -> tuple[Belief, MapUpdates]:
        """One frame: what the localiser believes, and what the frame found that changes
        the map (its owner stores that; this class only reads the map)."""
        t0 = time.perf_counter()  # timing only; never used by the method
        self.map = self._holder.current  # one map for the whole frame
        self.panorama = self.unwarper.unwarp(frame.image)
        grey = to_grey(self.panorama)
        self._told_apart = self._floor_learned = None
        timings = {"unwarp": (time.perf_counter() - t0) * 1e3}
        local_space = self.local_space
        if local_space is not None and self.panorama.ndim == 3 and (
                self.mode != "track" or self._frames % self.settings.local_space_every == 0):
            t1 = time.perf_counter()
            knew = local_space.floor is not None
            local_space.update(core_of(self.panorama, self.unwarper.panorama.wrap_margin))
            if not knew:  # learned from this frame: the map keeps it
                self._floor_learned = local_space.floor
            timings["local_space"] = (time.perf_counter() - t1) * 1e3
        odo = self.odometry.at(frame.stamp_ns, max_extrapolation_ns=self.ODOMETRY_STALE_NS)
        motion = None
        if odo is not None and self._last_odometry is not None:
            motion = relative_motion(self._last_odometry, odo)
        dt_s = 0.1 if self._last_stamp_ns is None else \
            max(1e-3, (frame.stamp_ns - self._last_stamp_ns) / 1e9)
        self._last_odometry, self._last_stamp_ns = odo, frame.stamp_ns
        self._frames += 1
        prepared: list[PreparedPanorama] = []  # made at most once, when first needed

        def prepare() -> PreparedPanorama:
            if not prepared:
                prepared.append(PreparedPanorama.of(grey))
            return prepared[0]

        t1 = time.perf_counter()
        started = self._apply_pose_request(grey, odo)
        local = None
        if self.tracker is not None and not started:
            local = self.tracker.update(grey, motion, dt_s)
        timings["positioning"] = (time.perf_counter() - t1) * 1e3
        t2 = time.perf_counter()
        mode = self.mode
        searched, event = self._supervise(prepare, grey, local, frame.stamp_ns,
                                          0.0 if motion is None else math.hypot(*motion[:2]))
        timings["search"] = (time.perf_counter() - t2) * 1e3
        t2 = time.perf_counter()
        scores: tuple[PlaceScore, ...] = ()
        switched_from, closed = None, None
        if self.tracker is not None and self.mode == mode and mode in ("track", "confirm") \
                and self._frames % self.settings.recognise_every == 0:
            scores, switched_from = self._recognise(prepare(), grey, odo, frame.stamp_ns)
        scores = _merged(scores, searched)
        # A cycle's estimate in the new place counts once the place is confirmed (entered
        # from a guess, or chosen by the search): a candidate can look reliable for
        # frames and still be a look-alike's.
        if self._closure is not None and local is not None and self.tracker is not None \
                and self.tracker.place.id == self._closure.to_id and self.mode == "track":
            closed = self._observe_closure(local)
        if self.mode == "track" and local is not None and odo is not None \
                and self.tracker is not None \
                and reliable(local.estimate.covariance, local.confidence, self.settings):
            self._fix = Fix(self.tracker.place.id,
                            UncertainSE2(SE2.of(local.estimate.pose), local.estimate.covariance),
                            OdometryChain(odo, self.odometry_noise))
        timings["recognition"] = (time.perf_counter() - t2) * 1e3
        t3 = time.perf_counter()
        watched = WatchStep() if self.watch is None else self.watch.observe(
            self.map, prepare, grey, odo, self._tracked(),
            lambda ids: self._score_many(prepare(), ids, estimated=True))
        recent, recent_lrp = watched.recent, watched.recent_lrp
        decision, background, revisited = watched.decision, watched.backgrounds, \
            watched.revisited
        if revisited is not None and self.tracker is not None \
                and self.tracker.estimate is not None \
                and self.mode == "track":  # else the search finds the place itself
            switched_from = self._move_to(revisited.place_id, grey, odo, frame.stamp_ns)
        timings["acquisition"] = (time.perf_counter() - t3) * 1e3
        timings["total"] = (time.perf_counter() - t0) * 1e3
        belief = self._belief(frame.stamp_ns, odo, motion, local, scores, switched_from,
                              recent, recent_lrp, decision,
                              {k: round(v, 3) for k, v in timings.items()}, event)
        return belief, MapUpdates(closed, background, self._floor_learned)

    def recognise(self, frame: Frame, place_ids: list[int], estimated: bool = False
                  ) -> tuple[PlaceScore, ...]:
        """Each place's LRP in ``frame`` and its lead over the place's background (§9.2),
        without touching the belief: what a frame's recognition step computes, for
        evaluations that ask about places of their choosing. ``estimated``: a place whose
        background was never measured is scored against its estimate (as the global
        search scores it), not the default."""
        prepared = PreparedPanorama.of(to_grey(self.unwarper.unwarp(frame.image)))
        return tuple(self._score_many(prepared, place_ids, estimated))

    def recognise_view(self, panorama: np.ndarray, place_ids: list[int]
                       ) -> list[PlaceScore]:
        """Each place's LRP in an unwarped ``panorama`` (with its wrap margin) and its lead
        over its background, estimated where never measured (as the global search scores
        places); places not in the map are left out. For the map's owner, from another
        thread: it reads the map holder's current snapshot, not the frame's."""
        known = self._holder.current
        return self._score_many(PreparedPanorama.of(to_grey(panorama)),
                                [p for p in place_ids if p in known.places], True, known)

    def _score_many(self, prepared: PreparedPanorama, place_ids: list[int],
                    estimated: bool = False, known: KnownMap | None = None
                    ) -> list[PlaceScore]:
        """LRP and lead over the background (§9.2, KnownMap.background) of each place, in
        one matching pass; ``estimated``: with the backgrounds estimated at learning (the
        global search, which compares every place with every other); ``known``: the map
        snapshot (this frame's unless given)."""
        known = self.map if known is None else known
        lrps = self.matcher.lrps(prepared, [known.places[p].templates for p in place_ids])
        return [PlaceScore(p, lrp, lrp - known.background(p, self.settings.background_lrp,
                                                          estimated))
                for p, lrp in zip(place_ids, lrps, strict=True)]

    # ------------------------------------------------------------------ global (§9)
    def _supervise(self, prepare: Callable[[], PreparedPanorama], grey: np.ndarray,
                   local: LocalResult | None, stamp_ns: int, travelled_m: float
                   ) -> tuple[list[PlaceScore], LocalisationEvent | None]:
        """Search, loss detection and recovery for this frame (the state machine of
        daemon/localisation/relocalisation.py): the places recognised by the search,
        and the event this frame brings, if any."""
        places = list(self.map.places)
        reloc = self.reloc
        if self._relocalise_requested:
            self._relocalise_requested = False
            reloc.begin_search(stamp_ns, self._frames)
        if not places:
            return [], None
        trackers = _FrameTrackers(self, prepare, grey)
        if reloc.mode == "search":
            current = None if self.tracker is None else self.tracker.place.id
            return reloc.searching(trackers, places, stamp_ns, self._frames, current), None
        if local is None or self.tracker is None:
            return [], None  # a tracker started this frame
        current = self.tracker.place.id
        out = reloc.supervise(trackers, places, tuple(self.map.neighbours(current)), current,
                              local.support, self._recovered(local),
                              0.0 if self._learning else travelled_m, stamp_ns, self._frames)
        return out.scores, out.event

    def _lost(self, left: bool) -> None:
        """A loss declared: the last fix bridges to the place found next only when the
        robot ``left`` the place's view on its own (relocalisation.left_view: blind
        travel, or an output that only faded, whether the output rule or another place
        leading the search declared it), away from the reference; a view that
        contradicted the estimate (carried off?), or a loss where the place is in view:
        no bridge — odometry cannot see a carry, and the transition would be wrong."""
        if not left or _near_reference(self.tracker, self.settings.bridge_from_m):
            self._fix = None

    def _tell_apart(self, grey: np.ndarray, best: int, places: list[int],
                    at_once: bool = False) -> int | None:
        """The search's pick (design §5, thesis §9.5): ``best`` unless places with
        disambiguating features against it that can part the two (``can_decide``) stand
        within ``ambiguity_margin`` of it. Those
        must stay so for ``ambiguity_frames`` frames (None until then: the search goes
        on, its scores may part); then their features decide (``choose``) — overruling
        the lower levels only by ``disambiguation_min_vote``. Features none of which is
        seen, or that part their top two by less than ``disambiguation_min_evidence``,
        say little from where the robot stands (0.4 m off a reference their NCCs fall to
        ~0.6 in either place): the decision waits for a clearer view, for at most
        ``disambiguation_max_wait_frames`` frames, then keeps the lower levels' pick.
        ``at_once`` (recovery, which does not wait): the features decide in this frame,
        and an unclear view keeps the lower levels' pick at once."""
        s = self.settings
        if not s.disambiguation:
            return best
        ranked = {c.place_id: c.lead for c in self.search.ranked()}
        if best not in ranked:
            return best  # not recognised in this search yet: nothing to compare it with
        top = ranked[best]
        rivals = [p for p, lead in sorted(ranked.items(), key=lambda kv: -kv[1])
                  if p != best and p in places and top - lead <= s.ambiguity_margin]
        rivals = [p for p in rivals if (pair := self.map.features.get(frozenset((best, p))))
                  is not None and can_decide(pair, s.disambiguation_min_evidence)
                  ][:MAX_RIVALS]
        if not rivals:
            self.reloc.ambiguous_frames = 0
            return best  # no look-alike of it stands near: nothing for the features to do
        self.reloc.ambiguous_frames += 1
        if self.reloc.ambiguous_frames < s.ambiguity_frames and not at_once:
            return None
        contenders = [best, *rivals]
        features: dict[tuple[int, int], Feature] = {}
        for x in contenders:
            for y in contenders:
                pair = self.map.features.get(frozenset((x, y))) if x < y else None
                if pair is not None:
                    features[(pair.a_id, pair.b_id)] = pair.a
                    features[(pair.b_id, pair.a_id)] = pair.b
        started = time.perf_counter()
        winner, scores, nccs = choose(grey, features)
        elapsed_ms = (time.perf_counter() - started) * 1e3
        first, second = sorted(scores.values(), reverse=True)[:2]
        # Clear: the winner's features are seen (its vote above 0) and part it from the
        # next; with no feature seen the votes differ only by the features' spans.
        clear = first > 0.0 and first - second >= s.disambiguation_min_evidence
        if not clear and not at_once and self.reloc.ambiguous_frames < s.ambiguity_frames \
                + s.disambiguation_max_wait_frames:
            return None  # the features say little from here: look again on the next frame
        self.reloc.ambiguous_frames = 0
        if not clear or scores[winner] - scores.get(best, 0.0) < s.disambiguation_min_vote:
            winner = best  # the features barely disagree with the lower levels: keep theirs
        runner_up = max((p for p in scores if p != winner
                         and frozenset((winner, p)) in self.map.features),
                        key=lambda p: scores[p])  # best, at least, is paired with each
        self._told_apart = Disambiguation(winner, runner_up, nccs[(winner, runner_up)],
                                          nccs[(runner_up, winner)],
                                          scores[winner] - scores[runner_up], elapsed_ms,
                                          len(features) // 2)
        return winner

    def _search_step(self, prepare: Callable[[], PreparedPanorama], grey: np.ndarray,
                     places: list[int], first: tuple[int, ...]) -> list[PlaceScore]:
        """One frame of the search: the cue of every place (signature similarity, design
        §9), then the frame's budget of places recognised, best first."""
        with_signature = [p for p in places if self.map.places[p].place.signature is not None]
        if with_signature:
            sigs = np.stack([self.map.places[p].place.signature  # type: ignore[misc]
                             for p in with_signature])
            here = signature(grey, self.unwarper.panorama.wrap_margin)
            self.search.set_cue(dict(zip(with_signature, similarity(here, sigs).tolist(),
                                         strict=True)), first, self._local_matches(places))
        scored = self._score_many(prepare(), self.search.to_score(places, first),
                                  estimated=True)
        self.search.observe(scored)
        return scored

    def _local_matches(self, places: list[int]) -> dict[int, float] | None:
        """Each place's local space match with the floor grid now (design §4), for the
        places with a profile; None while the floor is not learned."""
        local = self.local_space
        if local is None or local.floor is None or self.settings.local_space_margin >= 1.0:
            return None  # no floor yet, or every place kept whatever its match
        with_profile = [p for p in places if self.map.places[p].place.local_space is not None]
        if not with_profile:
            return None
        profiles = np.stack([self.map.places[p].place.local_space  # type: ignore[misc]
                             for p in with_profile])
        return dict(zip(with_profile, match_many(local.profile(), profiles, CAP_M).tolist(),
                        strict=True))

    def _recovered(self, local: LocalResult) -> bool:
        return local.support >= self.settings.recovered_output and reliable(
            local.estimate.covariance, local.confidence, self.settings)

    def _start_in(self, grey: np.ndarray, place_id: int) -> None:
        """Global relocalisation's pick: particles over ``recovery_sigma_m`` around the
        place's reference, the orientation from the bearings (§9.3.2, eq. 8.34)."""
        tracker = PlaceTracker(self.map.places[place_id].place, self.settings, self.model,
                               self.rng, self.mount)
        tracker.start_anywhere(grey, self.settings.recovery_sigma_m)
        self.tracker, self._closure = tracker, self._bridge(place_id)

    def _bridge(self, place_id: int) -> CycleClosure | None:
        """After a loss out of the last place's view, relocalisation's pick in a place
        the map does not join to it: the transition between them, measured as a cycle's
        is (last reliable estimate ∘ odometry since ∘ the new estimate⁻¹) once the new
        estimate is reliable — how two segments are joined when the robot drove back
        into mapped space out of view (design §6, issue 31). Only within ``bridge_max_m``
        of odometry, on an unbroken run; a loss within ``bridge_from_m`` of the place's
        reference, where it should be recognised (a kidnap), leaves no fix."""
        fix, s = self._fix, self.settings  # kept: a rejected pick may be followed by another
        if fix is None or fix.place_id == place_id or fix.odometry.broken \
                or not 0 < fix.odometry.distance_m <= s.bridge_max_m \
                or place_id in self.map.through_graph(fix.place_id, THROUGH_GRAPH_PLACES):
            return None
        return CycleClosure(fix.place_id, place_id, fix.T_place_robot, fix.odometry, s)

    def _spread(self, grey: np.ndarray, step: int) -> None:
        """§9.3.2 step 1: the particles around the estimate (σ recovery_local_sigma_m);
        step 2: over the whole place (σ recovery_sigma_m around its reference)."""
        assert self.tracker is not None and self.tracker.estimate is not None
        s = self.settings
        if step == 1:
            r = s.recovery_local_sigma_m
            self.tracker.move_to(self.tracker.estimate.pose, np.diag([r * r, r * r, r * r]))
        else:
            self.tracker.start_anywhere(grey, s.recovery_sigma_m)

    def _apply_pose_request(self, grey: np.ndarray, odo: Odometry | None) -> bool:
        request = self._pose_request
        if request is None or request.place_id not in self.map:
            return False  # a place stored while this frame's map was taken: the next frame
        if self._pose_request is request:  # not replaced by another thread meanwhile
            self._pose_request = None
        self.tracker = PlaceTracker(self.map.places[request.place_id].place, self.settings,
                                    self.model, self.rng, self.mount)
        self.tracker.start(grey, request.pose, request.sigma_xy, request.sigma_yaw)
        self._closure = None
        self.reloc.told(self._last_stamp_ns or 0, self._frames, request.confirm)
        return True

    def _recognise(self, prepared: PreparedPanorama, grey: np.ndarray, odo: Odometry | None,
                   stamp_ns: int) -> tuple[tuple[PlaceScore, ...], int | None]:
        """LRP − background of the current place, its neighbours and a few others; pass
        the estimate on when another place takes over (§8.2, §7.1.3): over a transition
        the estimate carries on; into a place with no transition from here it starts
        from a guess, confirmed before it is published tracking (Relocalisation.
        handed_over), and the cycle's transition is measured once it is."""
        assert self.tracker is not None and self.tracker.estimate is not None
        current = self.tracker.place.id
        links = self.map.neighbours(current)
        neighbours = [p for p in links if p in self.map.places]
        estimate = self.tracker.estimate
        x, y, _ = estimate.pose
        through = self.map.through_graph(current, THROUGH_GRAPH_PLACES)
        distance = {current: math.hypot(x, y)} | {  # T_current_p's origin: p's reference
            p: math.hypot(T.mean.x - x, T.mean.y - y) for p, T in through.items()}
        near = [p for p in through if p not in neighbours and p in self.map.places
                and distance[p] <= self.settings.cycle_near_m]
        checked = self.switcher.to_check(current, neighbours, list(self.map.places), near)
        scores = self._score_many(prepared, checked)
        switch = self.switcher.decide(current, neighbours, scores, distance, near, beyond(
            current, estimate.pose, through, self.settings.cycle_within_m))
        if switch is None:
            return tuple(scores), None
        here = UncertainSE2(SE2.of(estimate.pose), estimate.covariance)
        target = self.map.places[switch.place_id].place
        tracker = PlaceTracker(target, self.settings, self.model, self.rng, self.mount)
        if carried_over(switch, through):
            # §8.2, eq. 8.35: the pose in the neighbour's frame, T_to_robot = T_from_to⁻¹ ∘
            # T_from_robot; the particles spread over both uncertainties. A place with no
            # transition from here is reached through the graph's path to it (its drift
            # in the covariance), and the direct transition is then measured (§7.1.3).
            T = links[switch.place_id] if switch.kind == "neighbour" \
                else through[switch.place_id]
            moved = T.inverse().compose(here)
            if switch.kind == "neighbour":
                tracker.move_to(moved.mean.as_tuple(), moved.covariance)
            else:  # a long path drifts, in heading too: the landmarks set the orientation
                spread = math.sqrt(max(moved.covariance[0, 0] + moved.covariance[1, 1], 0.0))
                tracker.start_anywhere(grey, max(GRAPH_MIN_SIGMA_M, spread),
                                       (moved.mean.x, moved.mean.y))
                if odo is not None:
                    self._closure = CycleClosure(current, switch.place_id, here,
                                                 OdometryChain(odo, self.odometry_noise),
                                                 self.settings)
        else:
            # No transition: start over in the place (σ recovery_sigma around its reference,
            # orientation from the bearings, §9.3.2) and measure the cycle's transition.
            r = self.settings.recovery_sigma_m
            tracker.start(grey, (0.0, 0.0, 0.0), r, math.pi)
            if odo is not None:
                self._closure = CycleClosure(current, switch.place_id, here,
                                             OdometryChain(odo, self.odometry_noise),
                                             self.settings)
        self.tracker = tracker
        # A new place's landmarks: its own evidence from here on; from a guess, to be
        # confirmed, unless the estimate was carried over a transition.
        if switch.kind == "neighbour":
            self.reloc.switched()
        else:
            self.reloc.handed_over(stamp_ns, self._frames)
        return tuple(scores), current

    def _observe_closure(self, local: LocalResult) -> Transition | None:
        assert self._closure is not None
        est = local.estimate
        closed = self._closure.observe(UncertainSE2(SE2.of(est.pose), est.covariance),
                                       local.confidence)
        if closed is not None:  # the map's owner stores it (MapUpdates.closed_transition)
            self._closure = None
        return closed

    def _belief(self, stamp_ns: int, odometry: Odometry | None,
                motion: tuple[float, float, float] | None, local: LocalResult | None,
                scores: tuple[PlaceScore, ...], switched_from: int | None,
                recent: int | None, recent_lrp: float | None,
                decision: AcquisitionDecision | None, timings: dict[str, float],
                event: LocalisationEvent | None) -> Belief:
        odometry_ok = odometry is not None
        common = dict(stamp_ns=stamp_ns, odometry_ok=odometry_ok, odometry=odometry,
                      motion_since_last=motion,
                      scores=scores, timings_ms=timings, recent_place=recent,
                      recent_place_lrp=recent_lrp, acquisition=decision,
                      switched_from=switched_from, disambiguation=self._told_apart)
        no_odometry = "" if odometry_ok else \
            "; no odometry at this frame (base silent): motion unknown"
        tracker = self.tracker
        if not self.map.places:
            return Belief(state="uninitialised", reason="the map has no places yet"
                          + no_odometry, **common)  # type: ignore[arg-type]
        if self.mode == "search" or tracker is None or tracker.estimate is None:
            n = len(self.map.places)
            done = sum(p in self.search.scores for p in self.map.places)
            best = self.search.ranked()[:1]
            reason = f"global relocalisation: {done} of {n} places recognised" + (
                f", most likely {best[0].place_id} (lead {best[0].lead:.3f})" if best else "")
            tied = self.reloc.undecided if self.mode == "search" else None
            if tied is not None and tied in self.map.places:
                reason += "; look-alikes stand tied: their features decide shortly"
                return Belief(state="relocalising", reason=reason + no_odometry, event=event,
                              place_id=tied, place_label=self.map.places[tied].place.label,
                              **common)  # type: ignore[arg-type]
            return Belief(state="relocalising", reason=reason + no_odometry, event=event,
                          **common)  # type: ignore[arg-type]
        est = tracker.estimate
        confidence = 1.0 if local is None else local.confidence
        place = tracker.place.id
        state: BeliefState = "tracking"
        reason = f"tracking in place {place}"
        support = None if local is None or math.isnan(local.support) else local.support
        if self.mode == "track" and local is not None and contradicted(
                support, local.confidence, self.settings, switched=switched_from is not None):
            state, reason = "lost", (
                f"the view does not support the estimate in place {place}: its landmarks "
                f"are not where the estimate puts them (sensor output "
                f"{0.0 if support is None else support:.3f}, confidence "
                f"{local.confidence:.2f}): not published as tracking; a loss once the "
                f"output stays below {self.settings.loss_output} for "
                f"{self.settings.loss_frames} frames")
        elif self.mode == "confirm":
            chose = {"resumed": f"resumed in place {place} from the pose saved at the "
                                f"last stop",
                     "handover": f"handed over to place {place}, which has no transition "
                                 f"from the place left: its pose starts from a guess"
                     }.get(self.reloc.confirming,
                           f"global relocalisation chose place {place}")
            state, reason = "relocalising", f"{chose}; waiting for a reliable estimate"
        elif self.mode == "recover":
            state = "lost"
            reason = (f"lost in place {place}: recovery step {self.reloc.step} of 3 ("
                      + ("particles around the estimate" if self.reloc.step == 1
                         else "particles over the whole place") + ")")
        return Belief(state=state, reason=reason + no_odometry, place_id=place,
                      place_label=tracker.place.label, pose_in_place=est.pose,
                      covariance=tuple(float(v) for v in est.covariance.ravel()),
                      confidence=confidence, particles=len(tracker.filter.particles),
                      support=support,
                      event=event, **common)  # type: ignore[arg-type]

    def _tracked(self) -> Tracked:
        """What the tracker says in this frame, for the acquisition watch."""
        tracker = self.tracker
        tracking = tracker is not None and self.mode == "track"
        estimate = None if tracker is None else tracker.estimate
        return Tracked(self.map, None if tracker is None else tracker.place.id, tracking,
                       estimate.pose if tracking and estimate is not None else None)

    def _move_to(self, place_id: int, grey: np.ndarray, odo: Odometry | None,
                 stamp_ns: int) -> int:
        """Track in ``place_id`` from here, REVISIT_SIGMA_M around its reference (the
        orientation from the bearings), confirmed before it is published tracking; the
        cycle's transition is measured from the estimate being left, if reliable.
        Returns the place left."""
        assert self.tracker is not None and self.tracker.estimate is not None
        current, est = self.tracker.place.id, self.tracker.estimate
        confidence = self.tracker.confidence
        tracker = PlaceTracker(self.map.places[place_id].place, self.settings, self.model,
                               self.rng, self.mount)
        tracker.start_anywhere(grey, REVISIT_SIGMA_M)
        self._closure = None
        if odo is not None and reliable(est.covariance, confidence, self.settings):
            self._closure = CycleClosure(current, place_id,
                                         UncertainSE2(SE2.of(est.pose), est.covariance),
                                         OdometryChain(odo, self.odometry_noise),
                                         self.settings)
        self.tracker = tracker
        self.reloc.handed_over(stamp_ns, self._frames)
        return current


class _FrameTrackers:
    """The localiser's side of relocalisation in one frame (relocalisation.Trackers):
    the frame's grey panorama and its preparation, shared with the rest of the frame."""

    def __init__(self, localiser: Localiser, prepare: Callable[[], PreparedPanorama],
                 grey: np.ndarray) -> None:
        self._localiser, self._prepare, self._grey = localiser, prepare, grey

    def search_step(self, places: list[int], first: tuple[int, ...]) -> list[PlaceScore]:
        return self._localiser._search_step(self._prepare, self._grey, places, first)

    def tell_apart(self, best: int, places: list[int], at_once: bool = False) -> int | None:
        return self._localiser._tell_apart(self._grey, best, places, at_once)

    def start_in(self, place_id: int) -> None:
        self._localiser._start_in(self._grey, place_id)

    def spread(self, step: int) -> None:
        self._localiser._spread(self._grey, step)

    def lost(self, left: bool) -> None:
        self._localiser._lost(left)


def _merged(*groups: tuple[PlaceScore, ...] | list[PlaceScore]) -> tuple[PlaceScore, ...]:
    """Scores from several steps of one frame, one per place (the first kept)."""
    out: dict[int, PlaceScore] = {}
    for group in groups:
        for sc in group:
            out.setdefault(sc.place_id, sc)
    return tuple(out.values())
