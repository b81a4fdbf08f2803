"""The map file: the topological map in one SQLite file (design §6; docs/design.md, "Map file").

- WAL journal: a reader (``placecellctl map info``, a second process) is never blocked by
  the daemon writing, and a crash (even SIGKILL) loses at most the place being written.
- Each place is written with its transitions (both ways) in one transaction: after any
  crash a place is either complete with its transitions or absent.
- A schema version with migrations from older versions, and the checksum of the panorama
  geometry: a map made with another unwarping is refused, never silently misused.
- Refused files are left byte-for-byte as they were: every check runs on a read-only
  connection before anything is written.
- Each place's bytes carry a SHA-256 digest; a damaged place is reported by id.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import sqlite3
import stat
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from daemon.mapping.graph import TopologicalMap
from daemon.mapping.place import Place
from daemon.mapping.transition import Transition
from daemon.store import codec
from daemon.vision.disambiguation import Feature, PairFeatures
from daemon.vision.floor import BINS, ColourModel, FloorModel
from kernel.errors import MapNotWritableError, MapStoreError
from kernel.se2 import SE2, UncertainSE2

log = logging.getLogger(__name__)

SCHEMA_VERSION = 9
APPLICATION = "placecell-map"

_SCHEMA = """
CREATE TABLE meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE places (
    id             INTEGER PRIMARY KEY AUTOINCREMENT,
    label          TEXT NOT NULL DEFAULT '',
    created_unix_s REAL NOT NULL,
    background_lrp REAL,
    background_estimate REAL,           -- v3: from the reference panorama, NULL if not made
    signature      BLOB,                -- v3: float64, daemon/vision/signature.py
    background_cross REAL,              -- v7: in the other places' views, NULL if not made
    landmark_count INTEGER NOT NULL,
    landmarks      BLOB NOT NULL,       -- daemon/store/codec.py
    panorama       BLOB NOT NULL,       -- reference panorama, lossless PNG
    local_space    BLOB,                -- 16 float64 (chapter 5), NULL until measured
    digest         TEXT NOT NULL,       -- sha256 over landmarks and local_space
    panorama_digest TEXT NOT NULL       -- sha256 over panorama
);
CREATE TABLE transitions (
    from_id    INTEGER NOT NULL REFERENCES places(id),
    to_id      INTEGER NOT NULL REFERENCES places(id),
    x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL,   -- to's frame in from's (T_from_to)
    covariance BLOB NOT NULL,                             -- 3x3 float64, little endian
    source     TEXT NOT NULL,                             -- odometry | vision | cycle
    PRIMARY KEY (from_id, to_id)
);
CREATE INDEX transitions_to ON transitions(to_id);
"""
_RESUME_TABLE = """
CREATE TABLE resume (                                     -- v4: where the robot was last
    id           INTEGER PRIMARY KEY CHECK (id = 1),      -- one row
    place_id     INTEGER NOT NULL REFERENCES places(id),
    x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL,  -- in the place's frame
    covariance   BLOB NOT NULL,                           -- 3x3 float64, little endian
    saved_unix_s REAL NOT NULL
)
"""
_FEATURES_TABLE = """
CREATE TABLE features (                                   -- v5: disambiguating features
    place_id  INTEGER NOT NULL REFERENCES places(id),     -- the place the patch is cut from
    other_id  INTEGER NOT NULL REFERENCES places(id),     -- the look-alike it tells it from
    col INTEGER NOT NULL, row INTEGER NOT NULL,           -- in place_id's reference core
    template  BLOB NOT NULL,                              -- side x side uint8, row-major
    own_ncc   REAL NOT NULL, other_ncc REAL NOT NULL,     -- daemon/vision/disambiguation.py
    PRIMARY KEY (place_id, other_id)
)
"""
_FLOOR_TABLE = """
CREATE TABLE floor (                                      -- v6: the floor model (design §4)
    id           INTEGER PRIMARY KEY CHECK (id = 1),      -- one row
    histogram    BLOB NOT NULL,                           -- 256 x 256 uint8 rg chromaticity
    gradient_threshold REAL NOT NULL,                     -- daemon/vision/floor.py
    learned_unix_s REAL NOT NULL
)
"""
_VIEWS_TABLE = """
CREATE TABLE views (                                      -- v8: learning views (design §5)
    place_id  INTEGER NOT NULL REFERENCES places(id),     -- the place seen a little off
    k         INTEGER NOT NULL,                           -- 0, 1, ...: the cross's arms
    panorama  BLOB NOT NULL,                              -- grey with its wrap margin, PNG
    digest    TEXT NOT NULL,                              -- sha256 over panorama
    PRIMARY KEY (place_id, k)
)
"""
_ORIGINS_TABLE = """
CREATE TABLE origins (                                    -- v9: places a fleet shared
    place_id  INTEGER PRIMARY KEY REFERENCES places(id),  -- its id in this map
    robot     TEXT NOT NULL,                              -- the robot that learned it
    origin_id INTEGER NOT NULL,                           -- its id in that robot's map
    UNIQUE (robot, origin_id)
)
"""
_SCHEMA += ";" + _RESUME_TABLE + ";" + _FEATURES_TABLE + ";" + _FLOOR_TABLE + ";" \
    + _VIEWS_TABLE + ";" + _ORIGINS_TABLE


_PLACE_COLUMNS = ("id, label, created_unix_s, background_lrp, landmarks, local_space, "
                  "digest, background_estimate, signature, background_cross")


@dataclass(frozen=True)
class SavedPose:
    """The robot's last reliable pose, saved for a restart (design §11)."""

    place_id: int
    pose: tuple[float, float, float]  # x, y (m), yaw (rad) in the place's frame
    covariance: np.ndarray  # 3x3
    saved_unix_s: float


@dataclass(frozen=True)
class PlaceSummary:
    """What ``map/places`` and ``placecellctl places`` show of a place."""

    id: int
    label: str
    created_unix_s: float
    landmark_count: int
    background_lrp: float | None


class MapStore:
    """An open map file. Use :meth:`open`; close with :meth:`close` (or as a context).
    One connection shared by the daemon's threads under a lock."""

    def __init__(self, connection: sqlite3.Connection, path: Path, readonly: bool) -> None:
        self._db = connection
        self._lock = threading.RLock()
        self.path = path
        self.readonly = readonly

    # ------------------------------------------------------------ opening
    @classmethod
    def open(cls, path: str | Path, geometry_checksum: str | None, *,
             readonly: bool = False) -> MapStore:
        """Open (or, unless ``readonly``, create) the map at ``path``.

        ``geometry_checksum`` None accepts any geometry (offline tools that only read).
        Raises MapStoreError, leaving the file untouched, for anything that is not a
        healthy placecell map of this geometry and of a schema this version reads."""
        p = Path(path)
        _refuse_unusable(p)
        if not p.exists():
            if readonly:
                raise MapStoreError(f"{p}: no such map file")
            return cls._create(p, geometry_checksum)
        journals = [j for j in _with_journals(p)[1:] if not j.exists()]
        version = _inspect(p, geometry_checksum)
        if readonly:
            db = _connect(p, readonly=True)
            return cls(db, p, readonly=True)
        db = _connect(p, readonly=False)
        try:
            try:
                _probe_write(db, p)
            except MapNotWritableError:
                db.close()
                _remove_empty(journals)  # what SQLite's reading left beside it
                raise
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA foreign_keys=ON")
            if version < SCHEMA_VERSION:
                _migrate(db, p, version)
        except MapStoreError:
            db.close()
            raise
        except sqlite3.DatabaseError as e:
            db.close()
            raise MapStoreError(f"{p}: cannot open the map for writing ({e})") from e
        return cls(db, p, readonly=False)

    @classmethod
    def _create(cls, p: Path, geometry_checksum: str | None) -> MapStore:
        """A new, empty map, built under a temporary name and renamed into place: a file
        at ``p`` is always a whole map, never one cut short while it was made."""
        if geometry_checksum is None:
            raise MapStoreError(f"{p}: a new map needs the panorama geometry's checksum")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise MapStoreError(f"cannot create the map directory {p.parent}: "
                                f"{e.strerror}") from e
        building = p.with_name(p.name + ".new")
        for leftover in _with_journals(building):
            leftover.unlink(missing_ok=True)
        try:
            db = _connect(building, readonly=False)
            try:
                db.execute("PRAGMA journal_mode=WAL")
                with _transaction(db):
                    _create_tables(db)
                    db.executemany("INSERT INTO meta(key, value) VALUES (?, ?)", [
                        ("application", APPLICATION),
                        ("schema_version", str(SCHEMA_VERSION)),
                        ("geometry_checksum", geometry_checksum),
                        ("created_unix_s", repr(time.time())),
                    ])
            finally:
                db.close()  # the last connection: the log is checkpointed into the file
            os.replace(building, p)
        except (sqlite3.DatabaseError, OSError) as e:
            with contextlib.suppress(OSError):
                building.unlink(missing_ok=True)
            raise MapStoreError(f"cannot create the map {p}: {e}") from e
        log.info("created map %s", p)
        return cls.open(p, geometry_checksum)

    # ------------------------------------------------------------ reading
    def place_count(self) -> int:
        return int(self._one("SELECT COUNT(*) FROM places")[0])

    def transition_count(self) -> int:
        """Stored transitions, both directions counted."""
        return int(self._one("SELECT COUNT(*) FROM transitions")[0])

    def meta(self, key: str) -> str | None:
        row = self._one("SELECT value FROM meta WHERE key = ?", (key,))
        return None if row is None else str(row[0])

    def site_tie(self) -> tuple[str, float, float, float] | None:
        """The tie of the map frame to a site's map (frame, x, y, yaw of the map frame in
        it; design §11), or None: not tied. A malformed value reads as not tied."""
        text = self.meta("site_tie")
        try:
            d = json.loads(text) if text else None
            return None if d is None else (str(d["frame"]), float(d["x"]), float(d["y"]),
                                           float(d["yaw"]))
        except (ValueError, KeyError, TypeError):
            return None

    def save_site_tie(self, frame: str, x: float, y: float, yaw: float) -> None:
        """Store the map frame's pose in the site's map ``frame`` (replacing any)."""
        self._writable()
        value = json.dumps({"frame": frame, "x": float(x), "y": float(y), "yaw": float(yaw)})
        with self._lock, _transaction(self._db):
            self._db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('site_tie', ?)",
                             (value,))

    def summaries(self) -> list[PlaceSummary]:
        rows = self._all("SELECT id, label, created_unix_s, landmark_count, background_lrp "
                         "FROM places ORDER BY id")
        return [PlaceSummary(int(r[0]), str(r[1]), float(r[2]), int(r[3]),
                             None if r[4] is None else float(r[4])) for r in rows]

    def place(self, place_id: int, *, panorama: bool = False) -> Place:
        """A place by id (indexed); with its reference panorama if asked."""
        row = self._one(f"SELECT {_PLACE_COLUMNS} FROM places WHERE id = ?", (place_id,))
        if row is None:
            raise KeyError(place_id)
        place = self._decode_place(row)
        if panorama:
            place = dataclasses.replace(place, reference_panorama=self.reference_panorama(
                place_id))
        return place

    def reference_panorama(self, place_id: int) -> np.ndarray:
        row = self._one("SELECT panorama, panorama_digest FROM places WHERE id = ?",
                        (place_id,))
        if row is None:
            raise KeyError(place_id)
        where = f"{self.path}: place {place_id}"
        if codec.digest(row[0]) != row[1]:
            raise MapStoreError(f"{where} is damaged (its panorama's bytes do not match "
                                "their digest)")
        return codec.decode_image(bytes(row[0]), where)

    def neighbours(self, place_id: int) -> list[Transition]:
        """Transitions out of ``place_id`` (indexed: no scan)."""
        rows = self._all("SELECT from_id, to_id, x, y, yaw, covariance, source FROM "
                         "transitions WHERE from_id = ?", (place_id,))
        return [_transition(r) for r in rows]

    def transitions(self) -> list[Transition]:
        rows = self._all("SELECT from_id, to_id, x, y, yaw, covariance, source FROM "
                         "transitions ORDER BY from_id, to_id")
        return [_transition(r) for r in rows]

    def load(self) -> TopologicalMap:
        """The whole map in memory without the reference panoramas (read them with
        :meth:`reference_panorama`); every landmark set's digest checked."""
        rows = self._all(f"SELECT {_PLACE_COLUMNS} FROM places ORDER BY id")
        places = [self._decode_place(r) for r in rows]
        return TopologicalMap(places, self.transitions(), self.features(), self.floor())

    def _decode_place(self, row: Sequence[Any]) -> Place:
        pid, label, created, background, lm_blob, ls_blob, stored, estimate, sig, cross = row
        where = f"{self.path}: place {pid}"
        if codec.digest(lm_blob, ls_blob) != stored:
            raise MapStoreError(f"{where} is damaged (its bytes do not match their digest)")
        landmarks = codec.decode_landmarks(bytes(lm_blob), where)
        try:
            return Place(landmarks, None, label=str(label), created_unix_s=float(created),
                         background_lrp=None if background is None else float(background),
                         background_estimate=None if estimate is None else float(estimate),
                         background_cross=None if cross is None else float(cross),
                         signature=codec.decode_vector(sig),
                         local_space=codec.decode_vector(ls_blob), id=int(pid))
        except ValueError as e:
            raise MapStoreError(f"{where}: {e}") from e

    # ------------------------------------------------------------ writing
    def add_place(self, place: Place, links: Sequence[tuple[int, UncertainSE2, str]] = ()
                  ) -> Place:
        """Store ``place`` and its transitions in one transaction. ``links``: (existing
        place id, T_existing_new, source); each is stored both ways. Returns the place with
        the id it was given."""
        self._writable()
        with self._lock, _transaction(self._db):
            new_id = self._insert_place(place, keep_id=False)
            for other, T, source in links:
                t = Transition(int(other), new_id, T, source)  # type: ignore[arg-type]
                for one_way in t.both_ways():
                    self._put_transition(one_way)
        return dataclasses.replace(place, id=new_id)

    def adopt_place(self, place: Place, views: Sequence[np.ndarray], robot: str,
                    origin_id: int) -> Place:
        """Store a place another robot learned (place ``origin_id`` of ``robot``'s map,
        shared through the fleet, docs/fleet.md) with its learning views, under an id of
        this map, in one transaction. Returns the place with that id; MapStoreError if
        that robot's place is here already."""
        self._writable()
        blobs = [codec.encode_image(np.ascontiguousarray(v, dtype=np.uint8)) for v in views]
        try:
            with self._lock, _transaction(self._db):
                new_id = self._insert_place(place, keep_id=False)
                self._db.execute("INSERT INTO origins(place_id, robot, origin_id) "
                                 "VALUES (?, ?, ?)", (new_id, robot, origin_id))
                self._db.executemany(
                    "INSERT INTO views(place_id, k, panorama, digest) VALUES (?, ?, ?, ?)",
                    [(new_id, k, blob, codec.digest(blob)) for k, blob in enumerate(blobs)])
        except sqlite3.IntegrityError as e:
            raise MapStoreError(f"{self.path}: place {origin_id} of robot {robot!r} is "
                                f"in the map already ({e})") from e
        return dataclasses.replace(place, id=new_id)

    def origins(self) -> dict[int, tuple[str, int]]:
        """The places taken from other robots: this map's id → (robot, its id there)."""
        return {int(r[0]): (str(r[1]), int(r[2])) for r in
                self._all("SELECT place_id, robot, origin_id FROM origins")}

    def import_places(self, places: Sequence[Place], transitions: Sequence[Transition],
                      features: Sequence[PairFeatures] = ()) -> None:
        """Places with their ids, transitions and look-alike features as given (map
        import), in one transaction."""
        self._writable()
        with self._lock, _transaction(self._db):
            for place in places:
                self._insert_place(place, keep_id=True)
            for t in transitions:
                self._put_transition(t)
            for pair in features:
                self._put_features(pair)

    def add_transition(self, transition: Transition) -> None:
        """Store a transition both ways (replacing an earlier one between the two)."""
        self._writable()
        with self._lock, _transaction(self._db):
            for one_way in transition.both_ways():
                self._put_transition(one_way)

    def set_background(self, place_id: int, background_lrp: float) -> None:
        self._writable()
        with self._lock, _transaction(self._db):
            self._db.execute("UPDATE places SET background_lrp = ? WHERE id = ?",
                             (float(background_lrp), place_id))

    def set_cues(self, place_id: int, background_estimate: float, signature: np.ndarray
                 ) -> None:
        """What is derived from a place's reference panorama (a schema-2 map lacks it)."""
        self._writable()
        with self._lock, _transaction(self._db):
            self._db.execute("UPDATE places SET background_estimate = ?, signature = ? "
                             "WHERE id = ?", (float(background_estimate),
                                              codec.encode_vector(signature), place_id))

    def set_cross_backgrounds(self, values: dict[int, float]) -> None:
        """Places' background LRPs in the other places' views (design §9), in one
        transaction."""
        self._writable()
        with self._lock, _transaction(self._db):
            self._db.executemany("UPDATE places SET background_cross = ? WHERE id = ?",
                                 [(float(v), pid) for pid, v in values.items()])

    def save_pose(self, saved: SavedPose) -> None:
        """Replace the saved pose (one row; a crash keeps the previous one)."""
        self._writable()
        cov = np.asarray(saved.covariance, dtype="<f8").reshape(3, 3)
        if not (np.all(np.isfinite(cov)) and all(np.isfinite(saved.pose))):
            raise MapStoreError(f"a saved pose is finite, got {saved.pose}")
        with self._lock, _transaction(self._db):
            self._db.execute(
                "INSERT OR REPLACE INTO resume(id, place_id, x, y, yaw, covariance, "
                "saved_unix_s) VALUES (1, ?, ?, ?, ?, ?, ?)",
                (saved.place_id, *map(float, saved.pose), cov.tobytes(),
                 float(saved.saved_unix_s)))

    def save_floor(self, floor: FloorModel, learned_unix_s: float) -> None:
        """Replace the floor model (one row) the places' profiles are made with."""
        self._writable()
        histogram = np.ascontiguousarray(floor.colour.histogram, dtype=np.uint8)
        with self._lock, _transaction(self._db):
            self._db.execute("INSERT OR REPLACE INTO floor(id, histogram, gradient_threshold, "
                             "learned_unix_s) VALUES (1, ?, ?, ?)",
                             (histogram.tobytes(), float(floor.gradient_threshold),
                              float(learned_unix_s)))

    def floor(self) -> FloorModel | None:
        """The floor model stored with the map, or None (none learned yet)."""
        row = self._one("SELECT histogram, gradient_threshold FROM floor WHERE id = 1")
        if row is None:
            return None
        histogram = np.frombuffer(bytes(row[0]), dtype=np.uint8)
        try:
            return FloorModel(ColourModel(histogram.reshape(BINS, BINS).copy()), float(row[1]))
        except ValueError as e:
            raise MapStoreError(f"{self.path}: the floor model is damaged ({e})") from e

    def put_features(self, pair: PairFeatures) -> None:
        """Store (or replace) the features of a pair of look-alike places, both ways, in
        one transaction."""
        self._writable()
        with self._lock, _transaction(self._db):
            self._put_features(pair)

    def _put_features(self, pair: PairFeatures) -> None:
        for place_id, other_id, f in ((pair.a_id, pair.b_id, pair.a),
                                      (pair.b_id, pair.a_id, pair.b)):
            self._db.execute(
                "INSERT OR REPLACE INTO features(place_id, other_id, col, row, template, "
                "own_ncc, other_ncc) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (place_id, other_id, f.col, f.row,
                 np.ascontiguousarray(f.template, dtype=np.uint8).tobytes(),
                 float(f.own_ncc), float(f.other_ncc)))

    def put_views(self, place_id: int, views: Sequence[np.ndarray]) -> None:
        """Store (replacing any) a place's learning views: grey panoramas with their wrap
        margin, taken half-way out along the arms of its Turn Back and Look cross. A
        later look-alike's features are scored over them (design §5)."""
        self._writable()
        blobs = [codec.encode_image(np.ascontiguousarray(v, dtype=np.uint8)) for v in views]
        with self._lock, _transaction(self._db):
            self._db.execute("DELETE FROM views WHERE place_id = ?", (place_id,))
            self._db.executemany(
                "INSERT INTO views(place_id, k, panorama, digest) VALUES (?, ?, ?, ?)",
                [(place_id, k, blob, codec.digest(blob)) for k, blob in enumerate(blobs)])

    def views(self, place_id: int) -> list[np.ndarray]:
        """A place's learning views, in the order stored (none: a place learned before
        schema 8, or imported without them)."""
        rows = self._all("SELECT k, panorama, digest FROM views WHERE place_id = ? "
                         "ORDER BY k", (place_id,))
        out = []
        for k, blob, stored in rows:
            where = f"{self.path}: place {place_id}'s learning view {k}"
            if codec.digest(blob) != stored:
                raise MapStoreError(f"{where} is damaged (its bytes do not match their "
                                    "digest)")
            out.append(codec.decode_image(bytes(blob), where))
        return out

    def features(self) -> list[PairFeatures]:
        """Every pair's features (each pair once, the lower id first)."""
        rows = self._all("SELECT place_id, other_id, col, row, template, own_ncc, other_ncc "
                         "FROM features ORDER BY place_id, other_id")
        by_key = {(int(r[0]), int(r[1])): _feature(r, self.path) for r in rows}
        return [PairFeatures(a, b, fa, by_key[(b, a)])
                for (a, b), fa in by_key.items() if a < b and (b, a) in by_key]

    def saved_pose(self) -> SavedPose | None:
        """The pose saved last, or None (none saved, or its place is gone)."""
        row = self._one("SELECT r.place_id, r.x, r.y, r.yaw, r.covariance, r.saved_unix_s "
                        "FROM resume r JOIN places p ON p.id = r.place_id WHERE r.id = 1")
        if row is None:
            return None
        cov = np.frombuffer(bytes(row[4]), dtype="<f8")
        if cov.size != 9:
            raise MapStoreError(f"{self.path}: the saved pose's covariance is damaged")
        return SavedPose(int(row[0]), (float(row[1]), float(row[2]), float(row[3])),
                         cov.reshape(3, 3).copy(), float(row[5]))

    def _insert_place(self, place: Place, keep_id: bool) -> int:
        if place.reference_panorama is None:
            raise MapStoreError("a place is stored with its reference panorama")
        lm = codec.encode_landmarks(place.landmarks)
        pano = codec.encode_image(place.reference_panorama)
        ls = codec.encode_vector(place.local_space)
        cur = self._db.execute(
            "INSERT INTO places(id, label, created_unix_s, background_lrp, "
            "background_estimate, signature, background_cross, landmark_count, landmarks, "
            "panorama, local_space, digest, panorama_digest) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (place.id if keep_id else None, place.label, place.created_unix_s,
             place.background_lrp, place.background_estimate,
             codec.encode_vector(place.signature), place.background_cross,
             place.landmark_count, lm, pano, ls,
             codec.digest(lm, ls), codec.digest(pano)))
        return int(cur.lastrowid or 0)

    def _put_transition(self, t: Transition) -> None:
        m = t.T_from_to.mean
        cov = np.asarray(t.T_from_to.covariance, dtype="<f8").tobytes()
        self._db.execute("INSERT OR REPLACE INTO transitions(from_id, to_id, x, y, yaw, "
                         "covariance, source) VALUES (?, ?, ?, ?, ?, ?, ?)",
                         (t.from_id, t.to_id, m.x, m.y, m.yaw, cov, t.source))

    def _writable(self) -> None:
        if self.readonly:
            raise MapStoreError(f"{self.path} is open read-only")

    # ------------------------------------------------------------ plumbing
    def _one(self, sql: str, args: tuple[Any, ...] = ()) -> Any:
        with self._lock:
            try:
                return self._db.execute(sql, args).fetchone()
            except sqlite3.DatabaseError as e:
                raise MapStoreError(f"{self.path}: {e}") from e

    def _all(self, sql: str, args: tuple[Any, ...] = ()) -> list[Any]:
        with self._lock:
            try:
                return self._db.execute(sql, args).fetchall()
            except sqlite3.DatabaseError as e:
                raise MapStoreError(f"{self.path}: {e}") from e

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> MapStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _feature(r: Sequence[Any], path: Path) -> Feature:
    raw = np.frombuffer(bytes(r[4]), dtype=np.uint8)
    side = int(round(raw.size ** 0.5))
    if side * side != raw.size or side == 0:
        raise MapStoreError(f"{path}: the feature of place {r[0]} against {r[1]} is damaged")
    return Feature(int(r[2]), int(r[3]), raw.reshape(side, side).copy(), float(r[5]),
                   float(r[6]))


def _transition(r: Sequence[Any]) -> Transition:
    cov = np.frombuffer(r[5], dtype="<f8")
    if cov.size != 9:
        raise MapStoreError(f"transition {r[0]} -> {r[1]}: covariance is not 3 x 3")
    return Transition(int(r[0]), int(r[1]),
                      UncertainSE2(SE2(float(r[2]), float(r[3]), float(r[4])),
                                   cov.reshape(3, 3)), str(r[6]))  # type: ignore[arg-type]


def _connect(p: Path, readonly: bool) -> sqlite3.Connection:
    if readonly:
        return sqlite3.connect(f"file:{p}?mode=ro", uri=True, check_same_thread=False,
                               isolation_level=None)
    return sqlite3.connect(p, check_same_thread=False, isolation_level=None)


def _refuse_unusable(p: Path) -> None:
    """A path that is no map file and will not become one, refused before anything is
    read or written: a directory, a device or pipe, an empty file (no map this program
    writes is ever empty: :meth:`MapStore._create` renames a whole one into place), a
    file or folder it may not read."""
    try:
        st = p.stat()
    except (FileNotFoundError, NotADirectoryError):
        return  # no file yet: a new map, where the mode may create one
    except OSError as e:
        raise MapStoreError(f"{p}: cannot reach the map file ({e.strerror})") from e
    if stat.S_ISDIR(st.st_mode):
        raise MapStoreError(f"{p} is a directory, not a map file: set [map] path to a file "
                            f"(for example {p / 'placecell.db'})")
    if not stat.S_ISREG(st.st_mode):
        raise MapStoreError(f"{p} is not a regular file (a device, pipe or socket): set "
                            "[map] path to a map file")
    if st.st_size == 0:
        raise MapStoreError(f"{p} is empty (0 bytes): not a placecell map, and not made a "
                            "new one unasked; delete it, or set [map] path to another file, "
                            "to start a new map; the file was left untouched")
    if not os.access(p, os.R_OK):
        raise MapStoreError(f"{p}: cannot read the map file (permission denied)")


def _probe_write(db: sqlite3.Connection, p: Path) -> None:
    """Refuse a map that cannot be written before anything is learned: SQLite opens a
    read-only file read-only without a word and fails only at the first write, so one
    write is tried and rolled back (the file's bytes stay as they were)."""
    try:
        db.execute("BEGIN IMMEDIATE")
        try:
            db.execute("UPDATE meta SET value = value WHERE key = 'application'")
        finally:
            db.execute("ROLLBACK")
    except sqlite3.OperationalError as e:
        raise MapNotWritableError(f"{p} cannot be written ({e}): check the file's and its "
                                  "directory's permissions and the file system") from e


def _remove_empty(journals: list[Path]) -> None:
    """Remove the journal files this open made that hold nothing (a read-only
    connection leaves an empty log and its index behind; no other reader had them)."""
    for j in journals:
        with contextlib.suppress(OSError):
            if j.name.endswith("-shm") or j.stat().st_size == 0:
                j.unlink()


def _with_journals(p: Path) -> list[Path]:
    return [p, p.with_name(p.name + "-wal"), p.with_name(p.name + "-shm"),
            p.with_name(p.name + "-journal")]


def _inspect(p: Path, geometry_checksum: str | None) -> int:
    """Every check, on a read-only connection: the schema version this file has."""
    with open(p, "rb") as f:
        header = f.read(16)
    if header != b"SQLite format 3\x00":
        raise MapStoreError(f"{p} is not a placecell map (not an SQLite file); the file was "
                            "left untouched")
    try:
        db = _connect(p, readonly=True)
    except sqlite3.DatabaseError as e:
        raise MapStoreError(f"{p} is not a placecell map ({e})") from e
    try:
        check = db.execute("PRAGMA quick_check").fetchall()
        if [r[0] for r in check] != ["ok"]:
            raise MapStoreError(f"{p} is damaged (SQLite integrity check: "
                                f"{'; '.join(str(r[0]) for r in check[:3])}); the file was "
                                "left untouched")
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if "meta" not in tables:
            raise MapStoreError(f"{p} is not a placecell map (an SQLite file without its "
                                "meta table); the file was left untouched")
        rows = dict(db.execute("SELECT key, value FROM meta").fetchall())
        version_text = rows.get("schema_version")
        try:
            version = int(str(version_text))
        except ValueError:
            raise MapStoreError(f"{p} is not a placecell map (schema version "
                                f"{version_text!r}); the file was left untouched") from None
        if version > SCHEMA_VERSION:
            raise MapStoreError(
                f"{p} has map schema version {version}, this placecell reads versions up to "
                f"{SCHEMA_VERSION}: upgrade placecell; the file was left untouched")
        if version < 1:
            raise MapStoreError(f"{p} has an invalid map schema version {version}")
        stored = rows.get("geometry_checksum")
        if geometry_checksum is not None and stored != geometry_checksum:
            raise MapStoreError(
                f"{p} was made with another panorama geometry (checksum {stored}, configured "
                f"{geometry_checksum}): check [mirror] and [panorama], or set map.path to a "
                "new file; the map was left untouched")
        if version == 1 and int(db.execute("SELECT COUNT(*) FROM places").fetchone()[0]):
            raise MapStoreError(f"{p}: a version 1 map with places cannot be migrated (no "
                                "release stored any); the file was left untouched")
        return version
    except sqlite3.OperationalError as e:
        if "readonly" in str(e):  # a map in write-ahead-log mode in a read-only folder
            raise MapNotWritableError(
                f"{p} cannot be written ({e}): its folder {p.parent} is read-only, and "
                "SQLite keeps the map's write-ahead log beside it, even to read it; the "
                "file was left untouched") from e
        raise MapStoreError(f"{p} is not a readable placecell map ({e}); the file was left "
                            "untouched") from e
    except sqlite3.DatabaseError as e:
        raise MapStoreError(f"{p} is not a readable placecell map ({e}); the file was left "
                            "untouched") from e
    finally:
        db.close()


def _create_tables(db: sqlite3.Connection) -> None:
    for statement in _SCHEMA.split(";"):
        if statement.strip():
            db.execute(statement)


def _migrate(db: sqlite3.Connection, p: Path, version: int) -> None:
    """To the current version, in one transaction: 1 (meta, empty places and transitions
    tables) is rebuilt; 2 gains places.background_estimate and places.signature (NULL:
    the daemon's mapper makes them from the stored reference panoramas); 2 and 3 gain
    the resume table (no pose saved); 2 to 4 gain the features table (none yet: the
    daemon's mapper finds the look-alike pairs and their features); 2 to 5 gain the
    floor table (no floor model: the localiser learns one from its first colour frame);
    2 to 6 gain places.background_cross (NULL: the daemon's mapper measures it from the
    stored reference panoramas); 2 to 7 gain the views table (no learning views: an
    older place's features are scored over its reference alone, as before); 2 to 8 gain
    the origins table (every place its own robot's: none was taken from a fleet)."""
    with _transaction(db):
        if version == 2:
            db.execute("ALTER TABLE places ADD COLUMN background_estimate REAL")
            db.execute("ALTER TABLE places ADD COLUMN signature BLOB")
        if version in (2, 3):
            db.execute(_RESUME_TABLE)
        if version in (2, 3, 4):
            db.execute(_FEATURES_TABLE)
        if version in (2, 3, 4, 5):
            db.execute(_FLOOR_TABLE)
        if version in (2, 3, 4, 5, 6):
            db.execute("ALTER TABLE places ADD COLUMN background_cross REAL")
        if version in (2, 3, 4, 5, 6, 7):
            db.execute(_VIEWS_TABLE)
        if 2 <= version <= 8:
            db.execute(_ORIGINS_TABLE)
            db.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'",
                       (str(SCHEMA_VERSION),))
        if version == 1:
            meta = db.execute("SELECT key, value FROM meta").fetchall()
            db.execute("DROP TABLE IF EXISTS transitions")
            db.execute("DROP TABLE IF EXISTS places")
            db.execute("DROP TABLE meta")
            _create_tables(db)
            db.executemany("INSERT INTO meta(key, value) VALUES (?, ?)", meta)
            db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('application', ?)",
                       (APPLICATION,))
            db.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'",
                       (str(SCHEMA_VERSION),))
    log.info("migrated map %s from schema version %d to %d", p, version, SCHEMA_VERSION)


@contextlib.contextmanager
def _transaction(db: sqlite3.Connection) -> Iterator[None]:
    """All or nothing: a failure half-way leaves the file as it was."""
    db.execute("BEGIN IMMEDIATE")
    try:
        yield
    except BaseException:
        db.execute("ROLLBACK")
        raise
    db.execute("COMMIT")
