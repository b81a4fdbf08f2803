"""The one error hierarchy of placecell (STYLE.md rule 3).

Errors are split by *when* they happen: configuration, device initialisation, device
operation, timeouts. Foreign errors are wrapped with ``raise ... from e``.
"""


class PlacecellError(Exception):
    """Root of every error placecell raises on purpose."""


class ConfigError(PlacecellError):
    """A configuration file or value is invalid; the message names the section and key."""


class HalError(PlacecellError):
    """A device behind the HAL failed."""


class BackendUnavailableError(HalError):
    """A backend was chosen whose optional dependency is not installed."""


class UnknownBackendError(HalError):
    """A backend name that no registry entry matches."""


class DeviceInitError(HalError):
    """A device could not be opened or configured."""


class DeviceIOError(HalError):
    """A device failed while in operation (unplugged, bus-off, garbage...)."""


class DeviceTimeoutError(HalError):
    """A device did not answer or deliver in time."""


class CommandRejectedError(HalError):
    """The base controller refused a command (NAK) or cannot execute it."""


class MapStoreError(PlacecellError):
    """The map file is unreadable, corrupt, or made with another panorama geometry."""


class MapNotWritableError(MapStoreError):
    """The map file is healthy but cannot be written (read-only file or directory)."""


class LearningError(PlacecellError):
    """Place learning (Turn Back and Look) was refused or failed."""


class LearningRefusedError(LearningError):
    """Place learning cannot start here and now (e.g. the base cannot move)."""


class LearningAbortedError(LearningError):
    """Place learning was aborted on request; nothing was stored."""
