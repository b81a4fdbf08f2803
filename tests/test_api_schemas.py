"""docs/api/ says what the daemon's code does: every schema is valid JSON Schema, each
request schema has exactly the request's fields, and the daemon's strict reader and the
schema agree on good and bad requests."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import pytest

from daemon.service import api
from tests.api_schema import VALIDATORS, check, check_request

REQUESTS: dict[str, type[Any]] = {
    "learn_place": api.LearnRequest, "abort": api.NoParameters,
    "relocalise": api.NoParameters, "set_pose": api.SetPoseRequest,
    "mode": api.ModeRequest, "no_parameters": api.NoParameters}


def test_every_published_message_and_request_has_a_schema() -> None:
    for name in ("pose", "belief", "status", "event", "places", "transitions", "place",
                 "reply"):
        assert f"placecell.{name}/1" in VALIDATORS
    assert {f"placecell.request.{n}" for n in REQUESTS} <= set(VALIDATORS)


@pytest.mark.parametrize("name", sorted(REQUESTS))
def test_a_request_schema_lists_exactly_the_request_fields(name: str) -> None:
    schema = VALIDATORS[f"placecell.request.{name}"].schema
    assert set(schema["properties"]) == {f.name for f in dataclasses.fields(REQUESTS[name])}


@pytest.mark.parametrize(("name", "body", "good"), [
    ("learn_place", {}, True), ("learn_place", {"label": "dock", "extent_m": 0.5}, True),
    ("learn_place", {"label": 5}, False), ("learn_place", {"extent_m": 9}, False),
    ("learn_place", {"lable": "x"}, False), ("learn_place", {"label": "x" * 201}, False),
    ("set_pose", {"place": 1, "x": 0.5, "yaw": -1.0, "sigma_xy": 0.1}, True),
    ("set_pose", {"x": 1}, False), ("set_pose", {"place": 0}, False),
    ("set_pose", {"place": 1, "yaw": 1e9}, False), ("set_pose", {"place": 1, "x": "a"}, False),
    ("mode", {}, True), ("mode", {"mode": "localisation"}, True),
    ("mode", {"mode": "surveying"}, False), ("abort", {"now": True}, False),
    ("relocalise", {}, True), ("no_parameters", {}, True),
    ("no_parameters", {"id": 1}, False),
])
def test_the_daemon_and_the_schema_agree_on_a_request(name: str, body: dict[str, Any],
                                                      good: bool) -> None:
    assert (not check_request(name, body)) is good
    if good:
        api.parse(REQUESTS[name], json.dumps(body).encode(), name)
    else:
        with pytest.raises(api.RequestError):
            api.parse(REQUESTS[name], json.dumps(body).encode(), name)


def test_replies_made_by_the_api_validate_and_a_wrong_one_does_not() -> None:
    for payload in (api.progress(phase="+x", fraction=0.25), api.result(mode="mapping"),
                    api.error(api.ErrorCode.BUSY, "a place is being learned already")):
        check(json.loads(payload))
    with pytest.raises(AssertionError, match="code"):
        check({"schema": "placecell.reply/1", "kind": "error", "code": "oops",
               "message": "x"})
