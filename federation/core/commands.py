"""Which execution-control commands an agent acts on: ordering per issuer, free of I/O.

The rules, in the order :meth:`CommandGate.admit` applies them:

1. ``abort`` is always admitted, whatever its issuer, ``seq`` or timestamps: no value
   in a command can stop an abort (the run state makes a repeat harmless). Its seq
   becomes the issuer's last only where rule 4 would let it, so an abort with a wild
   seq cannot make that issuer's later reset and start stale.
2. A ``seq`` outside ``0 <= seq <= MAX_SEQ`` is dropped (``seq out of range``): a
   counter, not a wall clock, and small enough for any JSON reader.
3. Order is per issuer. Each issuer (``fedlab ctl`` makes a new one per invocation:
   host, pid and a random tag) numbers its commands 1, 2, 3...; the same seq again
   is a ``repeat`` (ctl publishes each command three times), a lower one is
   ``stale`` (it arrived after a later one).
4. A seq more than ``max_jump`` above the issuer's last is dropped (``seq jumped``)
   and does not become the issuer's last: one bad value cannot disable an issuer.
   An issuer's first command may have any seq in range.
5. At most ``max_issuers`` issuers are remembered (the least recently heard is
   forgotten), so a flood of forged issuers cannot grow an agent's memory.

Nothing here reads a clock: commands from two operators whose machines disagree
by minutes are ordered exactly as well as from one.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal

__all__ = ["MAX_JUMP", "MAX_SEQ", "CommandGate", "Verdict"]

MAX_SEQ = 2**53 - 1
"""The largest seq admitted: exact in a JSON double."""
MAX_JUMP = 1000
"""The largest step of one issuer's seq admitted (an issuer counts 1, 2, 3...)."""

Outcome = Literal["admitted", "repeat", "stale", "seq out of range", "seq jumped"]


@dataclass(frozen=True)
class Verdict:
    """What the gate made of one command."""

    outcome: Outcome
    detail: str = ""

    @property
    def admitted(self) -> bool:
        return self.outcome == "admitted"


class CommandGate:
    """Per-issuer ordering of commands; see the module's rules."""

    def __init__(self, max_issuers: int = 256, max_jump: int = MAX_JUMP):
        self.max_issuers = max_issuers
        self.max_jump = max_jump
        self.last: OrderedDict[str, int] = OrderedDict()  # issuer -> last admitted seq

    def admit(self, command: str, issuer: str, seq: int) -> Verdict:
        """Whether to act on ``command`` number ``seq`` from ``issuer``."""
        in_range = 0 <= seq <= MAX_SEQ
        if command == "abort":
            last = self.last.get(issuer)
            # Remembered only as a command in order would be (rule 4): an abort with a
            # wild seq is acted on but does not make later commands of its issuer stale.
            if in_range and (last is None or last < seq <= last + self.max_jump):
                self._remember(issuer, seq)
            return Verdict("admitted")
        if not in_range:
            return Verdict("seq out of range", f"seq {seq} not in [0, {MAX_SEQ}]")
        last = self.last.get(issuer)
        if last is not None:
            if seq == last:
                return Verdict("repeat", f"seq {seq} already seen from {issuer}")
            if seq < last:
                return Verdict("stale", f"seq {seq} below {issuer}'s last {last}")
            if seq - last > self.max_jump:
                return Verdict(
                    "seq jumped",
                    f"seq {seq} is {seq - last} above {issuer}'s last {last} "
                    f"(at most {self.max_jump})",
                )
        self._remember(issuer, seq)
        return Verdict("admitted")

    def _remember(self, issuer: str, seq: int) -> None:
        self.last[issuer] = seq
        self.last.move_to_end(issuer)
        while len(self.last) > self.max_issuers:
            self.last.popitem(last=False)
