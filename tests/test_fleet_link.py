"""Robots share places through the fleet's router and its storage (daemon/service/fleet.py,
docs/fleet.md): real zenoh sessions through a real zenohd with the storage manager plugin,
real map files. A robot puts its places and transitions; a robot with an empty map takes
them at start, follows new ones by subscription, takes each once (restarts included), and
refuses what is not a fleet document or was seen with another camera geometry."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
import zenoh

from daemon.config import FleetSettings
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.settings import AcquisitionSettings, OdometryNoiseSettings
from daemon.service.fleet import SHARED, FleetLink
from daemon.service.mapper import Link, Mapper
from daemon.service.mapping_session import Event, MappingSession
from daemon.store.fleet_wire import (
    FleetPlace,
    PlaceName,
    decode_place,
    encode_place,
    place_key,
)
from daemon.store.sqlite_store import MapStore
from kernel.se2 import SE2, UncertainSE2
from tests.daemon_harness import free_port, wait_for
from tests.map_fixtures import synthetic_place
from tools.fleet_router import client_session, fleet_routers

GEOMETRY = "fleet-geometry"
START_S = 60.0  # a router's start on a loaded machine
SETTINGS = FleetSettings(enabled=True, fetch_timeout_s=START_S)
T = UncertainSE2(SE2(1.5, 0.0, 0.0), np.diag([0.01, 0.01, 0.001]))

pytestmark = pytest.mark.xdist_group("zenohd")


class Robot:
    """A robot's map owner and fleet link on its own map file and zenoh session; the
    events its link publishes are kept, and ``arrived`` is set at each."""

    def __init__(self, name: str, path: Path, endpoint: str) -> None:
        self.name = name
        self.session = MappingSession(Mapper(MapStore.open(path, GEOMETRY),
                                             OdometryNoiseSettings()),
                                      AcquisitionSettings(enabled=False),
                                      LocalisationSettings(max_lookalikes=0))
        self.z = client_session(endpoint)
        self.events: list[Event] = []
        self.arrived = threading.Event()
        self.link = FleetLink(self.session, self.z, SETTINGS, name, GEOMETRY, self._publish)

    def _publish(self, events: list[Event]) -> None:
        self.events += events
        self.arrived.set()

    def learn(self, seed: int, after: int | None) -> int:
        """A place stored as a learn stores it, its events given to the link as the
        daemon's publish_event does."""
        rng = np.random.default_rng(seed)
        learned = self.session.store_place(synthetic_place(rng, f"{self.name}-{seed}"),
                                           [] if after is None else [Link(after, T)], [])
        self.link.on_event("place_learned", {"place": learned.place.id})
        for kind, fields in learned.events:
            self.link.on_event(kind, fields)
        return learned.place.id

    def places(self) -> dict[int, tuple[str, int] | None]:
        mapper = self.session.mapper
        return {p.id: mapper.origins.get(p.id) for p in mapper.graph.places}

    def close(self) -> None:
        self.link.close()
        self.z.close()
        self.session.mapper.store.close()


def _stored(watcher: zenoh.Session) -> set[str]:
    return {str(r.ok.key_expr) for r in watcher.get("placecell/fleet/**", timeout=5.0)
            if r.ok is not None}


def test_a_robot_takes_the_fleets_places_at_start_and_as_they_are_learned(
        tmp_path: Path) -> None:
    with fleet_routers([free_port()], tmp_path, START_S) as (router,):
        a = Robot("robot-a", tmp_path / "a.db", router.endpoint)
        watcher = client_session(router.endpoint)
        robots = [a]
        try:
            first = a.learn(1, None)
            second = a.learn(2, first)
            assert a.link.start() == 0  # the fleet had nothing: its own put
            keys = {"placecell/fleet/robot-a/place/1", "placecell/fleet/robot-a/place/2",
                    "placecell/fleet/robot-a/transition/robot-a/1/robot-a/2"}
            assert wait_for(lambda: _stored(watcher) == keys, START_S, 0.1), _stored(watcher)

            # An empty map takes both places and their transition before it acts.
            b = Robot("robot-b", tmp_path / "b.db", router.endpoint)
            robots.append(b)
            assert b.link.start() == 2
            assert b.places() == {1: ("robot-a", first), 2: ("robot-a", second)}
            assert b.session.mapper.graph.transition(1, 2) is not None
            assert sorted(b.session.known.places) == [1, 2]
            kinds = [(k, f.get("robot")) for k, f in b.events]
            assert kinds == [("place_adopted", "robot-a"), ("place_adopted", "robot-a"),
                             ("segments_joined", None), ("transition_added", "robot-a")], \
                b.events  # each place taken alone is a segment until its transition

            # A place learned now arrives by subscription, with its transition.
            b.arrived.clear()
            third = a.learn(3, second)
            assert wait_for(lambda: len(b.places()) == 3 and b.session.mapper.graph
                            .transition(2, 3) is not None, START_S, 0.05), b.events
            assert b.places()[3] == ("robot-a", third)

            # B's own place is put under its name; A takes it as A's place 4.
            own = b.learn(4, 3)
            assert wait_for(lambda: ("robot-b", own) in a.places().values()
                            and a.session.mapper.graph.transition(third, 4) is not None,
                            START_S, 0.05), a.places()

            # Restarted on its map file: nothing taken twice, nothing lost.
            b.close()
            robots.remove(b)
            b = Robot("robot-b", tmp_path / "b.db", router.endpoint)
            robots.append(b)
            assert b.link.start() == 0
            assert len(b.places()) == 4 and not [e for e in b.events
                                                 if e[0] == "place_adopted"]
            # Under its name B put what it measured, none of the transitions it took
            # from A (each start put them again as B's before, each robot claiming every
            # other's).
            mine = {"placecell/fleet/robot-b/place/4",
                    f"placecell/fleet/robot-b/transition/robot-a/{third}/robot-b/4"}
            a.learn(5, third)  # put after whatever B put at its start
            assert wait_for(lambda: "placecell/fleet/robot-a/place/5" in _stored(watcher),
                            START_S, 0.05)
            assert {k for k in _stored(watcher)
                    if k.startswith("placecell/fleet/robot-b/")} == mine, _stored(watcher)
        finally:
            watcher.close()
            for robot in robots:
                robot.close()


def test_a_robot_cut_off_catches_up_and_a_router_restarted_empty_gets_all_back(
        tmp_path: Path) -> None:
    """The fleet's router goes away (its storage is in memory) while robot A maps on:
    when it is back, empty, A puts everything of its own again, the place learned while
    cut off included, and a robot starting then takes all of it."""
    with fleet_routers([free_port()], tmp_path, START_S) as (router,):
        a = Robot("robot-a", tmp_path / "a.db", router.endpoint)
        watcher: zenoh.Session | None = None
        robots = [a]
        try:
            first = a.learn(1, None)
            a.link.start()
            watcher = client_session(router.endpoint)
            assert wait_for(lambda: "placecell/fleet/robot-a/place/1" in _stored(watcher),
                            START_S, 0.1)
            watcher.close()
            router.stop()
            second = a.learn(2, first)  # cut off: nothing stores it now
            router.start(START_S)  # back, empty
            watcher = client_session(router.endpoint)
            keys = {"placecell/fleet/robot-a/place/1", "placecell/fleet/robot-a/place/2",
                    "placecell/fleet/robot-a/transition/robot-a/1/robot-a/2"}
            assert wait_for(lambda: _stored(watcher) == keys, START_S, 0.2), _stored(watcher)
            b = Robot("robot-b", tmp_path / "b.db", router.endpoint)
            robots.append(b)
            assert b.link.start() == 2
            assert b.places() == {1: ("robot-a", first), 2: ("robot-a", second)}
        finally:
            if watcher is not None:
                watcher.close()
            for robot in robots:
                robot.close()


def test_another_map_under_a_robots_name_overwrites_nothing_in_the_fleet(
        tmp_path: Path) -> None:
    """Robot A's map file replaced by an empty one: its next place would be a place 1 of
    robot A too, not the one the fleet holds (and others took). The link finds the
    fleet's place 1 is not this map's, says why, and puts nothing of the new map."""
    with fleet_routers([free_port()], tmp_path, START_S) as (router,):
        a = Robot("robot-a", tmp_path / "a.db", router.endpoint)
        robots = [a]
        watcher = client_session(router.endpoint)
        try:
            a.learn(1, None)
            a.link.start()
            key = "placecell/fleet/robot-a/place/1"
            assert wait_for(lambda: key in _stored(watcher), START_S, 0.1)
            original = a.session.mapper.graph.place(1).created_unix_s
            a.close()
            robots.remove(a)
            again = Robot("robot-a", tmp_path / "new.db", router.endpoint)
            robots.append(again)
            again.link.start()
            assert again.link.conflict is not None and "another map file" in \
                again.link.conflict, again.link.conflict
            again.learn(2, None)  # its place 1: not put
            # A marker put after it on the same session: once stored, anything the
            # learn had put would be too.
            again.z.put("placecell/fleet/robot-a/marker", b"{}", congestion_control=SHARED)
            assert wait_for(lambda: "placecell/fleet/robot-a/marker" in _stored(watcher),
                            START_S, 0.1)
            held = [decode_place(r.ok.payload.to_bytes()) for r in watcher.get(key, timeout=5.0)
                    if r.ok is not None]
            assert [p.place.created_unix_s for p in held] == [original]
        finally:
            watcher.close()
            for robot in robots:
                robot.close()


def test_what_is_not_a_fleet_place_of_this_camera_never_reaches_the_map(
        tmp_path: Path) -> None:
    with fleet_routers([free_port()], tmp_path, START_S) as (router,):
        b = Robot("robot-b", tmp_path / "b.db", router.endpoint)
        writer = client_session(router.endpoint)
        try:
            b.link.start()
            rng = np.random.default_rng(5)
            other_camera = FleetPlace(PlaceName("robot-x", 1), "another-geometry",
                                      synthetic_place(rng), [])
            mislabelled = FleetPlace(PlaceName("robot-a", 2), GEOMETRY,
                                     synthetic_place(rng), [])
            probe = writer.declare_publisher("placecell/fleet/robot-x/place/1")
            assert wait_for(lambda: probe.matching_status.matching, START_S, 0.05)
            for key, payload in (("place/1", encode_place(other_camera)),
                                 ("place/2", encode_place(mislabelled)),
                                 ("place/3", b"{not json"), ("photo/1", b"{}")):
                writer.put(f"placecell/fleet/robot-x/{key}", payload,
                           congestion_control=SHARED)
            assert wait_for(lambda: b.link.refused == 4, START_S, 0.05), b.link.refused
            assert b.places() == {} and b.events == []
            # The same documents as the storage holds them: refused again at a start.
            again = Robot("robot-c", tmp_path / "c.db", router.endpoint)
            try:
                assert again.link.start() == 0 and again.link.refused == 4
                assert again.places() == {}
            finally:
                again.close()
            good = FleetPlace(PlaceName("robot-x", 4), GEOMETRY, synthetic_place(rng), [])
            writer.put(place_key("placecell/fleet", good.name), encode_place(good),
                       congestion_control=SHARED)
            assert wait_for(lambda: b.places() == {1: ("robot-x", 4)}, START_S, 0.05)
        finally:
            writer.close()
            b.close()
