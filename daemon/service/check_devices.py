"""``placecelld --check-devices``: open each configured device, read a little, report.

For commissioning on the robot: every line starts with ``OK`` or ``FAIL`` and says what
was found (image size and rate, odometry rate and counters) or what went wrong.
"""

from __future__ import annotations

import time
from typing import Any

from hal.registry import HalContext, create_base, create_camera
from kernel.errors import PlacecellError

FRAMES = 10
SECONDS = 2.0


def _check_camera(config: Any, context: HalContext) -> list[str]:
    name = f"camera ({config.camera.backend})"
    try:
        camera = create_camera(config.camera, context)
        camera.open()
    except PlacecellError as e:
        return [f"FAIL {name}: cannot open: {e}"]
    try:
        t0 = time.monotonic()
        frames = [camera.read(config.camera.read_timeout_s) for _ in range(FRAMES)]
        elapsed = time.monotonic() - t0
        shape = frames[-1].image.shape
        span_s = (frames[-1].stamp_ns - frames[0].stamp_ns) / 1e9
        rate = (len(frames) - 1) / span_s if span_s > 0 else float("nan")
        info = camera.info
        return [f"OK   {name}: {info.device}: {len(frames)} frames of {shape[1]} x {shape[0]}"
                f"{' x ' + str(shape[2]) if len(shape) == 3 else ''} in {elapsed:.2f} s, "
                f"{rate:.1f} frames/s by stamps, seq {frames[0].seq}..{frames[-1].seq}, "
                f"stats {dict(camera.stats())}"]
    except PlacecellError as e:
        return [f"FAIL {name}: opened but reading failed: {e}"]
    finally:
        camera.close()


def _check_base(config: Any, context: HalContext) -> list[str]:
    name = f"base ({config.base.backend})"
    try:
        base = create_base(config.base, context)
        base.open()
    except PlacecellError as e:
        return [f"FAIL {name}: cannot open: {e}"]
    try:
        samples = []
        end = time.monotonic() + SECONDS
        while time.monotonic() < end:
            samples += base.read(config.base.read_timeout_s)
        span_s = (samples[-1].stamp_ns - samples[0].stamp_ns) / 1e9
        rate = (len(samples) - 1) / span_s if span_s > 0 else float("nan")
        last = samples[-1]
        info = base.info
        return [f"OK   {name}: {info.device}: {len(samples)} odometry samples, {rate:.1f} Hz, "
                f"last x={last.x:.3f} m y={last.y:.3f} m yaw={last.yaw:.3f} rad, "
                f"status {base.status()}, can move: {info.can_move}, "
                f"stats {dict(base.stats())}"]
    except PlacecellError as e:
        return [f"FAIL {name}: opened but reading failed: {e}"]
    finally:
        base.close()


def check_devices(config: Any) -> list[str]:
    """One report line per device (``OK ...`` or ``FAIL ...``)."""
    context = HalContext(config)
    return _check_camera(config, context) + _check_base(config, context)
