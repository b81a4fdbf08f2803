"""Mapping through a loss (issue 31, point 1; design §6 "Segments"): the map's connected
parts, the unmapped-space rule, and the daemon end to end: kidnapped into unmapped space
in mapping mode it learns a place there, a segment of its own, and driven back the two
are joined."""

from __future__ import annotations

import dataclasses
import json
import math
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.mapping.graph import TopologicalMap
from daemon.mapping.settings import AcquisitionSettings
from daemon.mapping.transition import Transition
from daemon.mapping.unmapped import UnmappedWatch, unmapped
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Odometry
from tests.api_schema import check
from tests.conftest import OfficeMap
from tests.daemon_harness import client_session, running_daemon, wait_for, write_config
from tests.map_fixtures import synthetic_place
from tools.eval.lockstep import Run, lockstep_config


def _link(a: int, b: int) -> Transition:
    return Transition(a, b, UncertainSE2(SE2(1.0, 0.0, 0.0), np.eye(3) * 0.01), "odometry")


def test_segments_are_the_connected_parts_named_by_their_lowest_id() -> None:
    rng = np.random.default_rng(1)
    graph = TopologicalMap()
    for i in range(1, 7):
        graph.add_place(dataclasses.replace(synthetic_place(rng, str(i)), id=i))
    for a, b in ((1, 2), (2, 3), (4, 5)):
        graph.add_transition(_link(a, b))
    assert graph.segments() == {1: 1, 2: 1, 3: 1, 4: 4, 5: 4, 6: 6}
    graph.add_transition(_link(5, 3))  # a cycle closed across: 4-5 joins 1-2-3
    assert graph.segments() == {1: 1, 2: 1, 3: 1, 4: 1, 5: 1, 6: 6}


def test_unmapped_space_needs_both_the_frames_and_the_travel() -> None:
    s = AcquisitionSettings(unmapped_after_frames=30, unmapped_after_m=0.3)
    assert not unmapped(29, 5.0, s) and not unmapped(300, 0.29, s) and unmapped(30, 0.3, s)


def test_the_watch_counts_a_search_and_forgets_it_when_tracking() -> None:
    watch = UnmappedWatch(AcquisitionSettings(unmapped_after_frames=3, unmapped_after_m=0.2))
    odo = [Odometry(0.1 * i, 0.0, 0.0, i, i) for i in range(6)]
    assert [watch.observe(False, o) for o in odo[:4]] == [False, False, True, True]
    assert watch.frames == 4 and watch.travelled_m == pytest.approx(0.3)
    assert not watch.observe(True, odo[4])  # found: a new search starts from nothing
    assert (watch.frames, watch.travelled_m) == (0, 0.0)
    assert not watch.observe(False, None)


@pytest.mark.xdist_group("realtime")
@pytest.mark.timeout(420)
def test_kidnapped_into_unmapped_space_a_segment_of_its_own_is_learned(
        tmp_path: Path, office_map: OfficeMap) -> None:
    """The corridor's places a, b, c (x = 3, 4.5, 6 m) are the map; the robot stands at
    b, is carried 6.5 m on to x = 11 (unmapped): a place learned there starts a segment
    of its own, and the poses in it say they are not in the map frame; driven back
    towards c, the segments are joined and the pose is in the map frame again."""
    refs = office_map(tmp_path / "map.db")
    b = refs["b"]
    scenario = tmp_path / "kidnap.toml"
    scenario.write_text("\n".join([
        'name = "kidnap-unmapped"', 'world = "generate:office:1"',
        f"start_pose = [{b.x}, {b.y}, {b.yaw}]",
        "[trajectory]", 'kind = "waypoints"', "speed = 0.3", "start_after_s = 12.0",
        "resume_after_s = 1.5", "waypoints = [[5.6, 10.0]]",
        "[[kidnap]]", "t_s = 10.0", "pose = [11.0, 10.0, 0.0]"]) + "\n")
    # The autopilot drives back towards c after the kidnap (the unmapped-space rule wants
    # travel); places at least 2 m apart on the way.
    config, port = write_config(tmp_path, {
        "sim": {"scenario": str(scenario)},
        "mapping": {"mode": "mapping", "acquisition": {"enabled": True,
                                                        "min_distance_m": 2.0}}})
    events: list[dict[str, Any]] = []
    poses: list[dict[str, Any]] = []
    lock = threading.Lock()
    with running_daemon(config) as proc:
        session = client_session(port)
        try:
            def on_event(sample: Any) -> None:
                with lock:
                    events.append(check(json.loads(sample.payload.to_bytes())))

            def on_pose(sample: Any) -> None:
                with lock:
                    poses.append(check(json.loads(sample.payload.to_bytes())))

            session.declare_subscriber("placecell/*/events", on_event)
            session.declare_subscriber("placecell/*/pose", on_pose)

            def seen(kind: str) -> dict[str, Any] | None:
                with lock:
                    return next((e for e in events if e["event"] == kind), None)

            assert wait_for(lambda: seen("segment_started") is not None, 240), \
                [e["event"] for e in events]
            started = seen("segment_started")
            assert started is not None and started["segments"] == 2
            new_place = started["place"]

            # While the new segment stands apart, its poses say so.
            def apart() -> list[dict[str, Any]]:
                with lock:
                    return [p for p in poses if p["place"]
                            and p["place"]["segment"] == new_place]

            assert wait_for(lambda: len(apart()) >= 5, 60), poses[-1:]
            assert all(p["map"] is None and "not joined" in p["reason"] for p in apart())
            with lock:
                learned = [e for e in events if e["event"] == "place_learned"]
            assert learned and learned[0]["place"] == new_place
            # Driven back towards c: the segments are joined (a cycle closed, or the
            # bridge from the last fix in the new segment through a loss that only
            # faded), and the pose is in the map frame again.
            assert wait_for(lambda: seen("segments_joined") is not None, 240), \
                [e["event"] for e in events]
            joined = seen("segments_joined")
            assert joined is not None and new_place in joined["joined"]
            assert wait_for(lambda: poses[-1]["map"] is not None, 60), poses[-1:]
        finally:
            session.close()
        assert proc.poll() is None


def test_driven_back_out_of_view_the_segments_are_joined_by_a_measured_transition(
        tmp_path: Path, office_map: OfficeMap) -> None:
    """A place d learned at x = 11 m in unmapped space (a segment of its own: no link to
    the corridor's a, b, c at x = 3-6 m); the robot drives back towards c out of every
    place's view, is lost there, and relocalised in c: the transition d -> c
    is measured from the last reliable estimate in d, the odometry since and the estimate
    in c once relocalisation has confirmed it (lock-step, the daemon's localiser), close
    to the truth; a candidate on the way that is not confirmed measures nothing."""
    refs = office_map(tmp_path / "map.db")
    with Run(lockstep_config(1, start_pose=(11.0, 10.0, 0.0)),
             map_path=tmp_path / "map.db") as run:
        run.localiser = run.restart_localiser()
        for _ in range(5):
            run.step()
        run.mapper.odometry_restarted()  # unmapped space: no link to the last place
        d = run.learn("d")
        assert not run.mapper.graph.neighbours(d.id)  # its own segment
        closed: list[Transition] = []
        lost: list[str] = []
        for _ in run.drive(0.0, 0.0, math.pi, 0.3):  # about, and along the corridor
            pass
        for belief in run.drive(5.0, 0.0, 0.0, 0.3):
            if belief.event is not None and belief.event.kind == "lost":
                lost.append(belief.event.how)
            if run.updates.closed_transition is not None:
                closed.append(run.updates.closed_transition)
        for _ in range(60):  # at rest near c until the estimate in c is reliable
            if closed:
                break
            run.step()
            if run.updates.closed_transition is not None:
                closed.append(run.updates.closed_transition)
        assert lost, "never lost on the way"
        c = next(p.id for p in run.mapper.graph.places if p.label == "c")
        assert [(t.from_id, t.to_id) for t in closed] == [(d.id, c)], closed
        truth = run.references[d.id].between(refs["c"])  # T_d_c, the reference poses
        T = closed[0].T_from_to
        error = np.array([T.mean.x - truth.x, T.mean.y - truth.y,
                          math.remainder(T.mean.yaw - truth.yaw, 2 * math.pi)])
        # Five metres of odometry (the simulated base drifts 0.016 rad/m in heading):
        # within 0.3 m and 0.12 rad, and within what its covariance says (3 sigma).
        assert math.hypot(*error[:2]) < 0.3 and abs(error[2]) < 0.12, (T.mean, truth)
        assert all(abs(e) <= 3 * math.sqrt(v) for e, v in
                   zip(error, np.diag(T.covariance), strict=True)), (error, T.covariance)
