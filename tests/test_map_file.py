"""The map file (daemon/store): places with their transitions, durable, refusing bad files
untouched, readable while written, exported and imported back."""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import sqlite3
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from daemon.mapping.settings import OdometryNoiseSettings
from daemon.service.mapper import Mapper
from daemon.store.export import export_map, import_map
from daemon.store.sqlite_store import SCHEMA_VERSION, MapStore, SavedPose
from daemon.vision.disambiguation import Feature, PairFeatures
from daemon.vision.drawing import LANDMARK_COLOUR
from daemon.vision.floor import ColourModel, FloorModel
from kernel.errors import MapStoreError
from kernel.se2 import SE2, UncertainSE2
from tests.map_fixtures import synthetic_place, write_places_until_killed

GEOMETRY = "abc123"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _two_places(path: Path) -> MapStore:
    rng = np.random.default_rng(1)
    store = MapStore.open(path, GEOMETRY)
    a = store.add_place(synthetic_place(rng, "dock"))
    T = UncertainSE2(SE2(1.5, -0.2, 0.3), np.diag([0.01, 0.02, 0.003]))
    store.add_place(synthetic_place(rng, "door"), [(a.id, T, "odometry")])
    return store


def test_place_and_transitions_round_trip_both_ways(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    original = synthetic_place(rng, "dock")
    with _two_places(tmp_path / "map.db") as store:
        graph = store.load()
        assert [p.label for p in graph.places] == ["dock", "door"]
        first = graph.place(1)
        assert np.array_equal(first.landmarks.templates(), original.landmarks.templates())
        assert first.reference_panorama is None  # the map in memory holds no panoramas
        assert np.array_equal(store.reference_panorama(1), original.reference_panorama)
        assert np.array_equal(store.place(1, panorama=True).reference_panorama,
                              original.reference_panorama)
        assert first.landmarks.landmarks[3].depth == original.landmarks.landmarks[3].depth
        forward, back = graph.transition(1, 2), graph.transition(2, 1)
        assert forward is not None and back is not None
        assert forward.T_from_to.mean.as_tuple() == pytest.approx((1.5, -0.2, 0.3))
        round_trip = forward.T_from_to.mean.compose(back.T_from_to.mean)
        assert round_trip.as_tuple() == pytest.approx((0, 0, 0), abs=1e-12)
        assert [t.to_id for t in store.neighbours(2)] == [1]
        assert store.transition_count() == 2


def test_background_lrp_is_unknown_until_measured(tmp_path: Path) -> None:
    with _two_places(tmp_path / "map.db") as store:
        assert store.place(1).background_lrp is None
        store.set_background(1, 0.71)
        assert store.place(1).background_lrp == pytest.approx(0.71)


def _open_and_read_all(path: Path, geometry: str, readonly: bool) -> None:
    """What map info, export and a daemon's start read: every place and panorama."""
    with MapStore.open(path, geometry, readonly=readonly) as store:
        for place in store.load().places:
            store.reference_panorama(place.id)


def _truncated(p: Path) -> None:
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])


def _corrupt_place_bytes(p: Path) -> None:
    data = bytearray(p.read_bytes())
    # Inside the second place's panorama PNG: SQLite's structure stays intact.
    i = data.rfind(b"IDAT") + 400
    data[i: i + 64] = bytes(64)
    p.write_bytes(bytes(data))


def _corrupt_landmark_bytes(p: Path) -> None:
    data = bytearray(p.read_bytes())
    i = data.rfind(b"PCLS") + 200  # inside the second place's landmark set
    data[i: i + 16] = bytes(16)
    p.write_bytes(bytes(data))


def _corrupt_btree(p: Path) -> None:
    data = bytearray(p.read_bytes())
    page = 4096
    data[page: page + 200] = os.urandom(200)  # page 2: the first table's b-tree page
    p.write_bytes(bytes(data))


def _newer_schema(p: Path) -> None:
    db = sqlite3.connect(p)
    db.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'",
               (str(SCHEMA_VERSION + 1),))
    db.commit()
    db.close()


def _not_a_map(p: Path) -> None:
    p.unlink()
    db = sqlite3.connect(p)
    db.execute("CREATE TABLE recipes (name TEXT)")
    db.commit()
    db.close()


def _random_bytes(p: Path) -> None:
    p.write_bytes(np.random.default_rng(3).integers(0, 256, 20000, np.uint8).tobytes())


@pytest.mark.parametrize(("damage", "geometry", "message"), [
    (_truncated, GEOMETRY, "damaged|not a readable"),
    (_corrupt_place_bytes, GEOMETRY, "place 2 is damaged .*panorama"),
    (_corrupt_landmark_bytes, GEOMETRY, "place 2 is damaged"),
    (_corrupt_btree, GEOMETRY, "damaged|not a readable"),
    (_newer_schema, GEOMETRY, f"schema version {SCHEMA_VERSION + 1}.*upgrade placecell"),
    (lambda p: None, "fff000", "another panorama geometry"),
    (_not_a_map, GEOMETRY, "not a placecell map .*without its meta table"),
    (_random_bytes, GEOMETRY, "not a placecell map .*not an SQLite file"),
])
def test_bad_files_are_refused_byte_for_byte_unchanged(tmp_path: Path, damage, geometry: str,
                                                       message: str) -> None:
    path = tmp_path / "map.db"
    store = _two_places(path)
    store.close()  # checkpoints the WAL into the file
    damage(path)
    before = _sha(path)
    with pytest.raises(MapStoreError, match=message):
        _open_and_read_all(path, geometry, readonly=False)
    with pytest.raises(MapStoreError, match=message):
        _open_and_read_all(path, geometry, readonly=True)
    assert _sha(path) == before


def test_version_1_map_is_migrated(tmp_path: Path) -> None:
    path = tmp_path / "v1.db"
    db = sqlite3.connect(path)
    db.executescript("""
        CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        CREATE TABLE places (id INTEGER PRIMARY KEY, label TEXT NOT NULL DEFAULT '',
            created_unix_s REAL NOT NULL, background_lrp REAL, data BLOB NOT NULL);
        CREATE TABLE transitions (from_id INTEGER NOT NULL, to_id INTEGER NOT NULL,
            x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL, covariance BLOB NOT NULL,
            PRIMARY KEY (from_id, to_id));
        INSERT INTO meta VALUES ('schema_version', '1'), ('geometry_checksum', 'abc123'),
            ('created_unix_s', '1700000000.0');
    """)
    db.commit()
    db.close()
    with MapStore.open(path, GEOMETRY) as store:
        assert store.meta("schema_version") == str(SCHEMA_VERSION)
        assert store.meta("created_unix_s") == "1700000000.0"
        stored = store.add_place(synthetic_place(np.random.default_rng(0)))
        assert store.place(stored.id).landmark_count == 16


def test_version_2_map_keeps_its_places_and_gains_background_estimates(tmp_path: Path
                                                                       ) -> None:
    path = tmp_path / "v2.db"
    _two_places(path).close()
    db = sqlite3.connect(path)  # what a version 2 file holds: no background_estimate
    db.execute("ALTER TABLE places DROP COLUMN background_estimate")
    db.execute("ALTER TABLE places DROP COLUMN signature")
    db.execute("ALTER TABLE places DROP COLUMN background_cross")
    db.execute("DROP TABLE resume")
    db.execute("DROP TABLE features")
    db.execute("DROP TABLE floor")
    db.execute("DROP TABLE views")
    db.execute("DROP TABLE origins")
    db.execute("UPDATE meta SET value = '2' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    with MapStore.open(path, GEOMETRY) as store:
        assert store.meta("schema_version") == str(SCHEMA_VERSION)
        before = store.load()
        assert [p.label for p in before.places] == ["dock", "door"]
        assert all(p.background_estimate is None for p in before.places)
        assert store.transition_count() == 2
        mapper = Mapper(store, OdometryNoiseSettings())  # the daemon's, at start
        estimates = [p.background_estimate for p in store.load().places]
        assert all(e is not None and -1.0 <= e <= 1.0 for e in estimates), estimates
        assert [p.background_estimate for p in mapper.graph.places] == estimates
        assert all(p.signature is not None and p.signature.shape == (144,)
                   for p in store.load().places)
        assert store.saved_pose() is None  # v4's resume table, empty
        assert store.features() == []  # v5's features table, empty
        assert store.floor() is None  # v6's floor table, empty
        # v7's backgrounds in the other places' views, measured by the mapper at start
        crosses = [p.background_cross for p in store.load().places]
        assert all(c is not None and -1.0 <= c <= 1.0 for c in crosses), crosses


def test_the_saved_pose_survives_a_reopen_and_bad_ones_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "map.db"
    cov = np.diag([0.0004, 0.0009, 0.0001])
    with _two_places(path) as store:
        assert store.saved_pose() is None
        store.save_pose(SavedPose(1, (0.5, -0.25, 1.0), cov, 100.0))
        store.save_pose(SavedPose(2, (0.1, 0.2, -0.3), cov, 200.0))  # replaces
        with pytest.raises(MapStoreError, match="finite"):
            store.save_pose(SavedPose(2, (float("nan"), 0.0, 0.0), cov, 300.0))
        with pytest.raises(sqlite3.IntegrityError):  # a place the map does not hold
            store.save_pose(SavedPose(9, (0.0, 0.0, 0.0), cov, 300.0))
    with MapStore.open(path, GEOMETRY) as store:
        saved = store.saved_pose()
    assert saved is not None and saved.place_id == 2 and saved.saved_unix_s == 200.0
    assert saved.pose == (0.1, 0.2, -0.3) and np.array_equal(saved.covariance, cov)


def test_readers_are_not_blocked_by_the_writer(tmp_path: Path) -> None:
    path = tmp_path / "map.db"
    _two_places(path).close()
    writer = sqlite3.connect(path, isolation_level=None)
    writer.execute("BEGIN IMMEDIATE")
    writer.execute("UPDATE places SET label = 'renamed' WHERE id = 1")
    seen: list[str] = []

    def read() -> None:
        with MapStore.open(path, None, readonly=True) as reader:
            seen.extend(s.label for s in reader.summaries())

    t = threading.Thread(target=read)
    t.start()
    t.join(5.0)
    writer.execute("COMMIT")
    writer.close()
    assert not t.is_alive() and seen == ["dock", "door"]  # the committed state, at once


def test_export_then_import_gives_the_same_map(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    pair = PairFeatures(1, 2, Feature(10, 4, rng.integers(0, 255, (24, 24), np.uint8), 0.9,
                                      0.4),
                        Feature(300, 12, rng.integers(0, 255, (16, 16), np.uint8), 0.8, 0.5))
    floor = FloorModel(ColourModel(rng.integers(0, 256, (256, 256)).astype(np.uint8)), 0.37)
    with _two_places(tmp_path / "map.db") as store:
        store.set_background(2, 0.68)
        store.put_features(pair)
        store.save_floor(floor, 100.0)
        views = [rng.integers(0, 256, (20, 60)).astype(np.uint8) for _ in range(3)]
        store.put_views(2, views)
        assert export_map(store, tmp_path / "out") == 2
        original = store.load()
        panoramas = [store.reference_panorama(p.id) for p in original.places]
    assert import_map(tmp_path / "out", tmp_path / "copy.db") == 2
    with MapStore.open(tmp_path / "copy.db", GEOMETRY) as copy:
        again = copy.load()
        assert all(np.array_equal(pano, copy.reference_panorama(p.id))
                   for pano, p in zip(panoramas, again.places, strict=True))
        assert copy.views(1) == [] and len(copy.views(2)) == 3  # learning views, design §5
        assert all(np.array_equal(a, b) for a, b in zip(copy.views(2), views, strict=True))
    for a, b in zip(original.places, again.places, strict=True):
        assert (a.id, a.label, a.background_lrp) == (b.id, b.label, b.background_lrp)
        assert a.landmarks.templates().tobytes() == b.landmarks.templates().tobytes()
        for la, lb in zip(a.landmarks.landmarks, b.landmarks.landmarks, strict=True):
            assert (la.row, la.col, la.bearing, la.depth) == (lb.row, lb.col, lb.bearing,
                                                              lb.depth)
            assert np.array_equal(la.covariance, lb.covariance)
    assert {(t.from_id, t.to_id, t.T_from_to.mean) for t in original.transitions} == {
        (t.from_id, t.to_id, t.T_from_to.mean) for t in again.transitions}
    assert again.floor is not None and again.floor.gradient_threshold == 0.37
    assert again.floor.colour.histogram.tobytes() == floor.colour.histogram.tobytes()
    (kept,) = again.features  # the look-alikes' features come back byte for byte
    for f, g in ((pair.a, kept.a), (pair.b, kept.b)):
        assert (f.col, f.row, f.own_ncc, f.other_ncc) == (g.col, g.row, g.own_ncc, g.other_ncc)
        assert f.template.tobytes() == g.template.tobytes()
    # The picture shows every landmark: its outline in the landmark colour.
    drawn = cv2.imread(str(tmp_path / "out" / "place-1.png"))
    for lm in original.place(1).landmarks.landmarks:
        top = drawn[lm.row * 2, lm.col * 2: lm.col * 2 + 32]
        assert np.mean(np.all(top == LANDMARK_COLOUR, axis=1)) > 0.9
    with pytest.raises(MapStoreError, match="exists"):
        import_map(tmp_path / "out", tmp_path / "copy.db")


def test_sigkill_while_writing_never_leaves_half_a_place(tmp_path: Path) -> None:
    path = tmp_path / "map.db"
    MapStore.open(path, GEOMETRY).close()
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["daemon.store.sqlite_store", "tests.map_fixtures"])
    rng = np.random.default_rng(11)
    kills, checked = 200, 0  # issue 11: at least 200 kills
    for k in range(kills):
        writing = ctx.Event()
        proc = ctx.Process(target=write_places_until_killed, args=(str(path), GEOMETRY, k,
                                                                   writing), daemon=True)
        proc.start()
        assert writing.wait(30.0), f"writer {k} did not start (exit code {proc.exitcode})"
        proc.join(float(rng.uniform(0.0, 0.05)))  # a random moment of its writing
        proc.kill()
        proc.join(5.0)
        db = sqlite3.connect(path)
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        db.close()
        with MapStore.open(path, GEOMETRY, readonly=True) as store:
            ids = [summary.id for summary in store.summaries()]
            assert ids == list(range(1, len(ids) + 1))
            for pid in ids[max(checked - 1, 0):]:  # places written since the last kill
                store.place(pid)  # decodes, digest checked
                if pid > 1:  # complete with its transitions, both ways
                    assert pid - 1 in [t.to_id for t in store.neighbours(pid)]
                    assert pid in [t.to_id for t in store.neighbours(pid - 1)]
            checked = len(ids)
    assert checked > 20  # the writer did get to write between kills
    with MapStore.open(path, GEOMETRY, readonly=True) as store:
        assert len(store.load()) == checked


def test_placecellctl_map_commands_answer_in_json(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from tools.ctl import EXIT_OK, EXIT_REFUSED, main

    _two_places(tmp_path / "map.db").close()
    assert main(["map", "info", str(tmp_path / "map.db"), "--json"]) == EXIT_OK
    info = json.loads(capsys.readouterr().out)
    assert info["places"] == 2 and info["schema_version"] == str(SCHEMA_VERSION)
    assert info["floor_model"] is False and info["lookalike_pairs"] == 0
    assert info["places_with_local_space"] == 0  # synthetic places carry no profile
    histogram = np.zeros((256, 256), np.uint8)
    histogram[80, 90] = 255
    with MapStore.open(tmp_path / "map.db", GEOMETRY) as store:  # a floor learned
        store.save_floor(FloorModel(ColourModel(histogram), 0.2), 1.0)
    assert main(["map", "info", str(tmp_path / "map.db")]) == EXIT_OK
    assert "floor model learned, 0 places with a local space profile" in \
        capsys.readouterr().out
    assert main(["map", "export", str(tmp_path / "map.db"), str(tmp_path / "out"),
                 "--json"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["exported"] == 2
    assert main(["map", "import", str(tmp_path / "out"), str(tmp_path / "copy.db"),
                 "--json"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["imported"] == 2
    (tmp_path / "junk.db").write_bytes(b"not a map")
    assert main(["map", "info", str(tmp_path / "junk.db"), "--json"]) == EXIT_REFUSED
    refused = json.loads(capsys.readouterr().out)
    assert refused["kind"] == "error" and "not a placecell map" in refused["message"]



def test_the_map_frame_is_optimised_off_the_callers_thread_latest_result_kept(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """design §6: Mapper embeds the places in the `map` frame on a thread of its own
    (a large map takes seconds), and an optimisation that ends late never replaces a
    later one's result."""
    import daemon.service.mapper as mapper_module

    release = threading.Event()
    real_embed = mapper_module.embed
    calls: list[int] = []

    def first_one_slow(graph: Any) -> Any:
        calls.append(len(graph.places))
        if len(calls) == 1:
            assert release.wait(10)  # the start-up optimisation ends last
        return real_embed(graph)

    monkeypatch.setattr(mapper_module, "embed", first_one_slow)
    with _two_places(tmp_path / "map.db") as store:
        mapper = Mapper(store, OdometryNoiseSettings())  # returns while it optimises
        assert mapper.map_frame == {}
        mapper.reembed().join(10)
        held = mapper.map_frame
        assert set(held) == {1, 2}
        release.set()
        for thread in threading.enumerate():
            if thread.name == "placecell-embed":
                thread.join(10)
        assert calls == [2, 2]
        assert mapper.map_frame is held  # the late start-up result was dropped


def test_version_4_map_gains_the_features_table_and_keeps_the_rest(tmp_path: Path) -> None:
    """Schema 5 (design §5): each look-alike pair's features, both ways; a version 4
    file keeps its places, transitions and saved pose and gains an empty table."""
    path = tmp_path / "v4.db"
    cov = np.diag([0.0004, 0.0009, 0.0001])
    with _two_places(path) as store:
        store.save_pose(SavedPose(2, (0.1, 0.2, -0.3), cov, 200.0))
    db = sqlite3.connect(path)
    db.execute("DROP TABLE features")
    db.execute("DROP TABLE floor")
    db.execute("ALTER TABLE places DROP COLUMN background_cross")
    db.execute("DROP TABLE views")
    db.execute("DROP TABLE origins")
    db.execute("UPDATE meta SET value = '4' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    rng = np.random.default_rng(2)
    fa = Feature(40, 8, rng.integers(0, 256, (24, 24)).astype(np.uint8), 0.95, 0.31)
    fb = Feature(600, 16, rng.integers(0, 256, (16, 16)).astype(np.uint8), 0.9, 0.42)
    with MapStore.open(path, GEOMETRY) as store:
        assert store.meta("schema_version") == str(SCHEMA_VERSION) == "9"
        assert [p.label for p in store.load().places] == ["dock", "door"]
        assert store.transition_count() == 2 and store.saved_pose() is not None
        assert store.features() == []
        store.put_features(PairFeatures(1, 2, fa, fb))
    with MapStore.open(path, GEOMETRY) as store:
        (pair,) = store.features()
    assert (pair.a_id, pair.b_id) == (1, 2)
    assert np.array_equal(pair.a.template, fa.template) and pair.a.size == 24
    assert (pair.b.col, pair.b.row, pair.b.own_ncc, pair.b.other_ncc) == (600, 16, 0.9, 0.42)


def test_the_floor_model_is_kept_with_the_map_and_a_damaged_one_named(tmp_path: Path
                                                                       ) -> None:
    """Schema 6 (design §4): one floor model per map, replaced when learned again; a
    version 5 file gains the empty table; a damaged histogram is named, not used."""
    path = tmp_path / "v5.db"
    _two_places(path).close()
    db = sqlite3.connect(path)
    db.execute("DROP TABLE floor")
    db.execute("ALTER TABLE places DROP COLUMN background_cross")
    db.execute("DROP TABLE views")
    db.execute("DROP TABLE origins")
    db.execute("UPDATE meta SET value = '5' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    histogram = np.zeros((256, 256), np.uint8)
    histogram[80, 90] = 255
    with MapStore.open(path, GEOMETRY) as store:
        assert store.meta("schema_version") == "9" and store.floor() is None
        store.save_floor(FloorModel(ColourModel(histogram), 0.2), 10.0)
        store.save_floor(FloorModel(ColourModel(histogram), 0.3), 20.0)
    with MapStore.open(path, GEOMETRY) as store:
        floor = store.load().floor
        assert floor is not None and floor.gradient_threshold == 0.3
        assert np.array_equal(floor.colour.histogram, histogram)
    _write_behind(path, "UPDATE floor SET histogram = ?", (b"short",))
    with MapStore.open(path, GEOMETRY) as store, pytest.raises(
            MapStoreError, match="floor model is damaged"):
        store.floor()
    with pytest.raises(ValueError, match="gradient threshold is positive"):
        FloorModel(ColourModel(histogram), 0.0)


def test_version_6_map_gains_the_backgrounds_in_the_other_places_views(tmp_path: Path
                                                                       ) -> None:
    """Schema 7 (design §9): each place's background in the other places' views; a
    version 6 file keeps its places, the column empty until the daemon's mapper
    measures it from the stored panoramas (a read-only map is left as it is)."""
    path = tmp_path / "v6.db"
    _two_places(path).close()
    db = sqlite3.connect(path)
    db.execute("ALTER TABLE places DROP COLUMN background_cross")
    db.execute("DROP TABLE views")
    db.execute("DROP TABLE origins")
    db.execute("UPDATE meta SET value = '6' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    with MapStore.open(path, GEOMETRY) as store:
        assert store.meta("schema_version") == "9"
        assert [p.background_cross for p in store.load().places] == [None, None]
    with MapStore.open(path, GEOMETRY, readonly=True) as store:
        Mapper(store, OdometryNoiseSettings())
        assert [p.background_cross for p in store.load().places] == [None, None]
    with MapStore.open(path, GEOMETRY) as store:
        mapper = Mapper(store, OdometryNoiseSettings())
        stored = [p.background_cross for p in store.load().places]
        assert all(c is not None and -1.0 <= c <= 1.0 for c in stored), stored
        assert [p.background_cross for p in mapper.graph.places] == stored


def test_version_8_map_gains_the_fleets_origins_and_a_place_is_taken_once(
        tmp_path: Path) -> None:
    """Schema 9 (docs/fleet.md): the places taken from other robots, each by the robot
    that learned it and its id there; a version 8 file gains the empty table (all its
    places its own). A place taken is stored whole, under this map's next id, with its
    learning views; the same robot's place again is refused and changes nothing."""
    path = tmp_path / "v8.db"
    _two_places(path).close()
    db = sqlite3.connect(path)
    db.execute("DROP TABLE origins")
    db.execute("UPDATE meta SET value = '8' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    rng = np.random.default_rng(4)
    views = [rng.integers(0, 256, (24, 80)).astype(np.uint8) for _ in range(2)]
    with MapStore.open(path, GEOMETRY) as store:
        assert store.meta("schema_version") == "9" and store.origins() == {}
        theirs = store.place(1, panorama=True)
        taken = store.adopt_place(theirs, views, "robot-b", 7)
        assert taken.id == 3 and store.origins() == {3: ("robot-b", 7)}
        with pytest.raises(MapStoreError, match="place 7 of robot 'robot-b' is in the map"):
            store.adopt_place(theirs, views, "robot-b", 7)
    with MapStore.open(path, GEOMETRY, readonly=True) as store:
        assert store.place_count() == 3 and store.origins() == {3: ("robot-b", 7)}
        assert all(np.array_equal(a, b) for a, b in zip(store.views(3), views, strict=True))
        assert store.place(3).landmarks.width == store.place(1).landmarks.width


def test_version_7_map_gains_the_learning_views_and_a_damaged_one_is_named(
        tmp_path: Path) -> None:
    """Schema 8 (design §5): each place's learning views (grey, with their wrap margin),
    kept for the features of look-alikes learned later; a version 7 file gains the
    empty table (its places have none: their features are scored on the reference)."""
    path = tmp_path / "v7.db"
    _two_places(path).close()
    db = sqlite3.connect(path)
    db.execute("DROP TABLE views")
    db.execute("DROP TABLE origins")
    db.execute("UPDATE meta SET value = '7' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    rng = np.random.default_rng(3)
    views = [rng.integers(0, 256, (24, 80)).astype(np.uint8) for _ in range(4)]
    with MapStore.open(path, GEOMETRY) as store:
        assert store.meta("schema_version") == "9" and store.views(1) == []
        store.put_views(1, views[:2])
        store.put_views(1, views)  # replaced whole, not added to
    with MapStore.open(path, GEOMETRY, readonly=True) as store:
        kept = store.views(1)
        assert store.views(2) == []
    assert len(kept) == 4 and all(np.array_equal(a, b) for a, b in zip(kept, views,
                                                                       strict=True))
    _write_behind(path, "UPDATE views SET panorama = ? WHERE place_id = 1 AND k = 2",
                  (b"\x89PNG",))
    with MapStore.open(path, GEOMETRY) as store, pytest.raises(
            MapStoreError, match="place 1's learning view 2 is damaged"):
        store.views(1)


def _write_behind(path: Path, statement: str, args: tuple[Any, ...] = ()) -> None:
    """Change the map file behind placecell's back (damage, as a disk or a person would)."""
    db = sqlite3.connect(path)
    db.execute(statement, args)
    db.commit()
    db.close()
