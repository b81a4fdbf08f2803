"""Map export to a folder for inspection, and import back (docs/design.md §6).

A folder holds ``manifest.json`` (format, schema, geometry checksum), ``places.json``
(every place with its landmarks: row, column, bearing, depth, covariance, score, and the
template's bytes in base64 so they come back identical), ``transitions.json`` (both
directions), ``features.json`` (the disambiguating features of look-alike pairs, design
§5: position, scores and template bytes in base64; an export without it imports with
none), ``floor.json`` (the floor model the local space profiles were made with, design
§4; absent when none was learned), and per place ``place-<id>.png`` (the reference
panorama with its landmarks drawn, for people), ``place-<id>-reference.png`` (the
panorama itself, lossless) and ``place-<id>-view-<k>.png`` (its learning views, grey,
design §5; listed in the place's ``views``, absent for a place without them).
"""

from __future__ import annotations

import base64
import json
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from daemon.mapping.place import Place
from daemon.mapping.transition import Transition
from daemon.store.sqlite_store import SCHEMA_VERSION, MapStore
from daemon.vision.disambiguation import Feature, PairFeatures
from daemon.vision.drawing import draw_landmarks
from daemon.vision.floor import BINS, ColourModel, FloorModel
from daemon.vision.landmarks import TEMPLATE, Landmark, LandmarkSet
from kernel.errors import MapStoreError
from kernel.se2 import SE2, UncertainSE2

FORMAT = "placecell.map-export/1"


def export_map(store: MapStore, folder: str | Path) -> int:
    """Write the map to ``folder`` (created; must be empty). Returns the place count."""
    out = Path(folder)
    if out.exists() and any(out.iterdir()):
        raise MapStoreError(f"{out} is not empty: export into a new folder")
    out.mkdir(parents=True, exist_ok=True)
    graph = store.load()
    places = []
    for place in graph.places:
        views = store.views(place.id)
        places.append(_place_json(place) | {
            "views": [f"place-{place.id}-view-{k}.png" for k in range(len(views))]})
        panorama = store.reference_panorama(place.id)
        _write_png(out / f"place-{place.id}.png", draw_landmarks(panorama, place.landmarks))
        _write_png(out / f"place-{place.id}-reference.png", panorama)
        for k, view in enumerate(views):
            _write_png(out / f"place-{place.id}-view-{k}.png", view)
    transitions = [transition_json(t) for t in store.transitions()]
    features = [_pair_json(pair) for pair in store.features()]
    _write_json(out / "places.json", places)
    _write_json(out / "transitions.json", transitions)
    _write_json(out / "features.json", features)
    floor = store.floor()
    if floor is not None:
        _write_json(out / "floor.json", _floor_json(floor))
    _write_json(out / "manifest.json", {
        "format": FORMAT, "schema_version": SCHEMA_VERSION,
        "geometry_checksum": store.meta("geometry_checksum"),
        "places": len(places), "transitions": len(transitions), "features": len(features)})
    return len(places)


def import_map(folder: str | Path, path: str | Path) -> int:
    """Build a new map file at ``path`` from an exported folder; refuses to overwrite.
    Place ids are kept. Returns the place count."""
    src, dst = Path(folder), Path(path)
    if dst.exists():
        raise MapStoreError(f"{dst} exists: import into a new file (nothing was changed)")
    manifest = _read_json(src / "manifest.json")
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise MapStoreError(f"{src}: not a placecell map export (manifest format "
                            f"{manifest.get('format') if isinstance(manifest, dict) else '?'})")
    places_doc = _read_json(src / "places.json")
    transitions_doc = _read_json(src / "transitions.json")
    features_doc = _read_json(src / "features.json") if (src / "features.json").exists() \
        else []
    try:
        places = [_place_from_json(d, src) for d in places_doc]
        views = {int(d["id"]): [_read_view(src, str(name), d["id"])
                                for name in d.get("views", [])] for d in places_doc}
        transitions = [transition_from_json(d) for d in transitions_doc]
        features = [_pair_from_json(d) for d in features_doc]
        floor = _floor_from_json(_read_json(src / "floor.json")) \
            if (src / "floor.json").exists() else None
    except (KeyError, TypeError, ValueError) as e:
        raise MapStoreError(f"{src}: malformed export ({type(e).__name__}: {e})") from e
    tmp = dst.with_name(dst.name + ".importing")
    for leftover in (tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm")):
        leftover.unlink(missing_ok=True)
    store = MapStore.open(tmp, str(manifest["geometry_checksum"]))
    try:
        with store:
            store.import_places(places, transitions, features)
            for place_id, place_views in views.items():
                if place_views:
                    store.put_views(place_id, place_views)
            if floor is not None:
                store.save_floor(floor, time.time())
        os.replace(tmp, dst)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return len(places)


def _place_json(place: Place) -> dict[str, Any]:
    return {
        "id": place.id, "label": place.label, "created_unix_s": place.created_unix_s,
        "background_lrp": place.background_lrp,
        "background_estimate": place.background_estimate,
        "background_cross": place.background_cross,
        "signature": None if place.signature is None else place.signature.tolist(),
        "local_space": None if place.local_space is None else place.local_space.tolist(),
        "width": place.landmarks.width, "margin": place.landmarks.margin,
        "panorama": f"place-{place.id}-reference.png",
        "landmarks": [{
            "row": lm.row, "col": lm.col, "bearing": lm.bearing,
            "depth": None if not np.isfinite(lm.depth) else lm.depth,
            "covariance": lm.covariance.tolist() if np.all(np.isfinite(lm.covariance))
            else None,
            "score": lm.score,
            "template": base64.b64encode(np.ascontiguousarray(lm.template, np.uint8).tobytes()
                                         ).decode("ascii"),
        } for lm in place.landmarks.landmarks],
    }


def _place_from_json(d: dict[str, Any], src: Path) -> Place:
    pano = cv2.imread(str(src / str(d["panorama"])), cv2.IMREAD_UNCHANGED)
    if pano is None:
        raise ValueError(f"place {d['id']}: cannot read {d['panorama']}")
    return place_from_json(d, pano)


def place_json(place: Place) -> dict[str, Any]:
    """A place as JSON (its landmarks' templates in base64, so they come back
    identical), without its reference panorama."""
    doc = _place_json(place)
    del doc["panorama"]
    return doc


def place_from_json(d: dict[str, Any], pano: np.ndarray) -> Place:
    """The place of :func:`place_json` with its reference panorama ``pano``; KeyError,
    TypeError or ValueError naming what is wrong."""
    lms = []
    for lm in d["landmarks"]:
        raw = base64.b64decode(lm["template"], validate=True)
        if len(raw) != TEMPLATE * TEMPLATE:
            raise ValueError(f"place {d['id']}: a template has {len(raw)} bytes")
        cov = np.full((2, 2), np.nan) if lm["covariance"] is None else np.array(
            lm["covariance"], dtype=float).reshape(2, 2)
        lms.append(Landmark(np.frombuffer(raw, np.uint8).reshape(TEMPLATE, TEMPLATE).copy(),
                            int(lm["row"]), int(lm["col"]), float(lm["bearing"]),
                            float("nan") if lm["depth"] is None else float(lm["depth"]),
                            cov, float(lm["score"])))
    ls = d.get("local_space")
    return Place(LandmarkSet(tuple(lms), int(d["width"]), int(d["margin"])), pano,
                 label=str(d["label"]), created_unix_s=float(d["created_unix_s"]),
                 background_lrp=None if d["background_lrp"] is None
                 else float(d["background_lrp"]),
                 background_estimate=None if d.get("background_estimate") is None
                 else float(d["background_estimate"]),
                 background_cross=None if d.get("background_cross") is None
                 else float(d["background_cross"]),
                 signature=None if d.get("signature") is None
                 else np.array(d["signature"], dtype=float),
                 local_space=None if ls is None else np.array(ls, dtype=float),
                 id=int(d["id"]))


def transition_json(t: Transition) -> dict[str, Any]:
    m = t.T_from_to.mean
    return {"from": t.from_id, "to": t.to_id, "x": m.x, "y": m.y, "yaw": m.yaw,
            "covariance": t.T_from_to.covariance.tolist(), "source": t.source}


def transition_from_json(d: dict[str, Any]) -> Transition:
    return Transition(int(d["from"]), int(d["to"]),
                      UncertainSE2(SE2(float(d["x"]), float(d["y"]), float(d["yaw"])),
                                   np.array(d["covariance"], dtype=float)),
                      d["source"])


def _feature_json(f: Feature) -> dict[str, Any]:
    return {"col": f.col, "row": f.row, "size": f.size, "own_ncc": f.own_ncc,
            "other_ncc": f.other_ncc,
            "template": base64.b64encode(np.ascontiguousarray(f.template, np.uint8).tobytes()
                                         ).decode("ascii")}


def _pair_json(pair: PairFeatures) -> dict[str, Any]:
    return {"a": pair.a_id, "b": pair.b_id, "feature_a": _feature_json(pair.a),
            "feature_b": _feature_json(pair.b)}


def _feature_from_json(d: dict[str, Any]) -> Feature:
    size = int(d["size"])
    raw = base64.b64decode(d["template"], validate=True)
    if size <= 0 or len(raw) != size * size:
        raise ValueError(f"a feature of size {size} has {len(raw)} template bytes")
    return Feature(int(d["col"]), int(d["row"]),
                   np.frombuffer(raw, np.uint8).reshape(size, size).copy(),
                   float(d["own_ncc"]), float(d["other_ncc"]))


def _pair_from_json(d: dict[str, Any]) -> PairFeatures:
    return PairFeatures(int(d["a"]), int(d["b"]), _feature_from_json(d["feature_a"]),
                        _feature_from_json(d["feature_b"]))


def _floor_json(floor: FloorModel) -> dict[str, Any]:
    histogram = np.ascontiguousarray(floor.colour.histogram, np.uint8)
    return {"gradient_threshold": floor.gradient_threshold,
            "histogram": base64.b64encode(histogram.tobytes()).decode("ascii")}


def _floor_from_json(d: dict[str, Any]) -> FloorModel:
    raw = base64.b64decode(d["histogram"], validate=True)
    if len(raw) != BINS * BINS:
        raise ValueError(f"a floor colour histogram has {BINS * BINS} bytes, got {len(raw)}")
    return FloorModel(ColourModel(np.frombuffer(raw, np.uint8).reshape(BINS, BINS).copy()),
                      float(d["gradient_threshold"]))


def _read_view(src: Path, name: str, place_id: Any) -> np.ndarray:
    view = cv2.imread(str(src / name), cv2.IMREAD_UNCHANGED)
    if view is None or view.ndim != 2 or view.dtype != np.uint8:
        raise ValueError(f"place {place_id}: {name} is not a grey 8-bit image")
    return view


def _write_png(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise MapStoreError(f"cannot write {path}")


def _write_json(path: Path, doc: Any) -> None:
    path.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise MapStoreError(f"cannot read {path}: {e}") from e
