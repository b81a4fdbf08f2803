"""The zenoh requests the daemon answers, as validated dataclasses, and its replies.

Every request payload is a JSON object (empty means all defaults) read by the same strict
reader as the configuration (kernel/settings.py): unknown keys, wrong types and
out-of-range values are refused with a message naming the field. Every reply is a JSON
object with a ``schema`` field and a ``kind``: ``progress`` (long jobs stream these),
``result``, or ``error`` with a stable ``code`` and a message saying why.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Literal, TypeVar

from daemon.service import zenoh_link
from kernel.errors import ConfigError, PlacecellError
from kernel.settings import MAX_INT, build, setting

REPLY_SCHEMA = "placecell.reply"
_DECIMAL = re.compile(r"[0-9]{1,19}")
MAX_REQUEST_BYTES = 64 * 1024


class ErrorCode(StrEnum):
    BAD_REQUEST = "bad_request"  # the request itself is malformed
    BUSY = "busy"  # another job runs
    REFUSED = "refused"  # the daemon cannot do it now (mode, a base that cannot move...)
    ABORTED = "aborted"  # stopped on request; nothing stored
    FAILED = "failed"  # it was tried and went wrong
    NOT_FOUND = "not_found"  # no such place
    NOTHING_TO_ABORT = "nothing_to_abort"


class Reason(StrEnum):
    """Why a request was refused or found busy, stable like the codes: a client maps them
    to its own advice (placecellctl names the command to run)."""

    JOB_RUNNING = "job_running"  # a place is being learned
    LOCALISATION_MODE = "localisation_mode"  # the map is read-only by the mode
    MAP_READONLY = "map_readonly"  # the map file cannot be written
    BASE_NOT_RUNNING = "base_not_running"
    CAMERA_NOT_RUNNING = "camera_not_running"
    BASE_CANNOT_MOVE = "base_cannot_move"
    LOCALISER_NOT_RUNNING = "localiser_not_running"
    EMPTY_MAP = "empty_map"


class RequestError(PlacecellError):
    def __init__(self, code: ErrorCode, message: str, reason: Reason | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.reason = reason


@dataclass(frozen=True)
class LearnRequest:
    label: str = setting("", doc="the place's name for people")
    extent_m: float | None = setting(None, gt=0.0, le=2.0, doc="TBL cross arm; default "
                                     "[tbl] extent_m")

    def __post_init__(self) -> None:
        if len(self.label) > 200:
            raise ValueError("label is at most 200 characters")


@dataclass(frozen=True)
class NoParameters:
    """The queries that take none (cmd/abort, cmd/relocalise, status, map/...): an
    empty payload or ``{}``; anything else is refused, as every request with a key it
    does not know."""


@dataclass(frozen=True)
class SetPoseRequest:
    """cmd/set_pose: start tracking at (x, y, yaw) in a place's frame (design §7)."""

    place: int | None = setting(None, ge=1, doc="the place's id (required)")
    x: float = setting(0.0, ge=-1000.0, le=1000.0, doc="metres, in the place's frame")
    y: float = setting(0.0, ge=-1000.0, le=1000.0)
    yaw: float = setting(0.0, ge=-10.0, le=10.0, doc="radians")
    sigma_xy: float | None = setting(None, gt=0.0, le=10.0, doc="spread of the particles "
                                     "(m); default [localisation] initial_sigma_xy_m")
    sigma_yaw: float | None = setting(None, gt=0.0, le=10.0, doc="radians; default "
                                      "[localisation] initial_sigma_yaw_rad (above 0.2 "
                                      "the orientation is taken from the view)")

    def __post_init__(self) -> None:
        if self.place is None:
            raise ValueError("place is required: the id of the place the pose is in")


@dataclass(frozen=True)
class ModeRequest:
    """cmd/mode: ``mapping`` (places may be learned) or ``localisation`` (the map is
    read-only); empty: only report the mode (design §11)."""

    mode: Literal["", "mapping", "localisation"] = setting(
        "", doc="the mode to switch to; empty: report the current one")


R = TypeVar("R")


def parse(cls: type[R], payload: bytes | None, what: str) -> R:
    """A request of type ``cls`` from a query payload; RequestError(bad_request) if not."""
    raw = payload or b""
    if len(raw) > MAX_REQUEST_BYTES:
        raise RequestError(ErrorCode.BAD_REQUEST, f"{what}: request of {len(raw)} bytes is "
                           f"larger than {MAX_REQUEST_BYTES}")
    if not raw.strip():
        table: Any = {}
    else:
        try:
            table = json.loads(raw.decode("utf-8"), parse_constant=_not_a_number)
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise RequestError(ErrorCode.BAD_REQUEST, f"{what}: not a JSON object ({e})"
                               ) from e
        except ValueError as e:  # NaN, Infinity; an integer over Python's 4300 digits
            raise RequestError(ErrorCode.BAD_REQUEST, f"{what}: {e}") from e
        except RecursionError as e:  # "[[[[..." nested deeper than the parser goes
            raise RequestError(ErrorCode.BAD_REQUEST, f"{what}: JSON nested too deeply"
                               ) from e
    if not isinstance(table, dict):
        raise RequestError(ErrorCode.BAD_REQUEST, f"{what}: expected a JSON object, got "
                           f"{type(table).__name__}")
    try:
        return build(cls, table, what)
    except ConfigError as e:
        raise RequestError(ErrorCode.BAD_REQUEST, str(e)) from e


def _not_a_number(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows: every number must be finite")


def place_id(text: str, what: str) -> int:
    """A place id written in a key (``map/place/<id>``): ASCII decimal digits for a
    positive integer the map can hold; RequestError(bad_request) naming it otherwise
    (``str.isdigit`` would take '²' and '١')."""
    if not _DECIMAL.fullmatch(text) or not 1 <= int(text) <= MAX_INT:
        shown = text if len(text) <= 40 else text[:37] + "..."
        raise RequestError(ErrorCode.BAD_REQUEST, f"{what}: {shown!r} is not a place id "
                           f"(a decimal number from 1 to {MAX_INT})")
    return int(text)


def progress(**fields: Any) -> bytes:
    return zenoh_link.encode(REPLY_SCHEMA, {"kind": "progress", **fields})


def result(**fields: Any) -> bytes:
    return zenoh_link.encode(REPLY_SCHEMA, {"kind": "result", **fields})


def error_fields(code: ErrorCode, message: str, reason: Reason | None = None
                 ) -> dict[str, str]:
    """An error reply's fields after its ``kind``: the code, the message, the reason."""
    fields = {"code": str(code), "message": message}
    if reason is not None:
        fields["reason"] = str(reason)
    return fields


def error(code: ErrorCode, message: str, reason: Reason | None = None) -> bytes:
    return zenoh_link.encode(REPLY_SCHEMA, {"kind": "error",
                                            **error_fields(code, message, reason)})
