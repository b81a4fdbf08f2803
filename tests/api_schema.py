"""The API's JSON Schemas (docs/api/) as a checker for the end-to-end tests: every message
the daemon publishes or replies is validated against the schema its ``schema`` field
names (design §11)."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import zenoh
from jsonschema import Draft202012Validator

API = Path(__file__).resolve().parent.parent / "docs" / "api"


def _load() -> dict[str, Draft202012Validator]:
    out = {}
    for path in sorted(API.glob("*.schema.json")):
        schema = json.loads(path.read_text())
        Draft202012Validator.check_schema(schema)
        out[schema["$id"]] = Draft202012Validator(schema)
    return out


VALIDATORS = _load()


def check(message: dict[str, Any]) -> dict[str, Any]:
    """``message`` if it validates against the schema it names; AssertionError saying
    where it does not."""
    name = message.get("schema")
    assert name in VALIDATORS, f"no schema in docs/api for {name!r}: {message}"
    errors = sorted(VALIDATORS[name].iter_errors(message), key=lambda e: list(e.path))
    assert not errors, f"{name}: " + "; ".join(
        f"{'/'.join(map(str, e.path)) or '(top)'}: {e.message}" for e in errors[:3])
    return message


def check_request(name: str, request: dict[str, Any]) -> list[str]:
    """What the request schema ``name`` (e.g. ``set_pose``) finds wrong with ``request``."""
    return [e.message for e in VALIDATORS[f"placecell.request.{name}"].iter_errors(request)]


class Messages:
    """Every message published under ``placecell/<robot>/`` while open (a subscriber on
    its own session), each checked with :func:`check` on :meth:`check_all`."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self._lock = threading.Lock()
        self.seen: list[tuple[str, dict[str, Any]]] = []
        self._sub = session.declare_subscriber(f"placecell/{robot}/**", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        message = json.loads(sample.payload.to_bytes())
        with self._lock:
            self.seen.append((str(sample.key_expr), message))

    def check_all(self) -> dict[str, int]:
        """How many messages of each key; each validated."""
        with self._lock:
            seen = list(self.seen)
        counts: dict[str, int] = {}
        for key, message in seen:
            check(message)
            leaf = key.split("/", 2)[2]
            counts[leaf] = counts.get(leaf, 0) + 1
        return counts
