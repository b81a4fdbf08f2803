"""The one Localiser of a configuration and a map: what the daemon's processing component
runs and what ``placecell-eval replay`` drives over a recording (design §1: one pipeline)."""

from __future__ import annotations

import logging
import math

from daemon.config import PlacecellConfig
from daemon.localisation.known_map import KnownMap, MapHolder
from daemon.localisation.localiser import Localiser
from daemon.mapping.graph import TopologicalMap
from daemon.mapping.settings import AcquisitionSettings
from daemon.store.sqlite_store import SavedPose
from kernel.se2 import SE2

log = logging.getLogger(__name__)

# A resumed pose is spread at least this much: the robot may have been pushed while off.
RESUME_MIN_SIGMA_M = 0.05
RESUME_MIN_SIGMA_RAD = 0.05


def holder_of(graph: TopologicalMap) -> MapHolder:
    """A map nobody changes (a replay, an experiment's fixed map), for the localiser to
    read: every place, transition and look-alike pair of ``graph``."""
    return MapHolder(KnownMap.of(graph.places, graph.transitions, graph.features))


def make_localiser(config: PlacecellConfig, known_map: MapHolder, graph: TopologicalMap,
                   acquisition: AcquisitionSettings | None = None) -> Localiser:
    """A Localiser reading ``known_map`` (whose owner keeps it in step with ``graph``,
    the map as stored), with the floor model stored with the map, started at
    ``[localisation] initial_place`` / ``initial_pose`` when one is configured."""
    localiser = Localiser(config.projection, config.panorama, acquisition=acquisition,
                          settings=config.localisation, odometry_noise=config.odometry,
                          known_map=known_map, mount=config.mount)
    if graph.floor is not None:
        localiser.know_floor(graph.floor)
    start = config.localisation
    if start.initial_place:  # AMCL's set_initial_pose: track from there at once
        if start.initial_place in known_map.current:
            x, y, yaw = start.initial_pose  # the robot's: the method tracks the camera
            localiser.set_pose(start.initial_place,
                               config.mount.camera_pose(SE2(x, y, yaw)).as_tuple())
        else:
            log.error("localisation.initial_place %d is not in the map: not used",
                      start.initial_place)
    return localiser


def resume(localiser: Localiser, saved: SavedPose) -> None:
    """Start from the pose saved at the last stop (design §11), spread at least
    RESUME_MIN_SIGMA: confirmed by the view before it is ``tracking`` again."""
    cov = saved.covariance
    localiser.resume(saved.place_id, saved.pose,
                     max(math.sqrt(max(cov[0, 0], cov[1, 1])), RESUME_MIN_SIGMA_M),
                     max(math.sqrt(cov[2, 2]), RESUME_MIN_SIGMA_RAD))
