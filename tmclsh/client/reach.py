"""Following a module to where it answers after a write that moves it: its address (GP 66),
the host address its replies go to (GP 76), its CAN ids (GP 71, GP 70), its baud rate (GP 65).

The module data says which parameter does what (``reaches`` in the module file). The module
may answer the write itself from where it is now (the simulator and the modules seen answer
``SGP 66, 0, 3`` from address 3), so that answer is taken from either place; once the module
accepted the value, the client talks to it there. Nothing else is in doubt: an answer from the
new address is no late reply and casts no doubt on earlier ones.

A baud rate may take effect at once or at the next start (the manuals do not say): the module
is asked at the old rate first; when it no longer answers there, at the new one; either way
the user is told what holds and what to type.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..base.errors import ChecksumError, TmclTimeoutError, TransportError
from ..tmcl.frames import Control, Reply, Request
from .advice import setting

if TYPE_CHECKING:
    from ..tmcl.modules import Parameter
    from .core import Client

_GET_VERSION = int(Control.GET_VERSION)


def write(client: Client, req: Request, param: Parameter,
          timeout: float | None = None) -> Reply | None:
    """Send ``req``, a write of ``param`` (a parameter whose ``reaches`` says where the module
    answers from now on), taking its answer from the old or the new place; once the module
    accepted it, follow the module there (with a notice)."""
    role = param.reaches
    value = param.reading(req.value)
    accept = {"address": ("_also_from", value), "host_address": ("_also_host", value),
              "reply_id": ("_also_reply_id", value)}.get(role or "")
    if accept is not None:
        setattr(client, accept[0], accept[1])
    try:
        reply = client.request(req, timeout=timeout)
    finally:
        client._also_from = client._also_host = client._also_reply_id = None
    if reply is None or not reply.ok:
        return reply
    if role == "address" and not client.is_can and value != client.address:
        client.address = value
        client._taps.notice(f"the module answers at address {value} now: talking to it there "
                           f"({setting(client, 'address', value, later=True)} next time)")
    elif role == "host_address" and value != client.host_address:
        client.host_address = value
        client._taps.notice(f"the module sends its replies to host address {value} now: listening "
                           f"there ({setting(client, 'host_address', value, later=True)} next time)")
    elif role == "can_id" and client.is_can and value != client.can_id:
        client.can_id = value
        client._taps.notice(f"the module listens on CAN id {value} now: sending there "
                           f"({setting(client, 'can_id', value, later=True)} next time)")
    elif role == "reply_id" and client.is_can and value != client.reply_id:
        client.reply_id = value
        client._taps.notice(f"the module replies on CAN id {value} now: listening there "
                           f"({setting(client, 'reply_id', value, later=True)} next time)")
    elif role == "baud":
        _follow_baud(client, param, value)
    return reply


def _follow_baud(client: Client, param: Parameter, code: int) -> None:
    """After a new baud rate was accepted: where does the module answer now?"""
    t = client.transport
    old = getattr(t, "baudrate", None)
    rate = _rate(param, code)
    if rate is None or old is None or t.kind != "stream" or t.simulated or "://" in t.url:
        return  # no wire rate here (USB CDC, TCP, the simulator): nothing to follow
    if rate == old:
        return
    if _answers(client):
        client._taps.notice(f"the module still answers at {old} baud: it takes {rate} baud at its "
                           f"next start (then: {setting(client, 'baud', rate, later=True)})")
        return
    t.set_baudrate(rate)
    client._lifecycle.forget_stale()
    if _answers(client):
        client._taps.notice(f"the module answers at {rate} baud now: talking to it at that rate "
                           f"({setting(client, 'baud', rate, later=True)} next time)")
        return
    t.set_baudrate(old)
    client._lifecycle.forget_stale()
    client._taps.notice(f"the module answers neither at {old} nor at {rate} baud since the change; "
                       f"try 'tmclsh scan --port {t.url} --baud auto'")


def _rate(param: Parameter, code: int) -> int | None:
    """The baud rate a code of the parameter names (``values``: "115200 baud")."""
    words = param.values.get(code, "").split()
    return int(words[0]) if words and words[0].isdigit() else None


def _answers(client: Client) -> bool:
    try:
        reply = client.request(Request(client.address, _GET_VERSION, 1, 0, 0),
                               timeout=min(client.timeout, 0.3), retries=0)
    except (TmclTimeoutError, ChecksumError, TransportError):
        return False
    return reply is not None
