"""A learn's matching done while its cross is driven (daemon/service/learn_ahead.py,
design §13): the same map as measuring it all after the drive, and nothing measured
again after it."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path
from typing import Any

import pytest

from daemon.mapping import lookalikes
from daemon.service.learn_ahead import LearnAhead, Measured
from daemon.service.mapping_session import MappingSession
from daemon.vision.recognition import FastMatcher
from tools.eval.lockstep import Run, lockstep_config

WORLD = "generate:aliased-corridor:1"


def _cues(path: Path) -> dict[str, list[tuple[Any, ...]]]:
    """What a learn's matching stores: every place's cross background, every feature."""
    db = sqlite3.connect(path)
    try:
        return {"backgrounds": list(db.execute(
                    "SELECT id, background_cross FROM places ORDER BY id")),
                "features": list(db.execute("SELECT * FROM features ORDER BY rowid"))}
    finally:
        db.close()


def _stretches(path: Path) -> list[int]:
    """Two stretches of the aliased corridor 3 m apart: look-alikes of each other."""
    cfg = lockstep_config(1, world=WORLD, start_pose=(4.0, 1.2, 0.0))
    ids = []
    with Run(cfg, map_path=path) as run:
        for i in range(2):
            if i:
                for _ in run.drive(3.0, 0.0, 0.0, 0.4):
                    pass
            ids.append(run.learn(f"stretch {i + 1}").id)
    return ids


def test_matching_during_the_drive_stores_what_matching_after_it_does_and_no_more(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The LRPs a learn needs after its drive (its cross background, its look-alike
    candidates' views and theirs in its own views) and its look-alikes' features were all
    found during it, and the map is the one finding them after the drive gives."""
    measured_after: list[int] = []
    searched_after: list[int] = []
    finished: list[Measured | None] = []
    storing = threading.Event()
    lrps, finish, store = FastMatcher.lrps, LearnAhead.finish, MappingSession.store_place
    search = lookalikes.find_feature

    def counted(self: FastMatcher, pano: Any, places: list[Any]) -> list[float]:
        if storing.is_set() and threading.current_thread().name != "placecell-ahead":
            measured_after.append(len(places))
        return lrps(self, pano, places)

    def searched(*args: Any) -> Any:
        if storing.is_set():
            searched_after.append(1)
        return search(*args)

    def kept(self: LearnAhead) -> Measured | None:
        finished.append(finish(self))
        return finished[-1]

    def stored(self: MappingSession, *args: Any, **kwargs: Any) -> Any:
        storing.set()  # the drive is over: the learn thread stores the place
        try:
            return store(self, *args, **kwargs)
        finally:
            storing.clear()

    ahead_map, after_map = tmp_path / "ahead.db", tmp_path / "after.db"
    with monkeypatch.context() as spy:
        spy.setattr(FastMatcher, "lrps", counted)
        spy.setattr(LearnAhead, "finish", kept)
        spy.setattr(MappingSession, "store_place", stored)
        spy.setattr(lookalikes, "find_feature", searched)
        ids = _stretches(ahead_map)
    assert len(finished) == 2 and all(m is not None for m in finished), finished
    last = finished[-1]
    assert last is not None
    assert sorted(last.in_own_views) == [0, 1, 2, 3, 4]  # the reference and four views
    assert set(last.in_place_views) == {ids[0]}  # the older place's view
    assert all(len(best) == len(last.candidates.landmarks)
               for best in last.in_place_views.values())
    assert {(ids[0], k) for k in range(5)} <= set(last.places_in_own_views)
    assert measured_after == []
    assert last.foreseen is not None and set(last.foreseen.theirs) == {ids[0]}
    assert searched_after == []
    with monkeypatch.context() as patch:  # never begun: the mapper measures it all after
        patch.setattr(LearnAhead, "begin", lambda *_: None)
        _stretches(after_map)
    ahead, after = _cues(ahead_map), _cues(after_map)
    assert len(ahead["features"]) == 2, ahead  # the look-alikes were told apart
    assert all(b is not None for _, b in ahead["backgrounds"]), ahead
    assert ahead == after
