"""The SQLite map store: created with schema and geometry; bad files refused untouched."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from daemon.store.sqlite_store import SCHEMA_VERSION, MapStore
from kernel.errors import MapStoreError
from kernel.panorama import geometry_checksum
from kernel.sensor_settings import MirrorSettings, PanoramaSettings


def test_new_map_has_schema_wal_and_geometry(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "map.db"
    with MapStore.open(path, "abc123") as store:
        assert store.place_count() == 0 and store.transition_count() == 0
        assert store.meta("schema_version") == str(SCHEMA_VERSION)
        assert store.meta("geometry_checksum") == "abc123"
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    with MapStore.open(path, "abc123") as again:  # reopening the same geometry works
        assert again.meta("geometry_checksum") == "abc123"


def test_other_geometry_is_refused_and_file_untouched(tmp_path: Path) -> None:
    path = tmp_path / "map.db"
    MapStore.open(path, "abc123").close()
    before = path.read_bytes()
    with pytest.raises(MapStoreError, match="another panorama geometry"):
        MapStore.open(path, "fff000")
    assert path.read_bytes() == before


def test_not_a_map_is_refused_untouched(tmp_path: Path) -> None:
    path = tmp_path / "notes.db"
    path.write_bytes(b"these are my notes, not a database" * 10)
    before = path.read_bytes()
    with pytest.raises(MapStoreError, match="is not a placecell map"):
        MapStore.open(path, "abc123")
    assert path.read_bytes() == before


def test_future_schema_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "map.db"
    MapStore.open(path, "abc123").close()
    db = sqlite3.connect(path)
    db.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    with pytest.raises(MapStoreError, match="schema version 99"):
        MapStore.open(path, "abc123")


def test_geometry_checksum_tracks_every_geometry_setting() -> None:
    base = geometry_checksum(MirrorSettings(), PanoramaSettings())
    assert base == geometry_checksum(MirrorSettings(), PanoramaSettings())
    assert base != geometry_checksum(MirrorSettings(center_x_px=321.0), PanoramaSettings())
    assert base != geometry_checksum(MirrorSettings(), PanoramaSettings(width=360))
