"""``placecellctl map plot`` (design §6): the picture holds what the map holds — one marker
per place at its embedded position (each segment its own colour, a segment not joined to
the map frame drawn in its own frame), one line per linked pair coloured by what measured
it — in the SVG's elements and in the PNG's pixels."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.mapping.embedding import embed
from daemon.store.sqlite_store import MapStore
from kernel.se2 import SE2, UncertainSE2
from tests.conftest import OfficeMap
from tests.daemon_harness import client_session, running_daemon, wait_for, write_config
from tests.map_fixtures import synthetic_place
from tests.test_map_file import GEOMETRY
from tools.ctl import main
from tools.mapplot import KIND_COLOURS, SEGMENT_COLOURS, fit_alignment

SVG = "{http://www.w3.org/2000/svg}"


def _map_with_two_segments(path: Path) -> None:
    """Four places in a cycle (odometry, vision, cycle transitions) and a fifth learned in
    unmapped space with one neighbour: two segments."""
    rng = np.random.default_rng(3)
    cov = np.diag([0.01, 0.01, 0.002])
    with MapStore.open(path, GEOMETRY) as store:
        a = store.add_place(synthetic_place(rng, "dock"))
        b = store.add_place(synthetic_place(rng, "door"),
                            [(a.id, UncertainSE2(SE2(2.0, 0.0, math.pi / 2), cov), "odometry")])
        c = store.add_place(synthetic_place(rng), [(b.id, UncertainSE2(SE2(2.0, 0.0, 0.0), cov),
                                                    "vision")])
        store.add_place(synthetic_place(rng, "lab"),
                        [(c.id, UncertainSE2(SE2(0.0, 2.0, 0.0), cov), "odometry"),
                         (a.id, UncertainSE2(SE2(0.0, 2.0, 0.0), cov), "cycle")])
        e = store.add_place(synthetic_place(rng, "far"))
        store.add_place(synthetic_place(rng), [(e.id, UncertainSE2(SE2(1.0, 0.0, 0.0), cov),
                                                "odometry")])


def _plot(tmp_path: Path, map_path: Path, out: str, capsys: pytest.CaptureFixture[str]
          ) -> dict:
    assert main(["map", "plot", str(map_path), "--out", str(tmp_path / out), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _elements(svg: Path) -> tuple[ET.Element, list[ET.Element], list[ET.Element]]:
    root = ET.parse(svg).getroot()
    places = [e for e in root.iter(f"{SVG}circle") if e.get("class") == "place"]
    lines = [e for e in root.iter(f"{SVG}line") if (e.get("class") or "").startswith("trans")]
    return root, places, lines


def _to_px(root: ET.Element, x: float, y: float) -> tuple[float, float]:
    scale, margin = float(root.get("data-scale-px-per-m")), float(root.get("data-margin-px"))
    height = float(root.get("height"))
    return (margin + (x - float(root.get("data-x0"))) * scale,
            height - margin - (y - float(root.get("data-y0"))) * scale)


def test_every_place_and_transition_is_drawn_where_the_map_has_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _map_with_two_segments(tmp_path / "map.db")
    assert _plot(tmp_path, tmp_path / "map.db", "map.svg", capsys)["places"] == 6
    with MapStore.open(tmp_path / "map.db", None, readonly=True) as store:
        graph = store.load()
    frame = embed(graph)  # the map frame's segment: places 1-4
    assert sorted(frame) == [1, 2, 3, 4]
    root, places, lines = _elements(tmp_path / "map.svg")
    assert sorted(int(e.get("data-id")) for e in places) == [1, 2, 3, 4, 5, 6]
    centre = {}
    for e in places:
        pid = int(e.get("data-id"))
        x, y = float(e.get("data-x")), float(e.get("data-y"))
        cx, cy = _to_px(root, x, y)
        assert (float(e.get("cx")), float(e.get("cy"))) == pytest.approx((cx, cy), abs=0.1)
        centre[pid] = (cx, cy)
        if pid in frame:
            assert (x, y) == pytest.approx((frame[pid].x, frame[pid].y), abs=1e-3)
    # The other segment: in its own frame, beside the map frame's, one metre apart.
    assert {e.get("data-segment") for e in places} == {"1", "5"}
    assert math.dist(centre[5], centre[6]) == pytest.approx(60.0, abs=0.5)
    assert min(float(e.get("data-x")) for e in places if e.get("data-segment") == "5") > \
        max(frame[p].x for p in frame)
    # One line per linked pair, its ends on the places, its kind what measured it.
    pairs = {(int(e.get("data-from")), int(e.get("data-to"))): e.get("class").split()[1]
             for e in lines}
    assert pairs == {(1, 2): "odometry", (2, 3): "vision", (3, 4): "odometry",
                     (1, 4): "cycle", (5, 6): "odometry"}
    for e in lines:
        a, b = centre[int(e.get("data-from"))], centre[int(e.get("data-to"))]
        ends = ((float(e.get("x1")), float(e.get("y1"))), (float(e.get("x2")), float(e.get("y2"))))
        assert ends == (pytest.approx(a, abs=0.1), pytest.approx(b, abs=0.1))
        kind = e.get("class").split()[1]
        assert e.get("stroke") == "#" + "".join(f"{c:02x}" for c in KIND_COLOURS[kind])
    # Axes in metres and a legend a person reads.
    texts = [t.text or "" for t in root.iter(f"{SVG}text")]
    assert "x (m), map frame" in texts and "y (m)" in texts
    assert {"transition: odometry", "transition: vision", "transition: cycle"} <= set(texts)

    # The PNG is the same picture: each place's marker in its segment's colour.
    _plot(tmp_path, tmp_path / "map.db", "map.png", capsys)
    img = cv2.imread(str(tmp_path / "map.png"))
    assert img.shape[:2] == (int(root.get("height")), int(root.get("width")))
    for e in places:
        cx, cy = (int(round(float(e.get(k)))) for k in ("cx", "cy"))
        colour = SEGMENT_COLOURS[0 if e.get("data-segment") == "1" else 1]
        assert tuple(int(v) for v in img[cy, cx][::-1]) == colour, e.attrib


def test_a_map_the_daemon_learned_is_drawn(tmp_path: Path, office_map: OfficeMap,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Three places learned by Turn Back and Look 1.5 m apart along a corridor."""
    office_map(tmp_path / "map.db")
    _plot(tmp_path, tmp_path / "map.db", "map.svg", capsys)
    root, places, lines = _elements(tmp_path / "map.svg")
    assert len(places) == 3 and len(lines) == 2
    xy = {int(e.get("data-id")): (float(e.get("data-x")), float(e.get("data-y")))
          for e in places}
    ids = sorted(xy)
    for a, b in zip(ids, ids[1:], strict=False):
        assert math.dist(xy[a], xy[b]) == pytest.approx(1.5, abs=0.15)
    labels = {t.text for t in root.iter(f"{SVG}text") if t.get("class") == "label"}
    assert labels == {f"{ids[0]} a", f"{ids[1]} b", f"{ids[2]} c"}


def test_a_picture_needs_a_known_format(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    _map_with_two_segments(tmp_path / "map.db")
    assert main(["map", "plot", str(tmp_path / "map.db"), "--out",
                 str(tmp_path / "map.gif")]) == 2
    assert "the picture is .svg or .png" in capsys.readouterr().err


def test_the_alignment_fit_recovers_a_known_transform_and_refuses_a_still_robot() -> None:
    rng = np.random.default_rng(5)
    T = SE2(3.0, -1.0, 0.7)  # T_map_world
    world = [(float(x), float(y)) for x, y in rng.uniform(0, 5, (40, 2))]
    pairs = []
    for x, y in world:
        m = T.compose(SE2(x, y, 0.0))
        pairs.append(((m.x + rng.normal(0, 0.01), m.y + rng.normal(0, 0.01)), (x, y)))
    fitted, rms = fit_alignment(pairs)
    assert (fitted.x, fitted.y, fitted.yaw) == pytest.approx((3.0, -1.0, 0.7), abs=0.01)
    assert 0.005 < rms < 0.03
    with pytest.raises(ValueError, match="at least two"):
        fit_alignment(pairs[:1])
    with pytest.raises(ValueError, match="moved less"):
        fit_alignment([((1.0, 1.0), (2.0, 2.0))] * 5)


@pytest.mark.xdist_group("realtime")
@pytest.mark.timeout(300)
def test_live_over_the_simulated_worlds_plan(tmp_path: Path, office_map: OfficeMap,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """The robot tracked from b along the corridor towards c: the office's walls drawn
    under the map, placed by the daemon's path against the simulator's true one."""
    refs = office_map(tmp_path / "map.db")
    b = refs["b"]
    with MapStore.open(tmp_path / "map.db", None, readonly=True) as store:
        b_id = next(p.id for p in store.load().places if p.label == "b")
    scenario = tmp_path / "corridor.toml"
    scenario.write_text("\n".join([
        'name = "corridor"', 'world = "generate:office:1"',
        f"start_pose = [{b.x}, {b.y}, {b.yaw}]", "[trajectory]", 'kind = "waypoints"',
        "speed = 0.3", "start_after_s = 1.0", f"waypoints = [[{b.x + 3.0}, {b.y}]]"]) + "\n")
    truth = tmp_path / "truth.jsonl"
    config, port = write_config(tmp_path, {
        "sim": {"scenario": str(scenario), "truth_out": str(truth)},
        "localisation": {"initial_place": b_id}})
    with running_daemon(config):
        session = client_session(port)
        in_map: list[bool] = []
        session.declare_subscriber("placecell/*/pose", lambda s: in_map.append(
            json.loads(s.payload.to_bytes())["map"] is not None))
        try:
            assert wait_for(lambda: any(in_map), 120), "no pose in the map frame"
        finally:
            session.close()
        assert main(["--config", str(config), "map", "plot", str(tmp_path / "map.db"),
                     "--out", str(tmp_path / "plan.svg"), "--live", "--duration", "4",
                     "--world", "generate:office:1", "--truth", str(truth), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["poses"] >= 10 and out["plan_rms_m"] < 0.15, out
    root = ET.parse(tmp_path / "plan.svg").getroot()
    walls = [e for e in root.iter(f"{SVG}line") if e.get("class") == "wall"]
    from hal.sim.world import load_world
    assert len(walls) == sum(len(w.segments()) for w in load_world("generate:office:1").walls)
    assert main(["map", "plot", str(tmp_path / "map.db"), "--out", str(tmp_path / "x.svg"),
                 "--world", "generate:office:1"]) == 2  # the plan needs the path
