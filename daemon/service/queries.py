"""Answering zenoh queries safely (design §11): the payload of a query, a handler guarded
so nothing a client sends can raise out of it, and the answer for keys nobody serves."""

from __future__ import annotations

import logging
from typing import Any

import zenoh

from daemon.service import api, zenoh_link

log = logging.getLogger(__name__)


def payload(query: zenoh.Query) -> bytes:
    return b"" if query.payload is None else query.payload.to_bytes()


def guarded(leaf: str, handler: Any) -> Any:
    """A queryable callback that answers every failure with an error reply: nothing a
    client sends can raise out of it (design §11)."""
    def answer(query: zenoh.Query) -> None:
        try:
            handler(query)
        except api.RequestError as e:
            try_reply(query, api.error(e.code, str(e), e.reason))
        except Exception as e:  # noqa: BLE001 - a client must never crash the daemon
            log.warning("%s query failed: %s", leaf, e)
            try_reply(query, api.error(api.ErrorCode.FAILED, f"{type(e).__name__}: {e}"))

    return answer


def shorter(key: Any, limit: int = 120) -> str:
    text = str(key)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# Keys the daemon publishes: asked by query, they are answered with where to subscribe.
PUBLISHED = ("pose", "belief", "events", "alive")


def unknown_key(robot: str, answered: list[str]) -> Any:
    """The queryable on ``placecell/<robot>/**``: silent where a query reaches a key that
    another queryable answers (that one replies), a ``bad_request`` naming the key and
    the keys there are otherwise."""
    served = [zenoh.KeyExpr(zenoh_link.key(robot, leaf)) for leaf in answered]
    prefix = zenoh_link.key(robot, "")

    def answer(query: zenoh.Query) -> None:
        if any(k.intersects(query.key_expr) for k in served):
            return
        leaf = str(query.key_expr).removeprefix(prefix)
        hint = (f"{leaf} is published, not answered: subscribe to it"
                if leaf in PUBLISHED else
                f"no such key; the daemon answers {', '.join(answered)} under {prefix}")
        try_reply(query, api.error(api.ErrorCode.BAD_REQUEST,
                                    f"{shorter(query.key_expr)}: {hint}"))

    return answer


def try_reply(query: zenoh.Query, payload: bytes) -> None:
    try:
        query.reply(query.key_expr, payload)
    except Exception as e:  # noqa: BLE001 - the client may have gone
        log.debug("reply failed: %s", e)
