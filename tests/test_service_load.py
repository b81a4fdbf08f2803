"""The service under bad requests and under load (design §11): the daemon in a subprocess
tracking on a learned map with the camera at 30 Hz, clients in other processes, loopback
only, bounded in count and time."""

from __future__ import annotations

import contextlib
import json
import random
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from tests.api_schema import check
from tests.conftest import OfficeMap
from tests.daemon_harness import REPO, client_session, running_daemon, wait_for, write_config

# Held to wall-clock limits: one worker runs these modules one after another (tests/conftest.py).
pytestmark = pytest.mark.xdist_group("realtime")


ROBOT = "load"
CAMERA_HZ = 30.0
FUZZ_CAMERA_HZ = 10.0
REQUESTS_HZ = 100.0  # the bad requests' pace (a flood of them is bounded by the GIL)
QUERYABLES = ["status", "cmd/learn_place", "cmd/abort", "cmd/set_pose", "cmd/relocalise",
              "cmd/mode", "map/places", "map/transitions", "map/place/1",
              "map/place/2/panorama"]


@dataclass
class Daemon:
    proc: subprocess.Popen[str]
    port: int

    def rss_kib(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        raise AssertionError("no VmRSS")

    def status(self, session: zenoh.Session) -> dict[str, Any]:
        replies = [json.loads(r.ok.payload.to_bytes()) for r in session.get(
            f"placecell/{ROBOT}/status", timeout=5.0) if r.ok is not None]
        assert replies, "no status"
        return check(replies[0])


@contextlib.contextmanager
def _tracking_daemon(tmp: Path, office_map: OfficeMap, camera_hz: float
                     ) -> Iterator[Daemon]:
    """Standing near place "b" of a learned map, tracking, in localisation mode."""
    office_map(tmp / "map.db")
    scenario = tmp / "stand.toml"
    scenario.write_text('name = "stand"\nworld = "generate:office:1"\n'
                        "start_pose = [4.6, 10.05, 0.2]\n")
    config, port = write_config(tmp, {"robot": {"name": ROBOT}, "mapping": {
        "mode": "localisation"}, "camera": {"sim": {"rate_hz": camera_hz}},
        "sim": {"scenario": str(scenario)}})
    with running_daemon(config) as proc:
        d = Daemon(proc, port)
        session = client_session(port)
        try:
            def tracking() -> bool:
                try:
                    return d.status(session)["belief"]["state"] == "tracking"
                except AssertionError:
                    return False

            assert wait_for(tracking, 90, 0.5), "the daemon never tracked"
            time.sleep(3.0)  # warmed up: caches, JIT, zenoh buffers
        finally:
            session.close()
        yield d


@pytest.fixture
def fuzzed(tmp_path: Path, office_map: OfficeMap) -> Iterator[Daemon]:
    """At the default camera rate (10 Hz): the machine has room, so the pose rate shows
    what the bad requests cost."""
    with _tracking_daemon(tmp_path, office_map, FUZZ_CAMERA_HZ) as d:
        yield d


@pytest.fixture
def loaded(tmp_path: Path, office_map: OfficeMap) -> Iterator[Daemon]:
    """At 30 Hz: the simulated camera renders on the same two cores as everything else."""
    with _tracking_daemon(tmp_path, office_map, CAMERA_HZ) as d:
        yield d


PER_KEY = 300  # bad requests sent to each queryable, and to keys nobody serves
BIG = "1" + "0" * 400  # a JSON integer past any float
HUGE = "1" + "0" * 5000  # past Python's 4300-digit limit for reading integers
# Numbers no request field accepts: extremes, non-finite literals, underflow to zero
# where zero is out of range, huge integers, an integer where a float is fine but a
# float where an integer is needed.
EXTREMES = {
    "cmd/learn_place": ["extent_m", ["0", "-0.0", "1e-400", "1e309", "-1e309", "NaN",
                                     "Infinity", "-Infinity", BIG, "-" + BIG, HUGE, "2.0001"]],
    "cmd/set_pose": ["sigma_xy", ["0", "1e-400", "1e309", "NaN", "Infinity", BIG, HUGE,
                                  "-1e308", "10.5"]],
}
PLACE_IDS = ["0", "-1", "9223372036854775808", BIG, HUGE, "1.0", "true", "null", '"1"',
             "NaN", "Infinity", "1e3"]
# Keys under the prefix that no queryable serves, or serve nothing, as a misbehaving
# client might ask them: unicode digits, signs, odd suffixes, published keys.
ODD_PLACE_KEYS = ["map/place/\u00b2", "map/place/\u0661", "map/place/\uff11",
                  "map/place/\u0663\u0663", "map/place/+1", "map/place/-1", "map/place/0x1",
                  "map/place/1e3", "map/place/1 ", "map/place/ 1", "map/place/abc",
                  "map/place/99", "map/place/0/panorama", "map/place/1/thumbnail",
                  "map/place/1/panorama/big", "map/place/" + "9" * 5000,
                  "map/place/" + "1" * 30, "map/place/*", "map/place/*/panorama"]
UNSERVED_KEYS = ["pose", "belief", "events", "alive", "cmd", "map", "map/place",
                 "status/now", "cmd/learn_place/now", "cmd/fly", "map/places/1",
                 "nothing/here", "\u00e9t\u00e9", "cmd/abort/x/y/z"]


def _bad_request(rng: random.Random, key: str) -> tuple[str, bytes]:
    """A (key, payload) pair for ``key``, none of them a valid request: random bytes,
    other encodings, truncated and non-object JSON, unknown fields, wrong types and
    ranges, numbers at the extremes, huge and deeply nested payloads; and for the place
    keys, ids that are no place. ``key`` "unserved": a key nobody serves."""
    if key == "unserved":
        return rng.choice(UNSERVED_KEYS), rng.choice([b"", b"{}", b'{"x": 1}'])
    if key.startswith("map/place/") and rng.random() < 0.5:
        return rng.choice(ODD_PLACE_KEYS), rng.choice([b"", b"{}"])
    wrong_fields = {
        "cmd/learn_place": [{"label": 5}, {"extent_m": "far"}, {"extent_m": 50},
                            {"label": "x" * 300}, {"extent_m": None, "label": []}],
        "cmd/set_pose": [{"place": "one"}, {"place": 1, "x": 1e9}, {"x": 0.0},
                         {"place": 1, "sigma_xy": -1}, {"place": 1.5}],
        "cmd/mode": [{"mode": "fly"}, {"mode": 3}, {"mode": ["mapping"]}],
    }
    kinds = ["bytes", "utf16", "truncated", "not_object", "unknown_key", "huge", "nested",
             "extreme"]
    if key in wrong_fields:
        kinds.append("wrong_field")
    kind = rng.choice(kinds)
    if kind == "bytes":
        payload = b"\xff" + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200)))
    elif kind == "utf16":
        payload = json.dumps({"label": "dock"}).encode("utf-16")
    elif kind == "truncated":
        payload = b'{"label": "ab'[: rng.randrange(1, 12)]
    elif kind == "not_object":
        payload = rng.choice([b"[1, 2]", b'"learn"', b"42", b"null", b"true", b"1e999",
                              b"NaN", HUGE.encode()])
    elif kind == "unknown_key":
        payload = json.dumps({f"zz{rng.randrange(1000)}": rng.random()}).encode()
    elif kind == "wrong_field":
        payload = json.dumps(rng.choice(wrong_fields[key])).encode()
    elif kind == "huge":
        payload = b'{"label": "' + b"a" * rng.choice([70_000, 1_000_000]) + b'"}'
    elif kind == "nested":
        payload = b"[" * 50_000
    elif key in EXTREMES:
        field, values = EXTREMES[key]
        place = "" if key != "cmd/set_pose" else '"place": 1, '
        payload = ("{" + place + f'"{field}": {rng.choice(values)}' + "}").encode()
    elif key == "cmd/set_pose" or rng.random() < 0.5:
        payload = ('{"place": ' + rng.choice(PLACE_IDS) + "}").encode()
    else:  # a field no parameterless request has, holding an extreme
        payload = ('{"x": ' + rng.choice([BIG, "1e309", "NaN"]) + "}").encode()
    return key, payload


def test_every_key_answers_bad_requests_with_an_error_while_the_pose_flows(fuzzed: Daemon
                                                                          ) -> None:
    """Issue 32, point 3: 300 bad requests to every queryable and 300 to keys nobody
    serves, each answered once with bad_request (or not_found for a place id the map
    does not hold), never failed; the pose rate kept; memory bounded."""
    daemon = fuzzed
    session = client_session(daemon.port)
    poses: list[float] = []
    session.declare_subscriber(f"placecell/{ROBOT}/pose",
                               lambda s: poses.append(time.monotonic()))
    rng = random.Random(7)
    keys = [k for k in [*QUERYABLES, "unserved"] for _ in range(PER_KEY)]
    rng.shuffle(keys)
    try:
        time.sleep(1.0)
        b0 = time.monotonic()
        time.sleep(4.0)  # the baseline: the pose rate with nobody asking anything
        codes: dict[str, int] = {}
        per_key: dict[str, int] = {}
        frames_before = daemon.status(session)["components"]["camera"]["stats"]["frames"]
        t0 = time.monotonic()
        for i, asked in enumerate(keys):  # at most REQUESTS_HZ a second
            while time.monotonic() < t0 + i / REQUESTS_HZ:
                time.sleep(0.001)
            if i == 300:  # every kind seen: the allocator's high-water mark for a 1 MB
                rss_before = daemon.rss_kib()  # payload is reached; growth from here
            key, payload = _bad_request(rng, asked)
            replies = list(session.get(f"placecell/{ROBOT}/{key}", payload=payload,
                                       timeout=10.0))
            assert len(replies) == 1 and replies[0].ok is not None, (key[:60], payload[:80])
            reply = check(json.loads(replies[0].ok.payload.to_bytes()))
            assert reply["kind"] == "error" and reply["message"], (key[:60], payload[:80],
                                                                   reply)
            assert len(reply["message"]) < 1000, reply["message"][:200]
            codes[reply["code"]] = codes.get(reply["code"], 0) + 1
            per_key[asked] = per_key.get(asked, 0) + 1
        t1 = time.monotonic()
        frames = daemon.status(session)["components"]["camera"]["stats"]["frames"] \
            - frames_before
        time.sleep(1.0)
        rss_after = daemon.rss_kib()
        assert daemon.proc.poll() is None
        st = daemon.status(session)
    finally:
        session.close()
    assert set(codes) <= {"bad_request", "not_found"}, codes
    assert min(per_key.values()) >= PER_KEY and len(per_key) == len(QUERYABLES) + 1
    baseline = sum(b0 <= t < t0 for t in poses) / (t0 - b0)
    rate = sum(t0 <= t <= t1 for t in poses) / (t1 - t0)
    camera_hz = frames / (t1 - t0)  # what the camera delivered meanwhile
    print(f"fuzz: {sum(codes.values())} requests in {t1 - t0:.1f} s {codes}; pose "
          f"{rate:.1f} Hz (baseline {baseline:.1f}, camera {camera_hz:.1f}); RSS "
          f"{rss_before} -> {rss_after} KiB")
    assert rate >= 0.9 * FUZZ_CAMERA_HZ and rate >= 0.9 * camera_hz, (rate, camera_hz,
                                                                       baseline)
    assert rss_after <= 1.10 * rss_before, (rss_before, rss_after)
    assert st["healthy"] and st["belief"]["state"] == "tracking", st["belief"]


@pytest.mark.timeout(240)
def test_twenty_subscribers_and_ten_queries_a_second_for_a_minute(loaded: Daemon) -> None:
    daemon = loaded
    clients = [subprocess.Popen(
        [sys.executable, "-m", "tests.load_clients", "--port", str(daemon.port), "--robot",
         ROBOT, "--sessions", "10", "--duration", "60"], cwd=REPO, stdout=subprocess.PIPE,
        text=True) for _ in range(2)]
    session = client_session(daemon.port)
    try:
        for client in clients:
            assert client.stdout is not None
            assert json.loads(client.stdout.readline())["ready"]  # every session routed
        rss_before = daemon.rss_kib()
        before = daemon.status(session)
        keys = ["status", "map/places", "map/transitions", "cmd/mode", "map/place/2"]
        end = time.monotonic() + 54.0  # inside the clients' 60 s
        asked = 0
        while time.monotonic() < end:
            tick = time.monotonic()
            replies = list(session.get(f"placecell/{ROBOT}/{keys[asked % len(keys)]}",
                                       timeout=5.0))
            assert len(replies) == 1 and replies[0].ok is not None
            assert check(json.loads(replies[0].ok.payload.to_bytes())).get("kind") != "error"
            asked += 1
            time.sleep(max(0.0, 0.1 - (time.monotonic() - tick)))
        after = daemon.status(session)
        rss_after = daemon.rss_kib()
    finally:
        session.close()
    sessions = []
    for client in clients:
        out, _ = client.communicate(timeout=60)
        assert client.returncode == 0
        sessions += json.loads(out.splitlines()[-1])["sessions"]
    assert len(sessions) == 20 and asked >= 500
    frames = (after["components"]["camera"]["stats"]["frames"]
              - before["components"]["camera"]["stats"]["frames"])
    skipped = (after["components"]["processing"]["skipped_frames"]
               - before["components"]["processing"]["skipped_frames"])
    # The simulated camera renders on the same two cores: it delivers what it can (about
    # 26 of the 30 Hz on an idle machine, 19.4 beside two busy loops: 1048 frames in the
    # window); processing must keep 95 % of what it delivers. The floor on the camera
    # only says the load was real: half its rate.
    assert frames >= 0.5 * CAMERA_HZ * 50 and skipped <= 0.05 * frames, (frames, skipped)
    published = sorted({s for got in sessions for s in got["pose"]})
    lo, hi = published[0] + 3_000_000_000, published[-1] - 3_000_000_000
    window = [s for s in published if lo <= s <= hi]
    worst = min(sum(lo <= s <= hi for s in got["pose"]) for got in sessions) / len(window)
    print(f"load: {asked} queries; camera {frames} frames in ~54 s, {skipped} skipped; "
          f"worst subscriber {worst:.3f} of {len(window)} poses; RSS {rss_before} -> "
          f"{rss_after} KiB")
    for got in sessions:
        mine = sum(lo <= s <= hi for s in got["pose"])
        assert mine >= 0.95 * len(window), (mine, len(window))
        assert got["belief"] >= 0.95 * len(got["pose"])
    assert rss_after <= 1.10 * rss_before, (rss_before, rss_after)
