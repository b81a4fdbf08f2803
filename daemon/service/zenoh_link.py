"""The daemon's zenoh session and key space (docs/design.md §11).

Keys live under ``placecell/<robot>/``; payloads are JSON objects with a ``schema`` field.
By default the session is a peer listening on 127.0.0.1 only with multicast scouting off,
so nothing leaves the machine unless the configuration says so.
"""

from __future__ import annotations

import hashlib
import json
import logging
from typing import Any

import zenoh
import zenoh.ext

from daemon.service import access
from kernel.errors import ConfigError

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1


def key(robot: str, leaf: str) -> str:
    return f"placecell/{robot}/{leaf}"


# The events kept for late subscribers (``placecellctl events --follow`` shows them first).
EVENTS_KEPT = 32


def robot_zid(robot: str, configured: str = "") -> str:
    """The robot's zenoh id: ``[zenoh] id`` when set, else one derived from its name, so
    that placecellctl, reading the same configuration, knows which node may answer for
    the robot (docs/security.md: replies from any other node are dropped)."""
    # zenoh refuses an id with a leading zero ("Leading 0s are not valid").
    derived = hashlib.sha256(f"placecell/{robot}".encode()).hexdigest()[:32].lstrip("0")
    return configured or derived or "1"


def make_config(mode: str, listen: list[str], connect: list[str],
                multicast_scouting: bool, timestamping: bool = False,
                config_file: str = "", zid: str = "") -> zenoh.Config:
    """A zenoh configuration that touches only the endpoints given; ``timestamping``
    for a session whose publishers keep a cache (the daemon's); ``config_file``: a zenoh
    JSON5 file read first (access control and certificates, docs/security.md); ``zid``:
    the session's zenoh id (the robot's, robot_zid), random when empty."""
    try:
        conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    except Exception as e:  # zenoh's own error for a missing or malformed file
        raise ConfigError(f"[zenoh] config_file {config_file!r}: {e}") from e
    try:
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("listen/endpoints", json.dumps(listen))
        conf.insert_json5("connect/endpoints", json.dumps(connect))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
        if timestamping:
            conf.insert_json5("timestamping/enabled", "true")
        if zid:
            conf.insert_json5("id", json.dumps(zid))
    except Exception as e:  # zenoh raises its own ZError for bad values
        raise ConfigError(f"[zenoh] invalid setting: {e}") from e
    acl = access.acl_of(conf)
    if acl is not None:
        access.check_endpoints(acl, listen + connect)
    return conf


def open_session(mode: str, listen: list[str], connect: list[str],
                 multicast_scouting: bool, timestamping: bool = False,
                 config_file: str = "", zid: str = "") -> zenoh.Session:
    conf = make_config(mode, listen, connect, multicast_scouting, timestamping, config_file,
                       zid)
    return open_configured(conf, listen, connect)


def open_configured(conf: zenoh.Config, listen: list[str], connect: list[str]
                    ) -> zenoh.Session:
    try:
        return zenoh.open(conf)
    except Exception as e:
        raise ConfigError(
            f"[zenoh] cannot open a session (listen={listen}, connect={connect}): {e}"
        ) from e


def declare_event_publisher(session: zenoh.Session, key_expr: str) -> Any:
    """``events`` keeps its last EVENTS_KEPT samples (zenoh-ext's advanced publisher, its
    session timestamping): an operator's ``events --follow`` started after the daemon
    still sees how it localised."""
    return zenoh.ext.declare_advanced_publisher(
        session, key_expr, cache=zenoh.ext.CacheConfig(max_samples=EVENTS_KEPT),
        publisher_detection=True)


def declare_history_subscriber(session: zenoh.Session, key_expr: str,
                               callback: Any) -> Any:
    """A subscriber that first gets what the publishers of ``key_expr`` keep (the
    events), then every new sample."""
    return zenoh.ext.declare_advanced_subscriber(
        session, key_expr, callback,
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True))


def encode(schema: str, body: dict[str, Any]) -> bytes:
    """JSON payload with the schema name and version first."""
    return json.dumps({"schema": f"{schema}/{SCHEMA_VERSION}", **body},
                      separators=(",", ":"), allow_nan=False).encode()


def decode(payload: bytes) -> dict[str, Any]:
    obj = json.loads(payload)
    if not isinstance(obj, dict) or "schema" not in obj:
        raise ValueError("not a placecell message (no schema field)")
    return obj
