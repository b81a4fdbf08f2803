"""The JSON schemas of what placecell records (MCAP, design §10) and shows live (Foxglove,
design §11): one table, so a recording opens in the layout the live view uses.

Messages are JSON. Where Foxglove has a well-known type (``foxglove.CompressedImage``,
``foxglove.PoseInFrame``, ``foxglove.PosesInFrame``, ``foxglove.SceneUpdate``) the schema
carries its name and the fields Foxglove reads (its 3-D and image panels render them);
bytes are base64 strings, as Foxglove's JSON encoding has them. Our own types are
``placecell.*``.
"""

from __future__ import annotations

from typing import Any

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"},
                                          "nsec": {"type": "integer"}}}
_VECTOR3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUATERNION = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_POSE = {"type": "object", "properties": {"position": _VECTOR3, "orientation": _QUATERNION}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}}
_SPHERE = {"type": "object", "properties": {"pose": _POSE, "size": _VECTOR3, "color": _COLOR}}
_LINE = {"type": "object", "properties": {
    "type": {"type": "integer", "description": "0 strip, 1 loop, 2 list"},
    "pose": _POSE, "thickness": {"type": "number"}, "scale_invariant": {"type": "boolean"},
    "points": {"type": "array", "items": _VECTOR3}, "color": _COLOR,
    "colors": {"type": "array", "items": _COLOR},
    "indices": {"type": "array", "items": {"type": "integer"}}}}
_TEXT = {"type": "object", "properties": {
    "pose": _POSE, "billboard": {"type": "boolean"}, "font_size": {"type": "number"},
    "scale_invariant": {"type": "boolean"}, "color": _COLOR, "text": {"type": "string"}}}
_ENTITY = {"type": "object", "properties": {
    "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
    "lifetime": _TIME, "frame_locked": {"type": "boolean"},
    "metadata": {"type": "array", "items": {"type": "object"}},
    "arrows": {"type": "array"}, "cubes": {"type": "array"},
    "spheres": {"type": "array", "items": _SPHERE}, "cylinders": {"type": "array"},
    "lines": {"type": "array", "items": _LINE}, "triangles": {"type": "array"},
    "texts": {"type": "array", "items": _TEXT}, "models": {"type": "array"}}}

SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.CompressedImage": {
        "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                       "data": {"type": "string", "contentEncoding": "base64"},
                       "format": {"type": "string"}, "stamp_ns": {"type": "integer"},
                       "seq": {"type": "integer"}},
    },
    "foxglove.PoseInFrame": {
        "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
    },
    "foxglove.PosesInFrame": {
        "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                       "poses": {"type": "array", "items": _POSE}},
    },
    "foxglove.SceneUpdate": {
        "type": "object",
        "properties": {"deletions": {"type": "array"},
                       "entities": {"type": "array", "items": _ENTITY}},
    },
    "placecell.Odometry": {
        "type": "object",
        "properties": {k: {"type": "number"} for k in ("x", "y", "yaw")}
        | {"stamp_ns": {"type": "integer"}, "seq": {"type": "integer"}},
    },
    "placecell.BaseStatus": {
        "type": "object",
        "properties": {"stamp_ns": {"type": "integer"}, "flags": {"type": "integer"}},
    },
    "placecell.Pose2D": {
        "type": "object",
        "properties": {k: {"type": "number"} for k in ("x", "y", "yaw")}
        | {"stamp_ns": {"type": "integer"}},
    },
    "placecell.Json": {"type": "object"},
}
