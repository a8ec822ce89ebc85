"""Bad frames in, nothing bad out: an acceptance filter for CANopen stacks, fault injection for
the loopback bus, and a garbage generator to flood a bus with.

* :class:`FrameFilter` — what a CAN controller's acceptance filter plus a careful stack do:
  only classic 11-bit data frames reach the CANopen layer; a frame on an id the filter knows
  must have one of the data lengths allowed for it (an EMCY has 8 bytes, a heartbeat 1, a PDO
  exactly its mapped size); in strict mode frames on ids nobody configured are dropped too.
  Every dropped frame is counted by kind.
* :class:`FaultSpec` / :class:`FaultInjector` — lossy or slow reception for
  ``udp_loopback`` (bus options ``drop=0.1,delay_ms=5,fault_ids=0x080-0x4FF,seed=1``): each
  received frame whose id is in ``fault_ids`` is lost with probability ``drop`` and the others
  are delivered ``delay_ms`` late (order kept). Losses are drawn from one random stream per
  arbitration id, so with a seed the n-th frame of an id is always lost or always kept.
* :func:`garbage_frame` / :func:`flood` — random frames (any id, DLC, flags, error and remote
  frames, extended ids) that never form a *valid* frame of the protected set, e.g. of the
  stand's CANopen objects: on those ids only wrong lengths. ``python -m standbus.faults`` runs
  a flood as a separate process.
"""
from __future__ import annotations

import argparse
import math
import random
import sys
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Collection, Iterable, Mapping

import can

#: every data length of a classic CAN frame
ALL_LENGTHS = frozenset(range(9))
_ANY = object()


class FrameFilter(can.Listener):
    """Drop and count frames that must not reach a CANopen stack; pass the rest to ``deliver``.

    :param deliver: called with every accepted frame (on the Notifier thread).
    :param strict: drop frames on ids without a rule (else they pass unchecked).

    Counters (plain ints, read them any time): ``not_classic`` (error, remote, extended-id or
    FD frames), ``unexpected_id`` (strict mode: no rule for the id), ``wrong_dlc`` (length not
    allowed for the id, or DLC field disagreeing with the data), ``errors`` (``deliver`` raised).
    """

    def __init__(self, deliver: Callable[[can.Message], None], strict: bool = False,
                 fd: bool = False) -> None:
        self.deliver = deliver
        self.strict = strict
        #: a CAN FD bus: FD data frames pass too (classic ones always do)
        self.fd = fd
        self.rules: dict[int, frozenset[int] | None] = {}
        #: remote frames taken by a handler of their own, by id (a slave's node guarding: the
        #: canopen stack ignores remote frames); any other remote frame is dropped
        self.remote: dict[int, Callable[[can.Message], None]] = {}
        self.not_classic = 0
        self.unexpected_id = 0
        self.wrong_dlc = 0
        self.errors = 0

    def expect(self, can_id: int, lengths: Iterable[int] | int | None = None) -> None:
        """Accept ``can_id`` with these data lengths (an int, several, or None for any)."""
        if isinstance(lengths, int):
            lengths = (lengths,)
        self.rules[can_id] = None if lengths is None else frozenset(lengths)

    def accept_remote(self, can_id: int, handler: Callable[[can.Message], None]) -> None:
        """Hand classic remote frames on ``can_id`` (any DLC) to ``handler``."""
        self.remote[can_id] = handler

    def counts(self) -> dict[str, int]:
        return {"not_classic": self.not_classic, "unexpected_id": self.unexpected_id,
                "wrong_dlc": self.wrong_dlc, "errors": self.errors}

    @property
    def dropped(self) -> int:
        return self.not_classic + self.unexpected_id + self.wrong_dlc

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_remote_frame and self.remote and not (msg.is_error_frame or msg.is_extended_id
                                                        or msg.is_fd):
            handler = self.remote.get(msg.arbitration_id)
            if handler is not None:
                try:
                    handler(msg)
                except Exception:  # a listener must never kill the Notifier thread
                    self.errors += 1
                return
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or (msg.is_fd and not self.fd):
            self.not_classic += 1
            return
        rule = self.rules.get(msg.arbitration_id, _ANY)
        if rule is _ANY:
            if self.strict:
                self.unexpected_id += 1
                return
        if msg.dlc != len(msg.data) or (rule is not None and rule is not _ANY
                                        and len(msg.data) not in rule):
            self.wrong_dlc += 1
            return
        try:
            self.deliver(msg)
        except Exception:  # a listener must never kill the Notifier thread
            self.errors += 1


# -- fault injection ----------------------------------------------------------------------------
def parse_id_range(text: str | int | None) -> tuple[int, int] | None:
    """``"0x080-0x4FF"`` → ``(0x80, 0x4FF)``; ``"0x181"`` or ``385`` → one id; None → all ids."""
    if text is None or text == "":
        return None
    if isinstance(text, int):
        lo = hi = text
    else:
        first, sep, last = str(text).partition("-")
        try:
            lo = int(first.strip(), 0)
            hi = int(last.strip(), 0) if sep else lo
        except ValueError:
            raise ValueError(f"fault_ids={text!r}: write an id or a range, e.g. 0x181 or "
                             "0x080-0x4FF") from None
    if not (0 <= lo <= hi <= 0x1FFFFFFF):
        raise ValueError(f"fault_ids={text!r}: ids must be 0..0x1FFFFFFF with low <= high")
    return lo, hi


@dataclass(frozen=True)
class FaultSpec:
    """What to do to the frames a bus receives.

    :param drop: probability that a received frame (with an id in ``ids``) is lost, 0..1.
    :param delay_s: extra latency of every received frame in ``ids``, s (0..10).
    :param ids: inclusive range of arbitration ids affected; None: all.
    :param seed: seed of the loss pattern (None: random).
    """

    drop: float = 0.0
    delay_s: float = 0.0
    ids: tuple[int, int] | None = None
    seed: int | None = None

    def __post_init__(self) -> None:
        for name, value, hi in (("drop", self.drop, 1.0), ("delay", self.delay_s, 10.0)):
            if not isinstance(value, (int, float)) or isinstance(value, bool) or \
                    not math.isfinite(value) or not 0 <= value <= hi:
                raise ValueError(f"{name}={value!r} must be a number from 0 to {hi:g}"
                                 + (" (s)" if name == "delay" else ""))
        if self.seed is not None and (not isinstance(self.seed, int) or isinstance(self.seed, bool)):
            raise ValueError(f"seed={self.seed!r} must be an integer")

    @classmethod
    def from_options(cls, drop: float = 0.0, delay_ms: float = 0.0, fault_ids: str | int | None = None,
                     seed: int | None = None) -> "FaultSpec | None":
        """From bus options (``drop=0.1,delay_ms=5,fault_ids=0x080-0x4FF,seed=1``); None if
        they inject nothing."""
        if not isinstance(delay_ms, (int, float)) or isinstance(delay_ms, bool):
            raise ValueError(f"delay_ms={delay_ms!r} must be a number of milliseconds")
        spec = cls(drop=drop, delay_s=delay_ms / 1000.0, ids=parse_id_range(fault_ids), seed=seed)
        return spec if (spec.drop or spec.delay_s) else None


class FaultInjector:
    """Decides for each received frame: lose it, hold it back, or deliver it now."""

    def __init__(self, spec: FaultSpec) -> None:
        self.spec = spec
        self._rngs: dict[int, random.Random] = {}
        self._held: deque[tuple[float, can.Message]] = deque()
        self.dropped = 0
        self.delayed = 0

    def affects(self, can_id: int) -> bool:
        ids = self.spec.ids
        return ids is None or ids[0] <= can_id <= ids[1]

    def lose(self, can_id: int) -> bool:
        """True if this frame is lost (one random stream per id)."""
        if not self.spec.drop:
            return False
        rng = self._rngs.get(can_id)
        if rng is None:
            seed = self.spec.seed if self.spec.seed is not None else random.getrandbits(64)
            rng = self._rngs[can_id] = random.Random(f"{seed}:{can_id}")
        if rng.random() < self.spec.drop:
            self.dropped += 1
            return True
        return False

    def hold(self, msg: can.Message, now: float) -> None:
        """Keep ``msg`` until ``now + delay`` (monotonic time)."""
        self.delayed += 1
        self._held.append((now + self.spec.delay_s, msg))

    def pop_due(self, now: float) -> can.Message | None:
        if self._held and self._held[0][0] <= now:
            return self._held.popleft()[1]
        return None

    def next_due(self) -> float | None:
        return self._held[0][0] if self._held else None


# -- garbage ------------------------------------------------------------------------------------
def canopen_protected(node_ids: Iterable[int], tpdo_lengths: Mapping[int, int] | None = None,
                      ) -> dict[int, frozenset[int]]:
    """The valid ``{id: data lengths}`` of CANopen's predefined connection set for these nodes:
    NMT (2), SYNC (0/1), and per node EMCY (8), TPDO1-4 (the given lengths, else all), RPDO1-4
    (all: any frame there is a command), SDO (8 each way), heartbeat (1). Garbage must avoid
    these combinations, or it is not garbage but a valid (spoofed) frame."""
    tpdo_lengths = dict(tpdo_lengths or {})
    out: dict[int, frozenset[int]] = {0x000: frozenset({2}), 0x080: frozenset({0, 1})}
    for n in node_ids:
        out[0x080 + n] = frozenset({8})
        for base in (0x180, 0x280, 0x380, 0x480):
            cob = base + n
            out[cob] = frozenset({tpdo_lengths[cob]}) if cob in tpdo_lengths else ALL_LENGTHS
        for base in (0x200, 0x300, 0x400, 0x500):
            out[base + n] = ALL_LENGTHS
        out[0x580 + n] = frozenset({8})
        out[0x600 + n] = frozenset({8})
        out[0x700 + n] = frozenset({1})
    return out


def garbage_frame(rng: random.Random, protected: Mapping[int, Collection[int]]) -> can.Message:
    """One random frame that is not a valid frame of ``protected`` (``{id: valid lengths}``).

    Mix: 5 % error frames, 5 % remote frames, 10 % extended ids (often the protected ids'
    numbers with a valid length: a stack that ignores the IDE bit would take them), 5 % CAN FD,
    75 % classic data frames, half of them on protected ids with a wrong length."""
    kind = rng.random()
    ids = list(protected)
    if kind < 0.05:
        return can.Message(is_error_frame=True, arbitration_id=0, is_extended_id=False,
                           data=rng.randbytes(rng.randrange(9)))
    if kind < 0.10:
        return can.Message(arbitration_id=rng.choice(ids) if ids else rng.randrange(0x800),
                           is_remote_frame=True, dlc=rng.randrange(9), is_extended_id=False)
    if kind < 0.20:
        cid = rng.choice(ids) if ids and rng.random() < 0.7 else rng.randrange(1 << 29)
        return can.Message(arbitration_id=cid, is_extended_id=True,
                           data=rng.randbytes(rng.choice(sorted(protected.get(cid, ALL_LENGTHS)) or [8])))
    if kind < 0.25:
        n = rng.choice((0, 8, 12, 16, 32, 64))
        return can.Message(arbitration_id=rng.choice(ids) if ids else 0x100, is_fd=True,
                           is_extended_id=False, data=rng.randbytes(n))
    while True:
        cid = rng.choice(ids) if ids and rng.random() < 0.5 else rng.randrange(0x800)
        wrong = sorted(ALL_LENGTHS - frozenset(protected.get(cid, ())))
        if wrong:
            return can.Message(arbitration_id=cid, is_extended_id=False,
                               data=rng.randbytes(rng.choice(wrong)))


def flood(bus: can.BusABC, rate_hz: float, duration_s: float, protected: Mapping[int, Collection[int]],
          seed: int | None = None) -> int:
    """Send garbage frames on ``bus`` at about ``rate_hz`` for ``duration_s``; returns the count."""
    rng = random.Random(seed)
    sent = 0
    t0 = time.monotonic()
    burst = max(1, int(rate_hz / 1000))        # frames per millisecond tick
    while True:
        elapsed = time.monotonic() - t0
        if elapsed >= duration_s:
            return sent
        due = int(elapsed * rate_hz)
        if sent >= due:
            time.sleep(min(0.001, duration_s - elapsed))
            continue
        for _ in range(min(burst, due - sent + 1)):
            try:
                bus.send(garbage_frame(rng, protected))
            except (can.CanError, ValueError):
                pass
            sent += 1


def _main(argv: list[str] | None = None) -> int:
    from .spec import open_bus
    p = argparse.ArgumentParser(prog="python -m standbus.faults",
                                description="Flood a bus with garbage frames that never form a valid "
                                            "frame of the given CANopen nodes.")
    p.add_argument("--bus", required=True)
    p.add_argument("--rate", type=float, default=5000.0, help="frames per second")
    p.add_argument("--duration", type=float, default=5.0, help="seconds")
    p.add_argument("--node", type=int, action="append", default=[], help="protected node id (repeatable)")
    p.add_argument("--tpdo", action="append", default=[], metavar="COB:LEN",
                   help="length of a node's TPDO, e.g. 0x182:4 (repeatable)")
    p.add_argument("--seed", type=int, default=None)
    args = p.parse_args(argv)
    lengths = {int(c, 0): int(n) for c, _, n in (t.partition(":") for t in args.tpdo)}
    bus = open_bus(args.bus)
    try:
        print("flooding", flush=True)
        n = flood(bus, args.rate, args.duration, canopen_protected(args.node, lengths), args.seed)
    finally:
        bus.shutdown()
    print(f"sent {n} garbage frames", flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover - exercised by the flood tests as a process
    sys.exit(_main())
