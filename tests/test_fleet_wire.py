"""The fleet's documents (daemon/store/fleet_wire.py, docs/fleet.md): a place and a transition
come back as they were put; anything else in the key space is refused, saying what."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from daemon.mapping.transition import Transition
from daemon.store.fleet_wire import (
    MAX_DOCUMENT_BYTES,
    FleetDocumentError,
    FleetPlace,
    FleetTransition,
    PlaceName,
    decode_place,
    decode_transition,
    encode_place,
    encode_transition,
    place_key,
    transition_key,
)
from kernel.se2 import SE2, UncertainSE2
from tests.map_fixtures import synthetic_place


def _shared(seed: int = 1) -> FleetPlace:
    rng = np.random.default_rng(seed)
    place = synthetic_place(rng, "door", n=6)
    views = [rng.integers(0, 256, (120, 752), dtype=np.uint8) for _ in range(2)]
    return FleetPlace(PlaceName("robot-a", 12), "geom123", place, views)


def _transition() -> FleetTransition:
    T = UncertainSE2(SE2(1.5, -0.2, 0.3), np.diag([0.01, 0.02, 0.003]))
    return FleetTransition("robot-b", PlaceName("robot-a", 12), PlaceName("robot-b", 3),
                           Transition(12, 3, T, "cycle"))


def test_a_place_comes_back_as_it_was_put() -> None:
    shared = _shared()
    back = decode_place(encode_place(shared))
    assert back.name == PlaceName("robot-a", 12) and back.geometry_checksum == "geom123"
    a, b = shared.place, back.place
    assert b.label == "door" and b.created_unix_s == a.created_unix_s
    assert np.array_equal(b.reference_panorama, a.reference_panorama)
    assert all(np.array_equal(x.template, y.template) and (x.row, x.col) == (y.row, y.col)
               and x.depth == y.depth for x, y in zip(a.landmarks.landmarks,
                                                      b.landmarks.landmarks, strict=True))
    assert len(back.views) == 2 and all(np.array_equal(x, y) for x, y in
                                        zip(back.views, shared.views, strict=True))
    assert place_key("placecell/fleet", back.name) == "placecell/fleet/robot-a/place/12"


def test_a_transition_comes_back_as_it_was_put() -> None:
    shared = _transition()
    back = decode_transition(encode_transition(shared))
    assert (back.robot, back.a, back.b) == (shared.robot, shared.a, shared.b)
    t = back.transition
    assert (t.from_id, t.to_id, t.source) == (12, 3, "cycle")
    assert t.T_from_to.mean.x == 1.5 and np.array_equal(
        t.T_from_to.covariance, shared.transition.T_from_to.covariance)
    assert transition_key("p/f", shared.robot, shared.a, shared.b) == \
        "p/f/robot-b/transition/robot-a/12/robot-b/3"


def _place_doc() -> dict:  # type: ignore[type-arg]
    return json.loads(encode_place(_shared()))  # type: ignore[no-any-return]


def _grey_png() -> str:
    doc = _place_doc()
    return str(doc["views"][0])


@pytest.mark.parametrize(("payload", "message"), [
    (b"\xff\xfe not json", "not JSON"),
    (b"[1, 2]", "not a placecell.fleet-place/1 document"),
    (json.dumps({"format": "placecell.fleet-transition/1"}).encode(),
     "not a placecell.fleet-place/1 document"),
    (b" " * (MAX_DOCUMENT_BYTES + 1), "more than a fleet document's"),
], ids=["bytes", "list", "transition", "oversized"])
def test_what_is_not_a_place_document_is_refused(payload: bytes, message: str) -> None:
    with pytest.raises(FleetDocumentError, match=message):
        decode_place(payload)


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: d.update(robot="a/b"), "not a robot's name"),
    (lambda d: d.update(id=0), "not a place id: 0"),
    (lambda d: d.update(id=True), "not a place id: True"),
    (lambda d: d.update(panorama="@@@"), "malformed"),
    (lambda d: d.update(panorama=base64.b64encode(b"not a png").decode()), "panorama is not"),
    (lambda d: d.update(panorama=_grey_png()), "panorama is not a colour 8-bit PNG"),
    (lambda d: d["views"].append(d["panorama"]), "view 2 is not a grey 8-bit PNG"),
    (lambda d: d["place"].pop("landmarks"), "malformed \\(KeyError: 'landmarks'\\)"),
    (lambda d: d["place"]["landmarks"][0].update(template="AAAA"), "a template has 3 bytes"),
    (lambda d: d.update(geometry_checksum=5), "geometry_checksum is not a string"),
])
def test_a_damaged_place_document_is_refused_naming_what(change, message: str) -> None:  # type: ignore[no-untyped-def]
    doc = _place_doc()
    change(doc)
    with pytest.raises(FleetDocumentError, match=message):
        decode_place(json.dumps(doc).encode())


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: d.update(robot=""), "without the robot that measured it"),
    (lambda d: d["a"].update(id="12"), "not a place id"),
    (lambda d: d.update(b=d["a"]), "names places"),
    (lambda d: d["transition"].update(source="teleport"), "unknown source 'teleport'"),
    (lambda d: d["transition"].update(**{"from": 99}), "but joins 99 -> 3"),
    (lambda d: d["transition"].pop("covariance"), "malformed"),
])
def test_a_damaged_transition_document_is_refused_naming_what(change, message: str  # type: ignore[no-untyped-def]
                                                              ) -> None:
    doc = json.loads(encode_transition(_transition()))
    change(doc)
    with pytest.raises(FleetDocumentError, match=message):
        decode_transition(json.dumps(doc).encode())
