"""The map's queryables (design §11): ``map/places``, ``map/transitions`` and
``map/place/<id>[/panorama]``, answered from the map the daemon holds."""

from __future__ import annotations

import cv2
import zenoh

from daemon.service import api, queries, wire, zenoh_link
from daemon.service.mapper import Mapper
from daemon.vision.drawing import draw_landmarks


class MapQueries:
    """Handlers for zenoh queryables (wrap each with ``queries.guarded``)."""

    def __init__(self, robot: str, mapper: Mapper) -> None:
        self._robot = robot
        self._mapper = mapper

    def place(self, query: zenoh.Query) -> None:
        """map/place/<id> (metadata) and map/place/<id>/panorama (PNG, landmarks drawn)."""
        api.parse(api.NoParameters, queries.payload(query), "map/place")
        prefix = zenoh_link.key(self._robot, "map/place/")
        rest = str(query.key_expr).removeprefix(prefix).split("/")
        if len(rest) not in (1, 2) or (len(rest) == 2 and rest[1] != "panorama"):
            raise api.RequestError(api.ErrorCode.BAD_REQUEST,
                                   f"{queries.shorter(query.key_expr)}: ask for "
                                   f"{prefix}<id> or {prefix}<id>/panorama")
        place_id = api.place_id(rest[0], "map/place")
        if not self._mapper.has_place(place_id):
            raise api.RequestError(api.ErrorCode.NOT_FOUND, f"place {place_id} is not in "
                                   f"the map ({self._mapper.place_count()} places)")
        if len(rest) == 2:
            place = self._mapper.place(place_id, panorama=True)
            assert place.reference_panorama is not None
            ok, png = cv2.imencode(".png", draw_landmarks(place.reference_panorama,
                                                         place.landmarks))
            if not ok:
                raise api.RequestError(api.ErrorCode.FAILED, "could not encode the PNG")
            query.reply(query.key_expr, png.tobytes(), encoding=zenoh.Encoding.IMAGE_PNG)
            return
        query.reply(query.key_expr, zenoh_link.encode(
            "placecell.place", wire.place_body(self._mapper.place(place_id),
                                           self._mapper.neighbours(place_id))))

    def places(self, query: zenoh.Query) -> None:
        api.parse(api.NoParameters, queries.payload(query), "map/places")
        places = [{"id": p.id, "label": p.label, "created_unix_s": p.created_unix_s,
                   "landmarks": p.landmark_count, "background_lrp": p.background_lrp}
                  for p in self._mapper.summaries()]
        query.reply(query.key_expr, zenoh_link.encode("placecell.places", {"places": places}))

    def transitions(self, query: zenoh.Query) -> None:
        api.parse(api.NoParameters, queries.payload(query), "map/transitions")
        out = []
        for t in self._mapper.transitions():
            m = t.T_from_to.mean
            out.append({"from": t.from_id, "to": t.to_id, "x": m.x, "y": m.y, "yaw": m.yaw,
                        "covariance": t.T_from_to.covariance.tolist(), "source": t.source})
        query.reply(query.key_expr,
                    zenoh_link.encode("placecell.transitions", {"transitions": out}))
