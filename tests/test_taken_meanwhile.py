"""A place the fleet gave where this robot was learning one (docs/fleet.md): the
autopilot's learn stores nothing when, at the end of its drive, a place taken from the
fleet meanwhile stands out in its reference view by the take-over rule
(MappingSession.taken_meanwhile, scored by Localiser.recognise_view).

The office corridor's places "a", "b", "c" (1.5 m apart) are known; the robot stands
0.2 m from b's reference; another robot's copy of place b arrives while a learn begins.
Real rendered views; the truth stays on the test's side."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import OfficeMap, run_at


@pytest.mark.timeout(300)
def test_another_robots_place_here_is_found_and_one_far_off_is_not(
        tmp_path: Path, office_map: OfficeMap) -> None:
    with run_at(tmp_path, office_map, "b") as (run, _):
        ids = {p.label: p.id for p in run.mapper.graph.places}
        for _ in run.drive(0.2, 0.0, 0.0, 0.2):
            pass
        frame, _ = run.step()
        view = run.localiser.unwarper.unwarp(frame.image)
        scores = run.localiser.recognise_view(view, [ids["a"], ids["b"], ids["c"], 999])
        leads = {sc.place_id: sc.lead for sc in scores}
        assert sorted(leads) == sorted(ids.values())  # a place not in the map is left out
        assert max(leads, key=lambda p: leads[p]) == ids["b"], leads
        print("leads 0.2 m from b", {p: round(v, 3) for p, v in leads.items()})

        # Another robot learned place b too; its copy arrives while this learn drives.
        theirs = run.store.place(ids["b"], panorama=True)
        odometry = run.localiser.odometry.latest
        assert odometry is not None
        run.session.begin_place(odometry, None)
        [(_, fields)] = run.session.adopt_place(theirs, [], "robot-b", 2)
        taken = fields["place"]
        assert run.session.taken_meanwhile(
            lambda places: run.localiser.recognise_view(view, places)) == (taken, "robot-b")
        # The same place seen from 3 m away, past "c": not here.
        for _ in run.drive(3.0, 0.0, 0.0, 0.4):
            pass
        frame, _ = run.step()
        far = run.localiser.unwarper.unwarp(frame.image)
        print("lead of their b 3 m on", [round(sc.lead, 3) for sc in
                                         run.localiser.recognise_view(far, [taken])])
        assert run.session.taken_meanwhile(
            lambda places: run.localiser.recognise_view(far, places)) is None
        run.session.cancel_place()
