"""Who is connected to the robot, and who is refused (docs/security.md).

zenoh's access control enforces the rules (config/zenoh/robot.json5): only the robot puts,
replies and holds liveliness on its keys, watchers read, operators command. It drops what
the rules refuse without telling the application (its drop counters need the ``stats``
feature, which the eclipse-zenoh wheel is built without). What the daemon can see is each
link and the certificate name it authenticated with; this module names the roles that
name has in the rules, logs every connection with them, and counts the peers that have
none: every message from such a peer is refused.
"""

from __future__ import annotations

import json
import logging
import threading
from collections import Counter
from typing import Any

import zenoh

from kernel.errors import ConfigError

log = logging.getLogger(__name__)

# Link protocols that carry a certificate name zenoh's ACL can match.
_CERTIFIED = ("tls/", "quic/")


def acl_of(conf: zenoh.Config) -> dict[str, Any] | None:
    """The access-control section of a zenoh configuration, None when it is off."""
    acl = json.loads(conf.get_json("access_control"))
    return acl if isinstance(acl, dict) and acl.get("enabled") else None


def roles_by_name(acl: dict[str, Any]) -> dict[str, frozenset[str]]:
    """Certificate common name -> the ACL subjects (roles) it belongs to."""
    roles: dict[str, set[str]] = {}
    for subject in acl.get("subjects") or []:
        for name in subject.get("cert_common_names") or []:
            roles.setdefault(name, set()).add(str(subject.get("id")))
    return {name: frozenset(ids) for name, ids in roles.items()}


def check_endpoints(acl: dict[str, Any], endpoints: list[str]) -> None:
    """Rules that name peers by certificate need links that carry one: a tcp/ endpoint
    beside them would connect peers that match no rule and hear nothing (a ConfigError
    now, not a silent robot)."""
    if not roles_by_name(acl):
        return
    plain = [e for e in endpoints if not e.startswith(_CERTIFIED)]
    if plain:
        raise ConfigError(
            f"[zenoh] the access control names peers by their certificates, but "
            f"{', '.join(plain)} carries none: use tls/ endpoints (docs/security.md)")


class AccessWatch:
    """Counts the robot's peers by role as their links open (zenoh's link events)."""

    def __init__(self, acl: dict[str, Any]) -> None:
        self._roles = roles_by_name(acl)
        self._lock = threading.Lock()
        self._connected: Counter[str] = Counter()
        self._refused = 0
        self._last_refused = ""

    def on_link(self, event: Any) -> None:
        """A link opened (``SampleKind.PUT``) or closed; only openings are counted."""
        if event.kind != zenoh.SampleKind.PUT:
            return
        link = event.link
        name = link.auth_identifier
        roles = self._roles.get(name or "", frozenset())
        with self._lock:
            if roles:
                for role in roles:
                    self._connected[role] += 1
            else:
                self._refused += 1
                self._last_refused = name or f"(no certificate, {link.src})"
        if roles:
            log.info("peer %s connected as %r: %s", link.zid, name, ", ".join(sorted(roles)))
        else:
            log.warning("peer %s connected as %r, which has no role in the access control: "
                        "everything it sends is refused", link.zid, name)

    def summary(self) -> dict[str, Any]:
        with self._lock:
            return {"enabled": True, "links_by_role": dict(sorted(self._connected.items())),
                    "refused_links": self._refused, "last_refused": self._last_refused}


def disabled_summary() -> dict[str, Any]:
    return {"enabled": False, "links_by_role": {}, "refused_links": 0, "last_refused": ""}
