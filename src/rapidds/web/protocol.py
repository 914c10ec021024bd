"""What the browser may send, and the gate every message passes.

Every message is one JSON object with a ``type``, a sequence number ``seq`` (strictly increasing
per connection, so a replayed or reordered message is refused) and a small, typed payload:

* ``{"type": "move", "seq": n, "dx": -1|0|1, "dy": -1|0|1}``: the held arrow/WASD keys (y up);
* ``{"type": "target", "seq": n, "x": float, "y": float}``: walk to a point (click or tap), in
  metres inside the map;
* ``{"type": "start", "seq": n, "cycle": c}``: start cycle ``c`` (refused unless it is the
  cycle on screen and not started: a replayed start cannot start another cycle);
* ``{"type": "too_close", "seq": n, "cycle": c}``: the person says the robot is too close now
  (timed by the server's game clock, not the page's, so it is tied to where the robot was);
  refused unless cycle ``c`` is under way;
* ``{"type": "comfort", "seq": n, "cycle": c, "answer": 1..7}``: their agreement with "the robot
  came too close to me" after cycle ``c``; refused unless that cycle is over and the question is
  asked and not yet answered.

Anything else (not JSON, an unknown type or field, a value out of range, more than
:data:`MAX_MESSAGE_BYTES`, a sequence number not above the last one, more than
:data:`MAX_RATE` messages in a second) is refused with a reason; the connection stays open and
the server never raises on it. Nothing from the client names a file, a run or a setting.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from rapidds.settings import error_line

__all__ = [
    "MAX_MESSAGE_BYTES",
    "MAX_RATE",
    "ClientMessage",
    "Comfort",
    "Gate",
    "Move",
    "Refused",
    "Start",
    "Target",
    "TooClose",
]

MAX_MESSAGE_BYTES = 256
MAX_RATE = 240  # messages per second: key changes and clicks, far above what a person makes
_MAP = 1000.0  # coordinates are checked against the world's bounds by the game; this only
# keeps absurd numbers out before that

_Seq = Annotated[int, Field(ge=0, lt=2**53)]
_Unit = Annotated[int, Field(ge=-1, le=1)]  # strict: true and 1.0 are refused


class _Message(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)
    seq: _Seq


class Move(_Message):
    type: Literal["move"]
    dx: _Unit
    dy: _Unit


class Target(_Message):
    type: Literal["target"]
    x: Annotated[float, Field(ge=-_MAP, le=_MAP)]
    y: Annotated[float, Field(ge=-_MAP, le=_MAP)]


class Start(_Message):
    type: Literal["start"]
    cycle: Annotated[int, Field(ge=0, lt=2**31)]


class TooClose(_Message):
    type: Literal["too_close"]
    cycle: Annotated[int, Field(ge=0, lt=2**31)]


class Comfort(_Message):
    type: Literal["comfort"]
    cycle: Annotated[int, Field(ge=0, lt=2**31)]
    answer: Annotated[int, Field(ge=1, le=7)]  # the 7-point agreement scale


Message = Move | Target | Start | TooClose | Comfort
ClientMessage = Annotated[Message, Field(discriminator="type")]
_ADAPTER: TypeAdapter[Message] = TypeAdapter(ClientMessage)


class Refused(Exception):
    """A message the gate refused; ``str(self)`` says why (sent back and logged)."""


class Gate:
    """Validates one connection's messages in order (see the module docstring)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.last_seq = -1
        self.accepted = 0
        self.refused = 0
        self._clock = clock
        self._window_start = self._clock()
        self._window_count = 0

    def check(self, raw: str | bytes) -> Message:
        """The validated message, or :class:`Refused` with the reason."""
        try:
            msg = self._check(raw)
        except Refused:
            self.refused += 1
            raise
        self.accepted += 1
        return msg

    def _check(self, raw: str | bytes) -> Message:
        now = self._clock()
        if now - self._window_start >= 1.0:
            self._window_start, self._window_count = now, 0
        self._window_count += 1
        if self._window_count > MAX_RATE:
            raise Refused(f"more than {MAX_RATE} messages in a second")
        if isinstance(raw, bytes):
            raise Refused("binary messages are not accepted; send JSON text")
        if len(raw.encode("utf-8", "replace")) > MAX_MESSAGE_BYTES:
            raise Refused(f"message longer than {MAX_MESSAGE_BYTES} bytes")
        try:
            msg = _ADAPTER.validate_json(raw)
        except ValidationError as exc:
            raise Refused(error_line(exc, empty="message")) from None
        if msg.seq <= self.last_seq:
            raise Refused(f"seq {msg.seq} is not above the last accepted {self.last_seq}: "
                          "replayed or out of order")
        self.last_seq = msg.seq
        return msg
