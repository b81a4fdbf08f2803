"""The map's one owner (daemon/service/mapping_session.py): what a belief, a learned place
and a closed cycle do to the map file and to the map the localiser reads, in each mode;
and when the autopilot learns. A real SQLite map file; crafted places and beliefs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from daemon.localisation.belief import Belief, LocalisationEvent, MapUpdates, PlaceScore
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.acquisition import AcquisitionDecision
from daemon.mapping.settings import AcquisitionSettings, OdometryNoiseSettings
from daemon.mapping.transition import Transition
from daemon.service.mapper import Link, Mapper
from daemon.service.mapping_session import MappingSession
from daemon.store.sqlite_store import MapStore
from kernel.errors import PlacecellError
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Odometry
from tests.map_fixtures import synthetic_place

GEOMETRY = "abc123"
T = UncertainSE2(SE2(1.5, 0.0, 0.0), np.diag([0.01, 0.01, 0.001]))


def _session(path: Path, mode: str = "mapping", **acquisition: object) -> MappingSession:
    mapper = Mapper(MapStore.open(path, GEOMETRY), OdometryNoiseSettings())
    return MappingSession(mapper, AcquisitionSettings(enabled=True, **acquisition),
                          LocalisationSettings(max_lookalikes=0), mode)  # type: ignore[arg-type]


def _belief(state: str = "tracking", **fields: object) -> Belief:
    return Belief(stamp_ns=1, state=state, reason="", odometry_ok=True,  # type: ignore[arg-type]
                  **fields)  # type: ignore[arg-type]


def _two_segments(session: MappingSession) -> tuple[int, int]:
    rng = np.random.default_rng(3)
    a = session.store_place(synthetic_place(rng, "a", n=4, width=64, height=24, margin=0),
                            [], [])
    b = session.store_place(synthetic_place(rng, "b", n=4, width=64, height=24, margin=0),
                            [], [])
    assert [e[0] for e in a.events] == []  # the first place of a map starts nothing new
    assert [e[0] for e in b.events] == ["segment_started"]
    return a.place.id, b.place.id


def test_a_place_is_in_the_file_and_in_the_localisers_map_with_its_transitions(
        tmp_path: Path) -> None:
    session = _session(tmp_path / "map.db")
    a, _ = _two_segments(session)
    rng = np.random.default_rng(4)
    c = session.store_place(synthetic_place(rng, "c", n=4, width=64, height=24, margin=0),
                            [Link(a, T)], [])
    assert [(e[0], e[1]["from"], e[1]["to"]) for e in c.events] == [
        ("transition_added", c.place.id, a)]
    known = session.known
    assert c.place.id in known and known.neighbours(a)[c.place.id].mean.x == 1.5
    with MapStore.open(tmp_path / "map.db", GEOMETRY, readonly=True) as store:
        graph = store.load()
    assert graph.transition(c.place.id, a) is not None and len(graph) == 3


def test_the_mapper_matches_with_the_templates_the_localisers_map_prepared(
        tmp_path: Path) -> None:
    """A learn matches older places' landmarks many times (backgrounds, look-alikes):
    with the templates the localiser's map holds, not prepared again for every learn."""
    session = _session(tmp_path / "map.db")
    a, b = _two_segments(session)
    for place_id in (a, b):
        assert session.mapper.templates(place_id) is session.known.places[place_id].templates
    alone = Mapper(session.mapper.store, OdometryNoiseSettings())  # no session: its own
    assert alone.templates(a) is not session.known.places[a].templates
    assert np.array_equal(alone.templates(a).coarse, session.known.places[a].templates.coarse)


def test_a_closed_cycle_joins_segments_in_the_file_and_the_map_read(tmp_path: Path) -> None:
    session = _session(tmp_path / "map.db")
    a, b = _two_segments(session)
    events = session.observe(_belief(), MapUpdates(Transition(a, b, T, "cycle"),
                                                   backgrounds=((a, 0.42),)))
    kinds = [e[0] for e in events]
    assert kinds == ["background_measured", "segments_joined", "transition_added"]
    assert session.known.neighbours(b)[a].mean.x == pytest.approx(-1.5)
    assert session.known.place(a).background_lrp == 0.42
    assert set(session.mapper.segment_of.values()) == {a}
    with MapStore.open(tmp_path / "map.db", GEOMETRY, readonly=True) as store:
        graph = store.load()
    assert graph.transition(a, b) is not None and graph.place(a).background_lrp == 0.42


def test_localisation_mode_changes_nothing_and_learns_nothing(tmp_path: Path) -> None:
    session = _session(tmp_path / "map.db")
    a, b = _two_segments(session)
    before = session.known
    session.mode = "localisation"
    decision = AcquisitionDecision(a, 0.5, 1.0, 0.5)
    belief = _belief(acquisition=decision)
    updates = MapUpdates(Transition(a, b, T, "cycle"), backgrounds=((a, 0.4),))
    assert session.observe(belief, updates) == []
    assert session.known is before
    assert session.wants_place(belief, None, job_running=False) is None
    with pytest.raises(PlacecellError, match="read-only"):
        session.store_place(synthetic_place(np.random.default_rng(5)), [], [])
    with MapStore.open(tmp_path / "map.db", GEOMETRY, readonly=True) as store:
        graph = store.load()
    assert graph.transition(a, b) is None and graph.place(a).background_lrp is None


def test_the_autopilot_learns_the_first_place_a_faded_one_and_in_unmapped_space(
        tmp_path: Path) -> None:
    session = _session(tmp_path / "map.db", unmapped_after_frames=5, unmapped_after_m=0.3)
    assert session.wants_place(_belief("uninitialised"), None, False) == "the first one"
    assert session.wants_place(_belief("uninitialised"), None, True) is None  # a job runs
    a, _ = _two_segments(session)
    decision = AcquisitionDecision(a, 0.5, 1.0, 0.5)
    assert session.wants_place(_belief(acquisition=decision), None, False) \
        == f"place {a}'s background reached"
    assert session.wants_place(_belief("lost", acquisition=decision), None, False) is None
    assert session.wants_place(_belief("relocalising"), None, False) is None  # a restart
    assert session.wants_place(_belief(), None, False) is None  # tracking: counts restart
    whys = [session.wants_place(_belief("relocalising"),
                                Odometry(0.05 * k, 0.0, 0.0, k, k), False) for k in range(9)]
    assert whys[:6] == [None] * 6  # searched 5 frames at k = 4, but 0.3 m only at k = 6
    assert whys[6] is not None and whys[6].startswith("unmapped space")


def test_a_loss_holds_the_odometry_run_from_the_last_place(tmp_path: Path) -> None:
    """A place learned after a loss where the view contradicted the estimate is not linked
    to the last place by odometry at once: the robot may have been carried off in
    between, which odometry cannot see (office 2: a link across a kidnap put a place
    9.8 m off); the run is held until a path through the map checks it
    (tests/test_mapper_links.py). Before the loss the run links; a relocalised event or a
    loss by blind travel does not hold it; in localisation mode a loss holds it too (an
    operator's learn)."""
    for mode in ("mapping", "localisation"):
        session = _session(tmp_path / f"{mode}.db", mode)
        mapper = session.mapper

        def odo(x: float, stamp: int) -> Odometry:
            return Odometry(x, 0.0, 0.0, stamp, stamp)

        assert mapper.begin_place(odo(0.0, 1)) == []  # the first place: nothing to join
        a, _ = mapper.add_place(synthetic_place(np.random.default_rng(5), "a", n=4, width=64,
                                                height=24, margin=0), [])
        mapper.on_odometry([odo(0.5, 2), odo(1.0, 3)])
        session.observe(_belief("tracking", event=LocalisationEvent("relocalised", a.id,
                                                                    "local")), MapUpdates())
        links = mapper.begin_place(odo(1.0, 3))
        assert [(link.from_id, link.source) for link in links] == [(a.id, "odometry")]
        assert links[0].T_from_new.mean.x == pytest.approx(1.0)
        mapper.cancel_place()
        # Blind travel (no evidence either way) leaves the run: between places out of
        # view, odometry is the link (§7.1.2).
        session.observe(_belief("lost", event=LocalisationEvent("lost", a.id, "blind")),
                        MapUpdates())
        assert [link.from_id for link in mapper.begin_place(odo(1.0, 3))] == [a.id]
        mapper.cancel_place()
        session.observe(_belief("lost", event=LocalisationEvent(
            "lost", a.id, "sensor", contradicted=True)), MapUpdates())
        assert mapper.begin_place(odo(1.0, 3)) == [], mode


def test_a_learn_is_told_of_a_place_the_fleet_gave_where_it_was_learning(
        tmp_path: Path) -> None:
    """MappingSession.taken_meanwhile (docs/fleet.md): of the places taken from the fleet,
    only those taken since the learn began count, each by the autopilot's take-over rule
    on its lead in the new place's view (the higher of the recognition and coverage
    margins, 0.05 and 0.08 by default)."""
    session = _session(tmp_path / "map.db")
    rng = np.random.default_rng(5)

    def place(label: str):  # type: ignore[no-untyped-def]
        return synthetic_place(rng, label, n=4, width=64, height=24, margin=0)

    session.adopt_place(place("before"), [], "robot-a", 1)
    session.begin_place(Odometry(0.0, 0.0, 0.0, 1, 1), None)
    asked: list[list[int]] = []

    def leads(by_place: dict[int, float]):  # type: ignore[no-untyped-def]
        def score(ids: list[int]) -> list[PlaceScore]:
            asked.append(ids)
            return [PlaceScore(p, 0.9, by_place.get(p, 0.0)) for p in ids]
        return score

    assert session.taken_meanwhile(leads({})) is None and asked == []  # none taken since
    [(_, fields)] = session.adopt_place(place("meanwhile"), [], "robot-b", 4)
    here = fields["place"]
    assert session.taken_meanwhile(leads({here: 0.08})) == (here, "robot-b")
    assert asked == [[here]]  # the place taken before the learn began is not looked at
    assert session.taken_meanwhile(leads({here: 0.079})) is None
    session.cancel_place()
    session.begin_place(Odometry(0.0, 0.0, 0.0, 2, 2), None)  # the next learn: taken before
    assert session.taken_meanwhile(leads({here: 0.5})) is None
