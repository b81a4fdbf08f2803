"""The one Localiser of a configuration and a map: what the daemon's processing component
runs and what ``placecell-eval replay`` drives over a recording (design §1: one pipeline)."""

from __future__ import annotations

import logging

from daemon.config import PlacecellConfig
from daemon.localisation.localiser import Localiser
from daemon.mapping.graph import TopologicalMap
from daemon.mapping.settings import AcquisitionSettings

log = logging.getLogger(__name__)


def make_localiser(config: PlacecellConfig, graph: TopologicalMap,
                   acquisition: AcquisitionSettings | None = None) -> Localiser:
    """A Localiser knowing every place and transition of ``graph`` (in id order), started
    at ``[localisation] initial_place`` / ``initial_pose`` when one is configured."""
    localiser = Localiser(config.mirror, config.panorama, places=len(graph),
                          acquisition=acquisition, settings=config.localisation,
                          odometry_noise=config.odometry)
    for place in sorted(graph.places, key=lambda p: p.id):
        localiser.know_place(place)
    for transition in graph.transitions:
        localiser.know_transition(transition)
    for pair in graph.features:
        localiser.know_features(pair)
    if graph.floor is not None:
        localiser.know_floor(graph.floor)
    start = config.localisation
    if start.initial_place:  # AMCL's set_initial_pose: track from there at once
        if start.initial_place in graph:
            x, y, yaw = start.initial_pose
            localiser.set_pose(start.initial_place, (x, y, yaw))
        else:
            log.error("localisation.initial_place %d is not in the map: not used",
                      start.initial_place)
    return localiser
