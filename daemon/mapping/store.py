"""The map store: one SQLite file (SPEC §6).

WAL journal, a schema version, and the checksum of the panorama geometry the map was made
with: a map made with another unwarping is refused rather than silently misused. A file
that is not a placecell map is refused without being touched.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path

from daemon.errors import MapStoreError

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS places (
    id             INTEGER PRIMARY KEY,
    label          TEXT NOT NULL DEFAULT '',
    created_unix_s REAL NOT NULL,
    background_lrp REAL,
    data           BLOB NOT NULL        -- landmark set, reference panorama, profile (npz)
);
CREATE TABLE IF NOT EXISTS transitions (
    from_id INTEGER NOT NULL REFERENCES places(id),
    to_id   INTEGER NOT NULL REFERENCES places(id),
    x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL,   -- to's frame in from's frame
    covariance BLOB NOT NULL,                             -- 3x3 float64
    PRIMARY KEY (from_id, to_id)
);
"""


class MapStore:
    """An open map file. Use :meth:`open`; close with :meth:`close` (or as a context)."""

    def __init__(self, connection: sqlite3.Connection, path: Path) -> None:
        self._db = connection
        self.path = path

    @classmethod
    def open(cls, path: str | Path, geometry_checksum: str) -> MapStore:
        p = Path(path)
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise MapStoreError(f"cannot create the map directory {p.parent}: {e}") from e
        existed = p.exists() and p.stat().st_size > 0
        try:
            db = sqlite3.connect(p, check_same_thread=False, isolation_level=None)
            if existed:
                _check_existing(db, p, geometry_checksum)
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA foreign_keys=ON")
            if not existed:
                with _transaction(db):
                    for statement in _SCHEMA.split(";"):
                        if statement.strip():
                            db.execute(statement)
                    db.executemany("INSERT INTO meta(key, value) VALUES (?, ?)", [
                        ("schema_version", str(SCHEMA_VERSION)),
                        ("geometry_checksum", geometry_checksum),
                        ("created_unix_s", repr(time.time())),
                    ])
                log.info("created map %s", p)
        except sqlite3.DatabaseError as e:
            raise MapStoreError(f"{p} is not a placecell map (SQLite says: {e})") from e
        return cls(db, p)

    def place_count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM places").fetchone()[0])

    def transition_count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM transitions").fetchone()[0])

    def meta(self, key: str) -> str | None:
        row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> MapStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


def _check_existing(db: sqlite3.Connection, p: Path, geometry_checksum: str) -> None:
    try:
        rows = dict(db.execute("SELECT key, value FROM meta").fetchall())
    except sqlite3.DatabaseError as e:
        raise MapStoreError(f"{p} is not a placecell map ({e})") from e
    version = rows.get("schema_version")
    if version != str(SCHEMA_VERSION):
        raise MapStoreError(
            f"{p} has map schema version {version}, this placecell reads version "
            f"{SCHEMA_VERSION}; the file was left untouched")
    stored = rows.get("geometry_checksum")
    if stored != geometry_checksum:
        raise MapStoreError(
            f"{p} was made with another panorama geometry (checksum {stored}, configured "
            f"{geometry_checksum}): check [mirror] and [panorama], or set map.path to a new "
            "file; the map was left untouched")
