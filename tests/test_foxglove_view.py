"""The live view (design §11): the daemon's Foxglove WebSocket server, seen from a client
that speaks the Foxglove protocol (``foxglove.sdk.v1``): every channel advertised under
the recordings' schemas, and messages on each once subscribed."""

from __future__ import annotations

import base64
import json
import math
import struct
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from websockets.sync.client import ClientConnection, connect

from daemon.config import from_dict
from daemon.service import scene
from daemon.service.live_view import TOPICS
from kernel.errors import ConfigError
from kernel.message_schemas import SCHEMAS
from kernel.se2 import SE2
from tests.conftest import OfficeMap
from tests.daemon_harness import free_port, running_daemon, write_config


def test_particles_are_composed_into_the_map_frame() -> None:
    place = SE2(2.0, 1.0, math.pi / 2)
    particles = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.5], [0.5, 0.5, 0.1]])
    body = scene.particles_in_frame(5, place, particles, at_most=2)
    assert body["frame_id"] == "map" and len(body["poses"]) == 2  # every 2nd of 3
    first = body["poses"][0]
    assert (first["position"]["x"], first["position"]["y"]) == pytest.approx((2.0, 2.0))
    second = body["poses"][1]  # (0.5, 0.5) turned by 90 deg, from (2, 1)
    assert (second["position"]["x"], second["position"]["y"]) == pytest.approx((1.5, 1.5))
    q = second["orientation"]
    assert 2 * math.atan2(q["z"], q["w"]) == pytest.approx(math.pi / 2 + 0.1)


def test_the_map_scene_draws_each_place_and_link() -> None:
    places = {1: (SE2(0.0, 0.0, 0.0), "dock"), 2: (SE2(3.0, 0.0, 0.0), "door")}
    body = scene.map_scene(7, places, [(1, 2), (2, 9)])  # 9: not embedded yet
    ids = [e["id"] for e in body["entities"]]
    assert ids == ["place-1", "place-2", "transitions"]
    assert body["entities"][0]["texts"][0]["text"] == "1 dock"
    points = body["entities"][2]["lines"][0]["points"]
    assert [(p["x"], p["y"]) for p in points] == [(0.0, 0.0), (3.0, 0.0)]


def test_the_panorama_is_a_jpeg_at_most_the_width_asked() -> None:
    pano = np.random.default_rng(1).integers(0, 255, (120, 1440, 3), dtype=np.uint8)
    body = scene.panorama_image(3, pano, 720)
    image = cv2.imdecode(np.frombuffer(base64.b64decode(body["data"]), np.uint8),
                         cv2.IMREAD_COLOR)
    assert body["format"] == "jpeg" and image.shape == (60, 720, 3)


@pytest.mark.parametrize("listen", ["8765", "127.0.0.1", "127.0.0.1:0", "host:99999", ":80"])
def test_a_bad_listen_address_is_refused_by_name(listen: str) -> None:
    with pytest.raises(ConfigError, match="foxglove.listen"):
        from_dict({"foxglove": {"listen": listen}})


def _connect(port: int, limit_s: float = 40.0) -> ClientConnection:
    end = time.monotonic() + limit_s
    while True:
        try:
            return connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"],
                           open_timeout=2)
        except OSError:
            assert time.monotonic() < end, "the Foxglove server never came up"
            time.sleep(0.3)


def _listening_addresses(port: int) -> set[str]:
    """Local addresses of the TCP sockets listening on ``port`` (``/proc/net/tcp``)."""
    out = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            address, port_hex = local.split(":")
            if state == "0A" and int(port_hex, 16) == port:
                out.add(address)
    return out


def test_a_foxglove_client_sees_every_channel_and_its_messages(
        tmp_path: Path, office_map: OfficeMap) -> None:
    office_map(tmp_path / "map.db")
    port = free_port()
    config, _ = write_config(tmp_path, {
        "robot": {"name": "viewbot"}, "mapping": {"mode": "localisation"},
        "sim": {"start_pose": [4.75, 10.15, 0.4]},
        "foxglove": {"enabled": True, "listen": f"127.0.0.1:{port}"}})
    with running_daemon(config):
        with _connect(port) as ws:
            info = json.loads(ws.recv(timeout=10))
            assert info["op"] == "serverInfo" and "placecell viewbot" in info["name"]
            channels: dict[int, dict[str, Any]] = {}
            while len(channels) < len(TOPICS):
                message = json.loads(ws.recv(timeout=10))
                if message["op"] == "advertise":
                    channels |= {c["id"]: c for c in message["channels"]}
            # Every channel, each under the schema recordings use.
            assert {c["topic"]: c["schemaName"] for c in channels.values()} == TOPICS
            for c in channels.values():
                assert c["encoding"] == "json" and c["schemaEncoding"] == "jsonschema"
                assert json.loads(c["schema"]) == SCHEMAS[c["schemaName"]]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 100 + cid, "channelId": cid} for cid in channels]}))
            received: dict[str, list[dict[str, Any]]] = {t: [] for t in TOPICS}
            end = time.monotonic() + 60
            while any(not v for v in received.values()) and time.monotonic() < end:
                data = ws.recv(timeout=10)
                if isinstance(data, str):
                    continue  # more control messages
                assert data[0] == 0x01  # message data: op, subscription, log time, payload
                subscription, _ = struct.unpack_from("<IQ", data, 1)
                topic = channels[subscription - 100]["topic"]
                received[topic].append(json.loads(data[13:]))
            assert all(received.values()), {t: len(v) for t, v in received.items()}
        assert _listening_addresses(port) == {"0100007F"}  # 127.0.0.1 only
    pose = received["/placecell/pose_map"][-1]
    assert pose["frame_id"] == "map" and math.isfinite(pose["pose"]["position"]["x"])
    assert len(received["/placecell/particles"][-1]["poses"]) <= 300
    places = [e for e in received["/placecell/map"][-1]["entities"]
              if e["id"].startswith("place-")]
    assert sorted(e["texts"][0]["text"].split()[1] for e in places) == ["a", "b", "c"]
    image = cv2.imdecode(np.frombuffer(base64.b64decode(
        received["/placecell/panorama"][-1]["data"]), np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape[1] <= 720
    assert received["/placecell/belief"][-1]["state"] in (
        "uninitialised", "tracking", "lost", "relocalising")


def test_the_shipped_layout_shows_the_live_topics_and_nothing_else() -> None:
    layout = json.loads((Path(__file__).resolve().parent.parent / "config"
                         / "foxglove-layout.json").read_text())

    def panels(node: Any) -> list[str]:
        return [node] if isinstance(node, str) else panels(node["first"]) + panels(
            node["second"])

    shown = panels(layout["layout"])
    assert sorted(shown) == sorted(layout["configById"])
    panel = layout["configById"]
    topics = set(panel["3D!map"]["topics"]) | {panel["Image!panorama"]["imageMode"][
        "imageTopic"], panel["RawMessages!belief"]["topicPath"]} | {
        p["value"].split(".")[0] for p in panel["Plot!confidence"]["paths"]}
    assert topics == set(TOPICS)
