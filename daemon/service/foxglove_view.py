"""The live view in Foxglove (design §11): the Foxglove SDK's WebSocket server, one JSON
channel per topic of the live scene under the schemas recordings use. Open
``ws://<listen>`` in Foxglove with ``config/foxglove-layout.json``."""

from __future__ import annotations

import json
import time
from typing import Any

import foxglove

from daemon.config import FoxgloveSettings
from kernel.errors import ConfigError
from kernel.message_schemas import SCHEMAS


class FoxgloveView:
    """A live-scene sink: the WebSocket server and its channels."""

    def __init__(self, settings: FoxgloveSettings, robot: str,
                 topics: dict[str, str]) -> None:
        host, port = settings.host_port()
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(name=f"placecell {robot}", host=host,
                                                 port=port, context=self._context)
        except Exception as e:  # the SDK's own error for a port in use or a bad host
            raise ConfigError(f"[foxglove] listen {settings.listen!r}: cannot start the "
                              f"server: {e}") from e
        self._channels = {
            topic: foxglove.Channel(topic, schema=foxglove.Schema(
                name=schema, encoding="jsonschema", data=json.dumps(SCHEMAS[schema]).encode()),
                message_encoding="json", context=self._context)
            for topic, schema in topics.items()}
        # Foxglove orders live messages by log time since the UNIX epoch.
        self._epoch_offset_ns = time.time_ns() - time.monotonic_ns()

    @property
    def port(self) -> int:
        return int(self._server.port)

    def write_message(self, topic: str, schema: str, stamp_ns: int,
                      body: dict[str, Any]) -> None:
        self._channels[topic].log(body, log_time=stamp_ns + self._epoch_offset_ns)

    def close(self) -> None:
        self._server.stop()
