"""The robot's link to its fleet (docs/fleet.md): its places put into the fleet's key space,
the other robots' taken into its own map.

The fleet's map lives in its routers' storage (zenohd with the storage manager plugin,
``config/fleet/router.json5``), not in a protocol of ours. At start the link waits, up to
``[fleet] fetch_timeout_s``, until a complete storage of the key space is known (a querier's
matching status), takes every place and transition of the other robots from it, and puts
those of its own the storage lacks; then it follows the key space by subscription and puts
each place and transition as it is added. It catches up the same way each time a storage
comes back after none was reachable (a robot cut off, a router restarted empty). Taking
happens before the robot acts on its map, so a robot started with an empty map in a mapped
building localises in the fleet's places instead of learning a first place of its own. A
map that is not the one the fleet knows under this robot's name puts nothing
(:meth:`FleetLink._check_own`).

A place is named across the fleet by the robot that learned it and its id there
(daemon/store/fleet_wire.py); the map file remembers which of its places came from where
(schema 9, ``origins``), so a place is taken once, and a restart takes only what is new.
A transition is taken once both its places are in the map (until then it waits here, in
memory: the storage has it again at the next start). A sample that is not a fleet
document, or of another camera geometry, is refused with a log line and reaches no map.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from daemon.config import FleetSettings
from daemon.mapping.transition import Transition
from daemon.service.mapping_session import Event, MappingSession
from daemon.store.fleet_wire import (
    FleetDocumentError,
    FleetPlace,
    FleetTransition,
    PlaceName,
    decode_place,
    decode_transition,
    encode_place,
    encode_transition,
    place_key,
    transition_key,
)
from kernel.errors import PlacecellError

log = logging.getLogger(__name__)

# A place is ~0.5 MB in fragments: with zenoh's default (drop when the queue is full) a
# busy machine lost the samples put right after one. The map is worth the wait.
SHARED = zenoh.CongestionControl.BLOCK


class FleetLink:
    """One robot's link (module docstring). ``publish``: events to publish (place_adopted,
    transition_added)."""

    def __init__(self, session: MappingSession, zenoh_session: zenoh.Session,
                 settings: FleetSettings, robot: str, geometry_checksum: str,
                 publish: Callable[[list[Event]], None]) -> None:
        self.session = session
        self.z = zenoh_session
        self.settings = settings
        self.robot = robot
        self.geometry_checksum = geometry_checksum
        self._publish = publish
        self._lock = threading.Lock()  # one sample taken at a time
        self._waiting: dict[str, FleetTransition] = {}  # by key: a place not here yet
        self._subscriber: Any = None
        self._querier: Any = None
        self._listener: Any = None
        self._storage = threading.Event()  # a complete storage of the key space is known
        self._resync = threading.Event()  # it came back: catch up
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._resyncing, name="placecell-fleet",
                                        daemon=True)
        self.refused = 0  # samples refused (malformed, foreign geometry)
        self.conflict: str | None = None  # why nothing of this map is put (_check_own)

    # ------------------------------------------------------------------ start, stop
    def start(self) -> int:
        """Take the fleet's places, put this robot's own, then follow the key space
        (module docstring). Returns how many places were taken."""
        prefix = self.settings.key_prefix
        # Subscribed before asking: a place put meanwhile arrives one way or the other.
        self._subscriber = self.z.declare_subscriber(f"{prefix}/**", self._on_sample)
        self._querier = self.z.declare_querier(f"{prefix}/**",
                                               target=zenoh.QueryTarget.ALL_COMPLETE,
                                               timeout=self.settings.fetch_timeout_s)
        # A complete storage of the key space known, at start and each time it comes back
        # (a router restarted empty, a robot cut off and back): zenoh's matching event.
        self._listener = self._querier.declare_matching_listener(self._on_matching)
        # zenoh's stubs type matching_status as bool; it is a MatchingStatus.
        if self._querier.matching_status.matching:  # type: ignore[attr-defined]
            self._storage.set()
        taken = 0
        if self._storage.wait(self.settings.fetch_timeout_s):
            try:
                taken = self._sync()
            except (PlacecellError, zenoh.ZError) as e:  # the robot runs on its own map
                log.error("fleet: taking the fleet's places failed: %s (again when a "
                          "storage returns)", e)
        else:
            log.warning("fleet: no storage of %s/** answered within %.1f s; acting on the "
                        "own map (the fleet's places are taken, and its own put, once one "
                        "does)", prefix, self.settings.fetch_timeout_s)
        self._resync.clear()  # just done
        self._thread.start()
        return taken

    def _on_matching(self, status: Any) -> None:  # a zenoh thread: no query here
        if status.matching:
            self._storage.set()
            self._resync.set()
        else:
            self._storage.clear()
            log.warning("fleet: no storage of %s/** reachable; mapping on alone",
                        self.settings.key_prefix)

    def _resyncing(self) -> None:
        while True:
            self._resync.wait()
            if self._closing.is_set():
                return
            self._resync.clear()
            try:
                log.info("fleet: a storage of %s/** is back; catching up",
                         self.settings.key_prefix)
                self._sync()
            except (PlacecellError, zenoh.ZError) as e:
                log.error("fleet: catching up failed: %s (again when a storage returns)", e)

    def _sync(self) -> int:
        """Every other robot's place and transition the storage holds and this map does
        not, taken; this map's own the storage lacks, put. Returns the places taken."""
        samples = [r.ok for r in self._querier.get() if r.ok is not None]
        # Places before transitions (a transition is taken once both ends are here),
        # each robot's in the order it learned them.
        samples.sort(key=lambda s: self._order(str(s.key_expr)))
        taken, present = 0, set()
        for sample in samples:
            key, payload = str(sample.key_expr), sample.payload.to_bytes()
            present.add(key)
            self._check_own(key, payload)
            taken += self._take(key, payload)
        if self.conflict is not None:
            log.error("fleet: %s", self.conflict)
            return taken
        put = self._put_own(present)
        log.info("fleet: %d places taken from %s/**, %d of this map's own put", taken,
                 self.settings.key_prefix, put)
        return taken

    def _chunks(self, key: str) -> list[str]:
        """The key's chunks after the fleet's prefix: robot, kind, then the ids."""
        return key[len(self.settings.key_prefix) + 1:].split("/")

    def _order(self, key: str) -> tuple[bool, str, int, str]:
        parts = self._chunks(key)
        transition = len(parts) > 1 and parts[1] == "transition"
        number = int(parts[2]) if len(parts) > 2 and parts[2].isdigit() else 0
        return transition, parts[0], number, key

    def close(self) -> None:
        self._closing.set()
        self._resync.set()
        if self._thread.is_alive():
            self._thread.join(self.settings.fetch_timeout_s)
        for declared in (self._listener, self._querier, self._subscriber):
            if declared is not None:
                declared.undeclare()
        self._listener = self._querier = self._subscriber = None

    # ------------------------------------------------------------------ putting
    def on_event(self, kind: str, fields: dict[str, Any]) -> None:
        """The daemon's events: a place this robot learned is put, and each transition
        it added (learned with a place, a closed cycle, held odometry confirmed); those
        taken from the fleet (``robot`` given) are the other robot's to put."""
        try:
            if kind == "place_learned":
                self._put_place(int(fields["place"]))
            elif kind == "transition_added" and "robot" not in fields:
                t = self.session.mapper.graph.transition(int(fields["from"]),
                                                         int(fields["to"]))
                if t is not None:
                    self._put_transition(t)
        except (PlacecellError, zenoh.ZError) as e:
            log.error("fleet: %s %s not put: %s (put at the next catching up)",
                      kind, fields, e)

    def _put_own(self, present: set[str]) -> int:
        """This map's own places and its transitions that the storage does not hold
        (``present``: the keys it answered with), a transition under no robot's name: one
        taken from the fleet is there under the name of the robot that measured it, and
        put again under this one's it would be claimed by every robot that took it (at
        each start, before this rule). Returns the places put."""
        mapper = self.session.mapper
        prefix = self.settings.key_prefix
        with mapper.lock:
            own = [p.id for p in mapper.graph.places if p.id not in mapper.origins]
            transitions = mapper.store.transitions()
        missing = [p for p in own if place_key(prefix, PlaceName(self.robot, p)) not in present]
        for place_id in missing:
            self._put_place(place_id)
        held = {tuple(chunks[2:]) for chunks in map(self._chunks, present)
                if len(chunks) == 6 and chunks[1] == "transition"}  # its two places' names
        for t in transitions:
            a, b = self._name(t.from_id), self._name(t.to_id)
            if (a.robot, a.id) < (b.robot, b.id) \
                    and (a.robot, str(a.id), b.robot, str(b.id)) not in held:
                self._put_transition(t)
        return len(missing)

    def _check_own(self, key: str, payload: bytes) -> None:
        """A place the storage holds under this robot's name must be this map's place
        of that id (the same creation time): a robot given another map file under the
        same name would otherwise overwrite the fleet's places with others of the same
        names, which the robots that took the old ones would never take. On a mismatch
        nothing more of this map is put (``conflict`` says why); taking goes on."""
        rest = self._chunks(key)
        if len(rest) != 3 or rest[0] != self.robot or rest[1] != "place":
            return
        try:
            shared = decode_place(payload)
        except FleetDocumentError:
            return  # counted where it is taken
        mapper = self.session.mapper
        with mapper.lock:
            mine = mapper.graph.place(shared.name.id) if shared.name.id in mapper.graph \
                and shared.name.id not in mapper.origins else None
        if mine is None or mine.created_unix_s != shared.place.created_unix_s:
            self.conflict = (
                f"the fleet holds place {shared.name.id} of robot {self.robot!r} learned "
                f"at {shared.place.created_unix_s:.3f} (unix s), which this map "
                f"{'has not' if mine is None else 'has with another time'}: another map "
                "file under this robot's name; nothing of this map is put (give the robot "
                "another name, or its own map file back)")

    def _put_place(self, place_id: int) -> None:
        if self.conflict is not None:
            return
        mapper = self.session.mapper
        if place_id in mapper.origins:
            return  # another robot's: it puts it itself
        with mapper.lock:
            place = mapper.store.place(place_id, panorama=True)
            views = mapper.store.views(place_id)
        name = PlaceName(self.robot, place_id)
        self.z.put(place_key(self.settings.key_prefix, name),
                   encode_place(FleetPlace(name, self.geometry_checksum, place, views)),
                   congestion_control=SHARED)

    def _put_transition(self, t: Transition) -> None:
        """One key per transition: put from the place named first."""
        if self.conflict is not None:
            return
        a, b = self._name(t.from_id), self._name(t.to_id)
        if (b.robot, b.id) < (a.robot, a.id):
            t, a, b = t.reversed(), b, a
        self.z.put(transition_key(self.settings.key_prefix, self.robot, a, b),
                   encode_transition(FleetTransition(
                       self.robot, a, b, Transition(a.id, b.id, t.T_from_to, t.source))),
                   congestion_control=SHARED)

    def _name(self, place_id: int) -> PlaceName:
        origin = self.session.mapper.origins.get(place_id)
        return PlaceName(self.robot, place_id) if origin is None else PlaceName(*origin)

    # ------------------------------------------------------------------ taking
    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        self._take(str(sample.key_expr), sample.payload.to_bytes())

    def _take(self, key: str, payload: bytes) -> int:
        """A sample of the key space into the map; 1 if it was a place taken."""
        rest = self._chunks(key)
        if len(rest) < 2 or rest[0] == self.robot:
            return 0  # this robot's own, echoed
        with self._lock:
            try:
                if rest[1] == "place":
                    return self._take_place(key, decode_place(payload), rest[0])
                if rest[1] == "transition":
                    self._take_transition(key, decode_transition(payload), rest[0])
                    return 0
                raise FleetDocumentError(f"no fleet document is put at {rest[1]!r}")
            except (FleetDocumentError, PlacecellError) as e:
                self.refused += 1
                log.warning("fleet: refused %s: %s", key, e)
                return 0

    def _take_place(self, key: str, shared: FleetPlace, robot: str) -> int:
        if shared.name.robot != robot:
            raise FleetDocumentError(f"robot {robot!r} put a place of robot "
                                     f"{shared.name.robot!r}")
        if shared.geometry_checksum != self.geometry_checksum:
            raise FleetDocumentError(
                f"seen with another panorama geometry (checksum {shared.geometry_checksum}, "
                f"this robot's {self.geometry_checksum}): of no use to this camera")
        if self._local(shared.name) is not None:
            return 0  # taken before
        events = self.session.adopt_place(shared.place, shared.views, robot,
                                          shared.name.id)
        if not events:
            return 0  # localisation mode: the map is read-only
        log.info("fleet: place %d of robot %s taken as place %d", shared.name.id, robot,
                 events[0][1]["place"])
        self._publish(events)
        for waiting_key, waiting in list(self._waiting.items()):
            if shared.name in (waiting.a, waiting.b):
                self._take_transition(waiting_key, waiting, waiting.robot)
        return 1

    def _take_transition(self, key: str, shared: FleetTransition, robot: str) -> None:
        if shared.robot != robot:
            raise FleetDocumentError(f"robot {robot!r} put a transition of robot "
                                     f"{shared.robot!r}")
        a, b = self._local(shared.a), self._local(shared.b)
        if a is None or b is None:
            self._waiting[key] = shared
            return
        self._waiting.pop(key, None)
        graph = self.session.mapper.graph
        if graph.transition(a, b) is not None:
            return  # there already
        t = shared.transition
        self._publish(self.session.adopt_transition(Transition(a, b, t.T_from_to, t.source),
                                                    robot))

    def _local(self, name: PlaceName) -> int | None:
        """The place's id in this map, None if it is not here."""
        mapper = self.session.mapper
        with mapper.lock:
            if name.robot == self.robot:
                return name.id if name.id in mapper.graph and name.id not in mapper.origins \
                    else None
            return mapper.taken.get((name.robot, name.id))

