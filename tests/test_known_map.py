"""The map as the localiser reads it (daemon/localisation/known_map.py): one immutable
snapshot, replaced whole; the one rule for a place's background."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from daemon.config import load
from daemon.localisation.known_map import KnownMap, MapHolder
from daemon.localisation.localiser import Localiser, PoseRequest
from daemon.mapping.transition import Transition
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Frame
from tests.map_fixtures import synthetic_place


def _places(n: int) -> list:
    rng = np.random.default_rng(7)
    return [dataclasses.replace(synthetic_place(rng, f"p{k}", n=4, width=64, height=24,
                                                margin=0), id=k) for k in range(1, n + 1)]


def _link(a: int, b: int, x: float) -> Transition:
    return Transition(a, b, UncertainSE2(SE2(x, 0.0, 0.0), np.diag([0.01, 0.01, 0.001])))


def test_a_change_makes_a_new_snapshot_and_leaves_the_old_one_as_it_was() -> None:
    one = KnownMap.of(_places(2), [_link(1, 2, 1.5)])
    assert one.neighbours(2)[1].mean.x == pytest.approx(-1.5)  # held both ways
    assert one.places[1].place.reference_panorama is None  # never the panorama
    two = one.with_background(1, 0.61)
    assert one.place(1).background_lrp is None and two.place(1).background_lrp == 0.61
    assert two.places[1].templates is one.places[1].templates  # not prepared again
    three = two.with_transitions([_link(2, 1, 0.5)])
    assert three.neighbours(1)[2].mean.x == pytest.approx(-0.5)  # the later measurement
    assert two.neighbours(1)[2].mean.x == pytest.approx(1.5)
    with pytest.raises(TypeError):
        three.places[9] = three.places[1]  # type: ignore[index]
    with pytest.raises(TypeError):
        three.links[1][3] = three.links[1][2]  # type: ignore[index]


def test_one_background_rule_measured_then_estimates_then_the_default() -> None:
    a, b, c = _places(3)
    a = dataclasses.replace(a, background_estimate=0.70, background_cross=0.80)
    b = dataclasses.replace(b, background_estimate=0.60, background_cross=0.90)
    c = dataclasses.replace(c, background_estimate=0.50, background_lrp=0.55)
    known = KnownMap.of([a, b, c])
    # The levels over a and b (c has no cross estimate): own 0.65, cross 0.85.
    assert known.background(3, 0.4, estimated=True) == 0.55  # measured wins
    assert known.background(3, 0.4, estimated=False) == 0.55
    assert known.background(1, 0.4, estimated=True) == pytest.approx(0.80 - 0.85 + 0.65)
    assert known.background(2, 0.4, estimated=True) == pytest.approx(0.90 - 0.85 + 0.65)
    assert known.background(1, 0.4, estimated=False) == 0.4  # tracking: the default
    alone = KnownMap.of([dataclasses.replace(_places(1)[0], background_estimate=0.7)])
    assert alone.background(1, 0.4, estimated=True) == 0.7  # no levels: its own view
    assert KnownMap.of(_places(1)).background(1, 0.4, estimated=True) == 0.4
    assert KnownMap.of(_places(1)).estimated_background(1) is None


def test_through_graph_composes_along_the_path_and_stops_at_its_limit() -> None:
    known = KnownMap.of(_places(4), [_link(1, 2, 1.0), _link(2, 3, 2.0), _link(3, 4, 0.5)])
    through = known.through_graph(1)
    assert sorted(through) == [2, 3, 4]
    assert through[4].mean.x == pytest.approx(3.5)
    assert through[4].covariance[0, 0] == pytest.approx(0.03)  # composed along it
    assert sorted(known.through_graph(1, max_places=3)) == [2, 3]


def test_changes_from_many_threads_are_all_kept_and_readers_see_whole_snapshots() -> None:
    holder = MapHolder(KnownMap.of(_places(9)))
    read = holder.current

    def link_from(a: int) -> None:
        for b in range(1, 10):
            if b != a:
                holder.replace(lambda m, b=b: m.with_transitions([_link(a, b, float(b))]))

    threads = [threading.Thread(target=link_from, args=(a,)) for a in (1, 4, 7)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not read.links  # a snapshot taken before stays as it was
    known = holder.current
    for a in (1, 4, 7):
        assert sorted(known.neighbours(a)) == [b for b in range(1, 10) if b != a]


def test_a_pose_asked_in_a_place_the_frames_map_lacks_waits_for_the_next_frame() -> None:
    """A learn job stores a place and asks for tracking at its reference from its own
    thread; a frame that took its map just before sees the request but not the place:
    the request waits for the next frame instead of failing the frame."""
    cfg = load(None)
    rng = np.random.default_rng(11)
    a, b = (dataclasses.replace(synthetic_place(rng), id=k) for k in (1, 2))
    holder = MapHolder(KnownMap.of([a]))
    localiser = Localiser(cfg.projection, cfg.panorama, settings=cfg.localisation,
                          known_map=holder)
    image = rng.integers(0, 256, (cfg.camera.sim.image_height, cfg.camera.sim.image_width, 3),
                         dtype=np.uint8)
    localiser._pose_request = PoseRequest(b.id, (0.0, 0.0, 0.0), 0.03, 0.03)
    localiser.process_frame(Frame(image, 1_000_000_000, 1))
    assert localiser.tracker is None and localiser._pose_request is not None
    holder.replace(lambda m: m.with_places([b]))
    localiser.process_frame(Frame(image, 1_100_000_000, 2))
    assert localiser.tracker is not None and localiser.tracker.place.id == b.id
    assert localiser._pose_request is None
