"""``placecell-eval replay --recording R.mcap --map M.db``: a recording through the
daemon's pipeline, frame by frame (design §1, §10).

The Localiser is built exactly as the daemon's processing component builds it
(daemon/service/pipeline.py: the configuration's ``[localisation]``, every place and
transition of the map, ``initial_place``), and fed every recorded frame after the
odometry up to it, as the daemon replaying the same recording in lock-step does
(``camera.replay.speed = 0``): the poses are the daemon's. ``--poses FILE`` writes them,
one JSON object per frame.

Metrics: ``frames``, ``tracked_frames``, ``place_switches``, ``process_ms_median``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from daemon.config import load
from daemon.service.pipeline import holder_of, make_localiser
from daemon.store.sqlite_store import MapStore
from hal.recording import (
    TOPIC_FRAMES,
    TOPIC_ODOMETRY,
    RecordingReader,
    decode_frame,
    decode_odometry,
)
from hal.replay import ReplayClock
from kernel.errors import PlacecellError
from kernel.panorama import geometry_checksum


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--recording", required=True, help="an MCAP recording")
    p.add_argument("--map", required=True, help="the map file (opened read-only)")
    p.add_argument("--config", help="the daemon's configuration (default: built-in)")
    p.add_argument("--poses", help="write the pose of every frame here (JSON lines)")


def pose_record(stamp_ns: int, belief: Any) -> dict[str, Any]:
    """The comparable part of a belief (as the daemon records it)."""
    return {"stamp_ns": stamp_ns, "state": belief.state, "place_id": belief.place_id,
            "pose_in_place": None if belief.pose_in_place is None
            else list(belief.pose_in_place)}


def run(args: argparse.Namespace) -> dict[str, Any]:
    cfg = load(args.config)
    if not Path(args.map).is_file():
        raise PlacecellError(f"map file {args.map} does not exist")
    with MapStore.open(args.map, geometry_checksum(cfg.projection, cfg.panorama),
                       readonly=True) as store:
        graph = store.load()
    localiser = make_localiser(cfg, holder_of(graph), graph)
    reader = RecordingReader(args.recording)
    frames: list[Any] = []
    odometry: list[Any] = []
    for msg in reader.messages([TOPIC_FRAMES, TOPIC_ODOMETRY]):
        if msg.topic == TOPIC_FRAMES:
            frames.append(msg.body)
        else:
            odometry.append(decode_odometry(msg.body))
    odometry.sort(key=lambda o: o.stamp_ns)
    out: list[dict[str, Any]] = []
    process_s: list[float] = []
    k = 0
    switches = 0
    for body in frames:
        frame = decode_frame(body)
        # The replay base runs up to ReplayClock.LOOKAHEAD_NS past the newest frame; the
        # daemon processes a frame once odometry has reached its stamp.
        start = k
        while k < len(odometry) and odometry[k].stamp_ns <= frame.stamp_ns \
                + ReplayClock.LOOKAHEAD_NS:
            k += 1
        localiser.add_odometry(odometry[start:k])
        t0 = time.perf_counter()
        belief, _ = localiser.process_frame(frame)
        process_s.append(time.perf_counter() - t0)
        switches += belief.switched_from is not None
        out.append(pose_record(frame.stamp_ns, belief))
    if args.poses:
        Path(args.poses).write_text("".join(json.dumps(p) + "\n" for p in out))
    return {
        "world": {"recording": str(args.recording)},
        "config": {"map": str(args.map), "places": len(graph),
                   "initial_place": cfg.localisation.initial_place},
        "metrics": {
            "frames": len(out),
            "tracked_frames": sum(p["state"] == "tracking" for p in out),
            "place_switches": switches,
            "process_ms_median": round(float(np.median(process_s)) * 1e3, 2)
            if process_s else None,
        },
    }
