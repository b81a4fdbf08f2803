"""Opening the map file for the daemon: its fitness for the configured mode is checked at
start, so a map that cannot be written is said up front, not at the first place learned
(design §11, "Map file")."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from daemon.config import PlacecellConfig
from daemon.store.sqlite_store import MapStore
from kernel.errors import MapNotWritableError, MapStoreError
from kernel.panorama import geometry_checksum

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OpenedMap:
    store: MapStore
    # Why the map is open read-only (None: writable). Then nothing is learned or saved.
    readonly_reason: str | None


def open_map(config: PlacecellConfig) -> OpenedMap:
    """The map at ``[map] path``, writable when it can be. A file that cannot be written
    is opened read-only in localisation mode (the map is read-only there anyway; only the
    pose is not saved for the next start), and in mapping mode only where
    ``[map] if_unwritable = "localisation"``; otherwise MapStoreError, naming the file
    and what to do. Bad files (a directory, an empty file, damage, another geometry)
    raise MapStoreError whatever the mode, the file left as it was."""
    geometry = geometry_checksum(config.projection, config.panorama)
    path = config.map.path
    try:
        return OpenedMap(MapStore.open(path, geometry), None)
    except MapNotWritableError as e:
        if config.mapping.mode == "mapping" and config.map.if_unwritable == "refuse":
            raise MapStoreError(f"{e}. Mapping mode writes every place learned to it: make "
                                "it writable, or set [mapping] mode = \"localisation\" (or "
                                "[map] if_unwritable = \"localisation\") to localise on it "
                                "read-only") from e
        reason = f"the map file cannot be written ({e})"
    store = MapStore.open(path, geometry, readonly=True)
    log.warning("%s: opened read-only in localisation mode; no place is learned and the "
                "pose is not saved for the next start", reason)
    return OpenedMap(store, reason)
