"""The daemon's messages as JSON bodies (docs/api/): the pose, the belief, a place."""

from __future__ import annotations

import math
from typing import Any

from daemon.localisation.localiser import Belief
from daemon.mapping.place import Place
from daemon.mapping.transition import Transition
from kernel.se2 import SE2


def pose_body(belief: Belief, in_map: SE2 | None, segment: int | None,
               map_segment: int | None) -> dict[str, Any]:
    """``pose`` (design §11): the estimate in the current place's frame, and composed
    into the `map` frame (design §6) when the place is embedded in it; a place in a
    segment not joined to the map frame's (``map_segment``) says so in the reason."""
    pose = belief.pose_in_place
    reason = belief.reason
    if segment is not None and segment != map_segment:
        reason += (f"; in segment {segment}, not joined to the map frame's (segment "
                   f"{map_segment}): the pose is in its place's frame only")
    return {"stamp_ns": belief.stamp_ns, "state": belief.state, "reason": reason,
            "place": None if belief.place_id is None else {
                "id": belief.place_id, "label": belief.place_label,
                "segment": belief.place_id if segment is None else segment},
            "x": None if pose is None else round(pose[0], 5),
            "y": None if pose is None else round(pose[1], 5),
            "yaw": None if pose is None else round(pose[2], 6),
            "covariance": None if belief.covariance is None else [
                float(f"{v:.6g}") for v in belief.covariance],
            "confidence": round(belief.confidence, 4),
            "map": None if in_map is None else {
                "x": round(in_map.x, 5), "y": round(in_map.y, 5), "yaw": round(in_map.yaw, 6)}}


def belief_body(belief: Belief) -> dict[str, Any]:
    return {"stamp_ns": belief.stamp_ns, "state": belief.state, "reason": belief.reason,
            "odometry_ok": belief.odometry_ok, "place_id": belief.place_id,
            "pose_in_place": belief.pose_in_place, "confidence": round(belief.confidence, 4),
            "particles": belief.particles, "switched_from": belief.switched_from,
            "scores": [{"place": sc.place_id, "lrp": round(sc.lrp, 4),
                        "lead": round(sc.lead, 4)} for sc in belief.scores],
            "timings_ms": belief.timings_ms,
            "recent_place": None if belief.recent_place is None else {
                "id": belief.recent_place, "lrp": None if belief.recent_place_lrp is None
                else round(belief.recent_place_lrp, 4)}}


def place_body(place: Place, out: list[Transition]) -> dict[str, Any]:
    """``map/place/<id>``: what the map holds of a place, without the images."""
    def finite(v: float) -> float | None:
        return round(float(v), 6) if math.isfinite(v) else None

    return {"id": place.id, "label": place.label, "created_unix_s": place.created_unix_s,
            "background_lrp": place.background_lrp,
            "background_estimate": place.background_estimate,
            "background_cross": place.background_cross,
            "landmarks": [{"row": lm.row, "col": lm.col, "bearing": round(lm.bearing, 6),
                           "depth_m": finite(lm.depth),
                           "depth_sigma_m": finite(math.sqrt(lm.covariance[0, 0]))
                           if lm.covariance[0, 0] >= 0 else None,
                           "score": round(lm.score, 5)} for lm in place.landmarks.landmarks],
            "transitions": [{"to": t.to_id, "x": round(t.T_from_to.mean.x, 5),
                             "y": round(t.T_from_to.mean.y, 5),
                             "yaw": round(t.T_from_to.mean.yaw, 6), "source": t.source}
                            for t in out]}
