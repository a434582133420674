"""Joining a Ray cluster (``gridloc bench --address``, ``gridloc sweep --address``): the address
checked before Ray is called (``HOST:PORT`` with a port in 1..65535, or ``auto``; no spaces), a
deadline on finding a Ray head there (:data:`CONNECT_DEADLINE`: a port where nothing listens, or
where something other than a Ray head answers, is one error line, never Ray's retries for
minutes), and whether a joined cluster's head still answers (:func:`answers`).

Ray itself is imported only in :func:`join`, when a run on a cluster starts (the ``sweep`` extra).
"""

from __future__ import annotations

import os
import re
import socket
from typing import Any

#: Seconds within which a Ray head must answer at ``--address`` (a TCP connection, then its gRPC
#: server's first frame).
CONNECT_DEADLINE = 5.0
#: What a host may be: a name or an IPv4 address, or an IPv6 address in brackets.
_HOST = re.compile(r"[A-Za-z0-9]([A-Za-z0-9._-]*[A-Za-z0-9])?|\[[0-9A-Fa-f:.]+\]")
#: The first bytes of an HTTP/2 connection (gRPC, which a Ray head's GCS speaks) and an empty SETTINGS frame.
_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"


class ClusterError(RuntimeError):
    """The cluster could not be joined, or it stopped answering during a run."""


def check_address(address: Any, flag: str = "--address") -> str:
    """``address`` if it is ``auto`` or ``HOST:PORT`` (a host name or address, a port in
    1..65535, no spaces); else a ``ValueError`` naming it and what is allowed."""
    allowed = "give the Ray head's HOST:PORT (a port in 1..65535, e.g. 10.0.0.5:6379), or auto"
    if not isinstance(address, str) or not address.strip():
        raise ValueError(f"{flag} needs a Ray cluster's address: {allowed}")
    if any(ch.isspace() for ch in address):
        raise ValueError(f"{flag} {address!r} holds a space; {allowed}")
    if address == "auto":
        return address
    host, colon, port = address.rpartition(":")
    if not colon or not _HOST.fullmatch(host) or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{flag} {address!r} is not an address; {allowed}")
    return address


def host_port(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of a checked ``HOST:PORT`` address (None for ``auto``)."""
    if address == "auto":
        return None
    host, _, port = address.rpartition(":")
    return host.strip("[]"), int(port)


def answers(address: str, timeout: float | None = None) -> str | None:
    """None if a gRPC server (a Ray head's GCS) answers at ``HOST:PORT`` within ``timeout``
    seconds (default :data:`CONNECT_DEADLINE`), else why not (one phrase).  With ``RAY_USE_TLS``
    set, a TCP connection is enough."""
    timeout = CONNECT_DEADLINE if timeout is None else timeout
    where = host_port(address)
    if where is None:
        return None
    try:
        with socket.create_connection(where, timeout=timeout) as sock:
            if os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true"):
                return None
            sock.settimeout(timeout)
            sock.sendall(_PREFACE)
            head = sock.recv(9)
    except OSError as exc:
        return f"nothing answers there ({exc.strerror or exc})"
    if len(head) < 4 or head[3] != 0x04:  # an HTTP/2 server answers with its SETTINGS frame
        return "something answers there, but not a Ray head (no gRPC server)"
    return None


def join(address: str, **init: Any) -> bool:
    """Join the Ray cluster at ``address`` (checked first: :func:`check_address`, then a Ray head
    must answer within :data:`CONNECT_DEADLINE` seconds) unless Ray is already initialised;
    ``init``: more ``ray.init`` keywords.  Whether this call started the connection (the caller
    then shuts it down).  :class:`ClusterError` in one line when it cannot join."""
    try:
        address = check_address(address)
    except ValueError as exc:
        raise ClusterError(str(exc)) from None
    import ray

    if ray.is_initialized():
        return False
    if (why := answers(address)) is not None:
        raise ClusterError(f"cannot join the Ray cluster at {address}: {why}; start one with `ray start --head` "
                           "or give the head's HOST:PORT")
    try:
        ray.init(address=address, logging_level="WARNING", **init)
    except Exception as exc:  # noqa: BLE001 - Ray raises bare Exception too (e.g. a node that timed out starting)
        hint = (" (a cluster with token authentication needs RAY_AUTH_MODE=token and its token: RAY_AUTH_TOKEN or "
                "~/.ray/auth_token)") if isinstance(exc, ConnectionError) else ""
        raise ClusterError(f"cannot join the Ray cluster at {address}: {' '.join(str(exc).split())}{hint}") from None
    return True


__all__ = ["CONNECT_DEADLINE", "ClusterError", "answers", "check_address", "host_port", "join"]
