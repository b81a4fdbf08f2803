"""The daemon's zenoh session and key space (SPEC §11).

Keys live under ``placecell/<robot>/``; payloads are JSON objects with a ``schema`` field.
By default the session is a peer listening on 127.0.0.1 only with multicast scouting off,
so nothing leaves the machine unless the configuration says so.
"""

from __future__ import annotations

import json
import logging
from typing import Any

import zenoh

from kernel.errors import ConfigError

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1


def key(robot: str, leaf: str) -> str:
    return f"placecell/{robot}/{leaf}"


def make_config(mode: str, listen: list[str], connect: list[str],
                multicast_scouting: bool) -> zenoh.Config:
    """A zenoh configuration that touches only the endpoints given."""
    conf = zenoh.Config()
    try:
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("listen/endpoints", json.dumps(listen))
        conf.insert_json5("connect/endpoints", json.dumps(connect))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
    except Exception as e:  # zenoh raises its own ZError for bad values
        raise ConfigError(f"[zenoh] invalid setting: {e}") from e
    return conf


def open_session(mode: str, listen: list[str], connect: list[str],
                 multicast_scouting: bool) -> zenoh.Session:
    conf = make_config(mode, listen, connect, multicast_scouting)
    try:
        return zenoh.open(conf)
    except Exception as e:
        raise ConfigError(
            f"[zenoh] cannot open a session (listen={listen}, connect={connect}): {e}"
        ) from e


def encode(schema: str, body: dict[str, Any]) -> bytes:
    """JSON payload with the schema name and version first."""
    return json.dumps({"schema": f"{schema}/{SCHEMA_VERSION}", **body},
                      separators=(",", ":"), allow_nan=False).encode()


def decode(payload: bytes) -> dict[str, Any]:
    obj = json.loads(payload)
    if not isinstance(obj, dict) or "schema" not in obj:
        raise ValueError("not a placecell message (no schema field)")
    return obj
