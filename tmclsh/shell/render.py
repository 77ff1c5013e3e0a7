"""Replies rendered for people (rich) and for programs (JSON, one object per line).

Rendering does no I/O on the bus: everything it needs is in the Result.
"""

from __future__ import annotations

import json
import os
import sys
from typing import Any

from ..client import Result
from ..modules import Module, Parameter
from ..protocol import Reply, Status, status_text
from .style import rich_theme


def _console(stderr: bool = False):
    from rich.console import Console

    return Console(file=sys.stderr if stderr else sys.stdout, theme=rich_theme(),
                   highlight=False, soft_wrap=True,
                   no_color=bool(os.environ.get("NO_COLOR")) or None)


class Output:
    """Where results go: rich text for people, JSON lines for programs, errors to stderr."""

    def __init__(self, json_mode: bool = False):
        self.json = json_mode
        self.console = _console()
        self.err = _console(stderr=True)

    # -- JSON ---------------------------------------------------------------------------
    def emit(self, obj: dict[str, Any]) -> None:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()

    # -- people -------------------------------------------------------------------------
    def print(self, *items: Any, **kw: Any) -> None:
        if not self.json:
            self.console.print(*items, **kw)

    def info(self, text: str) -> None:
        """A status line for people (stderr under --json, so stdout stays parseable)."""
        if self.json:
            self.err.print(text, style="tmcl.note")
        else:
            self.console.print(text, style="tmcl.note")

    def warn(self, text: str) -> None:
        self.err.print(text, style="tmcl.warn")

    def error(self, line: str | None, message: str) -> None:
        if self.json:
            self.emit({"line": line, "error": message})
        else:
            self.err.print(f"error: {message}", style="tmcl.error", markup=False)

    def result(self, result: Result, module: Module | None) -> None:
        if self.json:
            self.emit(result_json(result))
        else:
            self.console.print(render_result(result, module))


def result_json(result: Result) -> dict[str, Any]:
    ins = result.encoded.instruction
    reply = result.reply
    obj: dict[str, Any] = {"line": result.line, "op": ins.opcode, "type": ins.type,
                           "motor": ins.motor, "value": ins.signed_value,
                           "status": reply.status if reply else None,
                           "reply": reply.value if reply else None}
    if reply is not None and reply.version is not None:
        obj["reply"] = reply.version
    if reply is not None and reply.status not in (Status.OK, Status.LOADED, Status.EVENT):
        obj["error"] = status_text(reply.status)
    return obj


def value_text(value: int, param: Parameter | None) -> str:
    """``1000 pps``, ``8 (256 microsteps)``, ``17 [start up in ASCII mode; ...]``."""
    if param is None:
        return str(value)
    if param.min is not None and param.min >= 0 and value < 0:
        value &= 0xFFFFFFFF  # unsigned 32-bit parameters arrive as negative numbers
    text = f"{value}"
    if param.unit:
        text += f" {param.unit}"
    meaning = param.describe_value(value)
    if meaning:
        text += f" ({meaning})"
    return text


def render_result(result: Result, module: Module | None):
    from rich.text import Text

    reply = result.reply
    enc = result.encoded
    out = Text()
    if reply is None:
        out.append("sent (no reply expected)", style="tmcl.note")
        return out
    if reply.version is not None:
        out.append(reply.version, style="tmcl.value")
        return out
    if not reply.ok:
        out.append(f"error {reply.status}: {status_text(reply.status)}", style="tmcl.error")
        return out
    spec = enc.spec
    param = enc.parameter
    if spec is not None and spec.reads:
        if param is not None:
            out.append(param.name, style="tmcl.name")
            out.append(" = ")
        out.append(value_text(reply.value, param), style="tmcl.value")
        if param is not None and param.bits:
            out.append("\n")
            out.append_text(render_bits(reply.value, param))
        return out
    if spec is None:
        out.append(f"status {reply.status} ({status_text(reply.status)}) value {reply.value}")
        return out
    out.append("ok", style="tmcl.ok")
    if spec.mnemonic == "RFS" and enc.instruction.type == 2:
        out.append(f"  {reply.value} ({'searching' if reply.value else 'not searching'})")
    elif reply.value and spec.mnemonic not in ("SAP", "SGP", "SIO"):
        out.append(f"  value {reply.value}")
    return out


def render_bits(value: int, param: Parameter):
    from rich.text import Text

    text = Text()
    for bit, meaning in sorted(param.bits.items()):
        on = bool(value >> bit & 1)
        text.append(f"  bit {bit:2d} {'1' if on else '0'} {meaning}\n",
                    style="tmcl.bit.on" if on else "tmcl.bit.off")
    text.rstrip()
    return text


def render_event(reply: Reply) -> str:
    motors = [str(m) for m in range(8) if reply.value >> m & 1]
    return f"event: target position reached (motor {', '.join(motors) or reply.value})"
