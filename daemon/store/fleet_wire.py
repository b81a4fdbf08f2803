"""What a robot puts in the fleet's key space (docs/fleet.md), and reading it back.

Every robot writes only under its own name: ``<prefix>/<robot>/place/<id>`` holds a place
it learned (``id``: the place's id in that robot's map, which never changes, so a place is
named across the fleet by the robot that learned it and that id), and
``<prefix>/<robot>/transition/<robot a>/<id a>/<robot b>/<id b>`` a transition it measured
between two places, each named the same way (one of them may be another robot's). The
values are JSON: a place as the map export writes it (daemon/store/export.py), with its
reference panorama and learning views as PNG in base64 and the geometry checksum of the
camera it was seen with (a place of another geometry is of no use to this camera). A
document that is not one of these, or is damaged, raises :class:`FleetDocumentError`
naming what is wrong; nothing of it reaches a map.
"""

from __future__ import annotations

import base64
import binascii
import json
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from daemon.mapping.place import Place
from daemon.mapping.transition import Transition
from daemon.store.export import (
    place_from_json,
    place_json,
    transition_from_json,
    transition_json,
)
from kernel.errors import PlacecellError

PLACE_FORMAT = "placecell.fleet-place/1"
TRANSITION_FORMAT = "placecell.fleet-transition/1"
MAX_DOCUMENT_BYTES = 8 * 1024 * 1024  # a place with its panorama and views is ~0.5 MB


class FleetDocumentError(PlacecellError):
    """A sample in the fleet's key space that is not a placecell fleet document."""


@dataclass(frozen=True)
class PlaceName:
    """A place across the fleet: the robot that learned it and its id in that map."""

    robot: str
    id: int


@dataclass(frozen=True)
class FleetPlace:
    name: PlaceName
    geometry_checksum: str
    place: Place  # with its reference panorama; its id is the one in its robot's map
    views: list[np.ndarray]  # grey learning views (design §5), possibly none


@dataclass(frozen=True)
class FleetTransition:
    robot: str  # the robot that measured it
    a: PlaceName
    b: PlaceName
    transition: Transition  # T_a_b, with the ids of ``a`` and ``b`` in their own maps


def place_key(prefix: str, name: PlaceName) -> str:
    return f"{prefix}/{name.robot}/place/{name.id}"


def transition_key(prefix: str, robot: str, a: PlaceName, b: PlaceName) -> str:
    return f"{prefix}/{robot}/transition/{a.robot}/{a.id}/{b.robot}/{b.id}"


def encode_place(shared: FleetPlace) -> bytes:
    place = shared.place
    if place.reference_panorama is None:
        raise ValueError("a place is shared with its reference panorama")
    return _dump({"format": PLACE_FORMAT, "robot": shared.name.robot, "id": shared.name.id,
                  "geometry_checksum": shared.geometry_checksum, "place": place_json(place),
                  "panorama": _png(place.reference_panorama),
                  "views": [_png(v) for v in shared.views]})


def decode_place(payload: bytes) -> FleetPlace:
    doc = _load(payload, PLACE_FORMAT)
    name = _name(doc)
    try:
        panorama = _image(doc["panorama"], "panorama", colour=True)
        views = [_image(v, f"view {k}", colour=False) for k, v in enumerate(doc["views"])]
        place = place_from_json(doc["place"], panorama)
        checksum = doc["geometry_checksum"]
        if not isinstance(checksum, str):
            raise TypeError("geometry_checksum is not a string")
    except (KeyError, TypeError, ValueError, binascii.Error) as e:
        raise FleetDocumentError(f"place {name.id} of robot {name.robot!r}: malformed "
                                 f"({type(e).__name__}: {e})") from e
    return FleetPlace(name, checksum, place, views)


def encode_transition(shared: FleetTransition) -> bytes:
    return _dump({"format": TRANSITION_FORMAT, "robot": shared.robot,
                  "a": {"robot": shared.a.robot, "id": shared.a.id},
                  "b": {"robot": shared.b.robot, "id": shared.b.id},
                  "transition": transition_json(shared.transition)})


def decode_transition(payload: bytes) -> FleetTransition:
    doc = _load(payload, TRANSITION_FORMAT)
    robot = doc.get("robot")
    if not isinstance(robot, str) or not robot:
        raise FleetDocumentError("a fleet transition without the robot that measured it")
    try:
        a, b = _name(doc["a"]), _name(doc["b"])
        transition = transition_from_json(doc["transition"])
    except (KeyError, TypeError, ValueError) as e:
        raise FleetDocumentError(f"robot {robot!r}'s transition: malformed "
                                 f"({type(e).__name__}: {e})") from e
    if (transition.from_id, transition.to_id) != (a.id, b.id) or a == b:
        raise FleetDocumentError(f"robot {robot!r}'s transition names places {a} and {b} "
                                 f"but joins {transition.from_id} -> {transition.to_id}")
    if transition.source not in ("odometry", "vision", "cycle"):
        raise FleetDocumentError(f"robot {robot!r}'s transition has an unknown source "
                                 f"{transition.source!r}")
    return FleetTransition(robot, a, b, transition)


def _dump(doc: dict[str, Any]) -> bytes:
    return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8")


def _load(payload: bytes, expected: str) -> dict[str, Any]:
    if len(payload) > MAX_DOCUMENT_BYTES:
        raise FleetDocumentError(f"{len(payload)} bytes: more than a fleet document's "
                                 f"{MAX_DOCUMENT_BYTES}")
    try:
        doc = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FleetDocumentError(f"not JSON ({e})") from e
    if not isinstance(doc, dict) or doc.get("format") != expected:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise FleetDocumentError(f"not a {expected} document (format {got!r})")
    return doc


def _name(doc: Any) -> PlaceName:
    """A place's name from ``{"robot": ..., "id": ...}``."""
    if not isinstance(doc, dict):
        raise FleetDocumentError(f"a place's name is not an object: {doc!r}")
    robot, place_id = doc.get("robot"), doc.get("id")
    if not isinstance(robot, str) or not robot or "/" in robot:
        raise FleetDocumentError(f"not a robot's name: {robot!r}")
    if not isinstance(place_id, int) or isinstance(place_id, bool) or place_id < 1:
        raise FleetDocumentError(f"robot {robot!r}: not a place id: {place_id!r}")
    return PlaceName(robot, place_id)


def _png(image: np.ndarray) -> str:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("cannot encode an image as PNG")
    return base64.b64encode(data.tobytes()).decode("ascii")


def _image(text: Any, what: str, colour: bool) -> np.ndarray:
    if not isinstance(text, str):
        raise TypeError(f"{what} is not base64 text")
    raw = np.frombuffer(base64.b64decode(text, validate=True), np.uint8)
    image = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED) if raw.size else None
    if image is None or image.dtype != np.uint8 or (image.ndim == 3) != colour \
            or (colour and image.shape[2] != 3):
        raise ValueError(f"{what} is not a {'colour' if colour else 'grey'} 8-bit PNG")
    return image
