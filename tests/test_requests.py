"""Requests are read strictly (issue 32, point 3): numbers bounded and finite before use,
place ids in keys as ASCII decimal within range; every malformed one a bad_request that
names the field."""

from __future__ import annotations

import pytest

from daemon.service import api
from kernel.settings import MAX_INT


def _refused(cls: type, payload: bytes, field: str) -> str:
    with pytest.raises(api.RequestError) as e:
        api.parse(cls, payload, "req")
    assert e.value.code == api.ErrorCode.BAD_REQUEST
    assert field in str(e.value), str(e.value)
    assert len(str(e.value)) < 300
    return str(e.value)


@pytest.mark.parametrize("number", ["1" + "0" * 400, "-" + "1" * 309, "1e309", "-1e309"])
def test_a_number_past_any_float_is_out_of_range(number: str) -> None:
    message = _refused(api.SetPoseRequest, f'{{"place": 1, "x": {number}}}'.encode(),
                       "req.x")
    assert "out of range" in message or "finite" in message


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_literals_are_refused(literal: str) -> None:
    _refused(api.LearnRequest, f'{{"extent_m": {literal}}}'.encode(), literal)


def test_an_integer_beyond_4300_digits_is_a_bad_request_not_a_crash() -> None:
    _refused(api.SetPoseRequest, b'{"place": ' + b"7" * 5000 + b"}", "req")


def test_an_id_beyond_64_bits_is_out_of_range() -> None:
    message = _refused(api.SetPoseRequest, f'{{"place": {MAX_INT + 1}}}'.encode(),
                       "req.place")
    assert "digits" not in message  # 19 digits are shown as they are
    assert api.parse(api.SetPoseRequest, f'{{"place": {MAX_INT}}}'.encode(),
                     "req").place == MAX_INT


def test_a_tiny_number_that_reads_as_zero_meets_the_range_check() -> None:
    _refused(api.LearnRequest, b'{"extent_m": 1e-400}', "req.extent_m")
    assert api.parse(api.SetPoseRequest, b'{"place": 1, "x": 1e-400}', "req").x == 0.0


@pytest.mark.parametrize("text", ["\u00b2", "\u0661", "\uff11", "+1", "-1", "0", "1.0",
                                  "1e3", " 1", "0x1", "", "9" * 20, str(MAX_INT + 1)])
def test_place_ids_in_keys_are_ascii_decimal_within_range(text: str) -> None:
    with pytest.raises(api.RequestError) as e:
        api.place_id(text, "map/place")
    assert e.value.code == api.ErrorCode.BAD_REQUEST
    assert "map/place" in str(e.value)


@pytest.mark.parametrize(("text", "expected"), [("1", 1), ("42", 42), ("007", 7),
                                                (str(MAX_INT), MAX_INT)])
def test_place_ids_in_keys_read(text: str, expected: int) -> None:
    assert api.place_id(text, "map/place") == expected
