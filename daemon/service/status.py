"""What ``status`` reports (design §11): the daemon's health, rates, belief, map, job and
versions, assembled from what each owner holds. Pure functions of their inputs; the
daemon (daemon/service/app.py) gathers the inputs and answers the query."""

from __future__ import annotations

import platform
from typing import Any

import cv2
import numpy as np

import daemon
from daemon.localisation.belief import Belief
from daemon.service.health import ComponentHealth, processing_state
from daemon.service.learn_job import LearnJob
from daemon.service.supervisor import describe


def zenoh_version() -> str:
    try:
        from importlib.metadata import version
        return version("eclipse-zenoh")
    except Exception:  # noqa: BLE001 - informational only
        return "unknown"


def versions() -> dict[str, str]:
    return {"placecell": daemon.__version__, "python": platform.python_version(),
            "zenoh": zenoh_version(), "opencv": cv2.__version__, "numpy": np.__version__}


def components_and_rates(health: dict[str, ComponentHealth], now_ns: int,
                         min_processed_share: float
                         ) -> tuple[dict[str, dict[str, Any]], dict[str, float]]:
    """Each component's state (``processing`` degraded while it keeps less than
    ``min_processed_share`` of the camera's frames) and the measured rates."""
    components = describe(health, now_ns)
    rates = {"frames_hz": round(health["camera"].rate.rate_hz(now_ns), 2),
             "odometry_hz": round(health["base"].rate.rate_hz(now_ns), 2),
             "processed_hz": round(health["processing"].rate.rate_hz(now_ns), 2)}
    components["processing"]["state"] = processing_state(
        health["processing"].state, rates["processed_hz"], rates["frames_hz"],
        min_processed_share)
    return components, rates


def job_summary(job: LearnJob | None) -> dict[str, Any] | None:
    return None if job is None else {
        "kind": job.kind, "phase": job.progress.phase,
        "fraction": round(job.progress.fraction, 3), "started_by": job.started_by,
        "label": job.label}


def belief_summary(belief: Belief | None, belief_age_ns: int, stale_after_s: float,
                   health: dict[str, ComponentHealth]) -> dict[str, Any]:
    """The belief as status reports it: honest about missing sensors (docs/design.md §11);
    ``belief_age_ns``: since the last belief came."""
    frames_ok = (health["camera"].state == "running" and belief is not None
                 and belief_age_ns < stale_after_s * 1e9)
    odometry_ok = health["base"].state == "running"
    state = "uninitialised" if belief is None else belief.state
    reasons = [] if belief is None else [belief.reason]
    if not frames_ok:
        reasons.insert(0, "no camera frames"
                       + (f" ({health['camera'].last_error})"
                          if health["camera"].last_error else ""))
    if not odometry_ok:
        reasons.insert(0, "no odometry: motion unknown"
                       + (f" ({health['base'].last_error})"
                          if health["base"].last_error else ""))
    return {"state": state, "reason": "; ".join(reasons), "frames_ok": frames_ok,
            "odometry_ok": odometry_ok}
