r"""The block and the flight sequence of a flight-by-flight test.

A test file's flight types are applied in **blocks**: a block holds ``counts[T]`` flights of
each type ``T`` (e.g. ten types of decreasing severity, the most severe once per block, as
TWIST's blocks are built), in an order that is a seeded random permutation of that multiset.
Flight ``n`` (1-based, over the whole test) is flight ``p = (n − 1) mod B + 1`` of block
``b = ⌊(n − 1)/B⌋ + 1``, ``B`` the block's size.

**Determinism.** Block ``b``'s order depends only on ``(seed, b)`` and the counts, the same on
every machine and after any resume:

* the random bits are PCG64's raw 64-bit outputs seeded by
  ``numpy.random.SeedSequence([seed, b])`` (``seed`` and ``b`` as two separate words, so seed 1
  block 2 and seed 2 block 1 differ). NumPy's compatibility policy (NEP 19) keeps a bit
  generator's raw stream and SeedSequence fixed across versions, but not the algorithms of
  ``Generator.permutation``/``shuffle``; so the permutation is our own:
* a Fisher–Yates shuffle of the types listed in the file's order (each repeated by its count),
  drawing ``j`` uniform in ``[0, i]`` from one raw output by rejection (draws of
  ``2⁶⁴ − (2⁶⁴ mod (i + 1))`` or more are discarded: no modulo bias).

``tests/test_endurance_spectrum.py`` pins a block's order literally, so a change of this
algorithm cannot pass unnoticed.

:func:`write_twist_like` writes a set of flight types for a station (load-case CSVs and a
``test.toml``) with the shape of a transport wing's flight-by-flight test: for tests and the
example, not a standard's content (bring TWIST, FALSTAFF, ... as load-case CSVs).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from core.errors import ParameterError

_TWO64 = 1 << 64


@dataclass(frozen=True)
class Block:
    """How many flights of each type one block holds, and the seed of its order.

    Attributes
    ----------
    counts : flight type → flights per block (≥ 1 each), in the test file's order (the order
        the shuffle starts from: part of the sequence's definition)
    seed : a non-negative integer
    """

    counts: Mapping[str, int]
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.counts:
            raise ParameterError("a block needs at least one flight type")
        for name, c in self.counts.items():
            if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or c < 1:
                raise ParameterError(f"block: flight type {name}: {c!r} flights; give a whole "
                                     "number >= 1")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise ParameterError(f"block: seed = {self.seed!r}: give a whole number >= 0")
        # a hashable, ordered copy (lru_cache keys on it)
        object.__setattr__(self, "counts", _Counts(tuple((str(k), int(v))
                                                        for k, v in self.counts.items())))

    @property
    def size(self) -> int:
        """Flights per block."""
        return sum(self.counts.values())

    @property
    def types(self) -> list[str]:
        return list(self.counts)

    def order(self, block: int) -> tuple[str, ...]:
        """The flight types of block ``block`` (1-based) in the order they are flown."""
        if isinstance(block, bool) or not isinstance(block, (int, np.integer)) or block < 1:
            raise ParameterError(f"block {block!r}: blocks are numbered from 1")
        return _order(self.counts.items_tuple, self.seed, int(block))


class _Counts(dict):
    """An ordered mapping that hashes by its items (a frozen Block's counts)."""

    def __init__(self, items: tuple[tuple[str, int], ...]) -> None:
        super().__init__(items)
        self.items_tuple = items

    def __hash__(self) -> int:             # type: ignore[override]
        return hash(self.items_tuple)


@dataclass(frozen=True)
class FlightSlot:
    """Where flight ``number`` sits: its block, its position in the block (both 1-based) and
    its type."""

    number: int
    block: int
    position: int
    flight_type: str


@dataclass(frozen=True)
class FlightSequence:
    """The flights of a test, block after block (module docstring).

    Attributes
    ----------
    block : the block
    flights : the target (None: open-ended)
    """

    block: Block
    flights: int | None = None

    def slot(self, number: int) -> FlightSlot:
        """Flight ``number`` (1-based): its block, position and type."""
        if isinstance(number, bool) or not isinstance(number, (int, np.integer)) or number < 1:
            raise ParameterError(f"flight {number!r}: flights are numbered from 1")
        if self.flights is not None and number > self.flights:
            raise ParameterError(f"flight {number}: the test has {self.flights} flights")
        b, p = divmod(int(number) - 1, self.block.size)
        return FlightSlot(int(number), b + 1, p + 1, self.block.order(b + 1)[p])

    def slots(self, first: int, last: int) -> list[FlightSlot]:
        """Flights ``first`` to ``last`` inclusive."""
        return [self.slot(n) for n in range(first, last + 1)]

    def counts_through(self, number: int) -> dict[str, int]:
        """How many flights of each type flights 1 to ``number`` hold (0 → none)."""
        out = {t: 0 for t in self.block.types}
        if number <= 0:
            return out
        whole, rest = divmod(int(number), self.block.size)
        for t, c in self.block.counts.items():
            out[t] += whole * c
        if rest:
            for t in self.block.order(whole + 1)[:rest]:
                out[t] += 1
        return out

    @property
    def blocks(self) -> int | None:
        """Blocks the target spans (the last may be partial)."""
        if self.flights is None:
            return None
        return -(-self.flights // self.block.size)


@functools.lru_cache(maxsize=64)
def _order(items: tuple[tuple[str, int], ...], seed: int, block: int) -> tuple[str, ...]:
    bits = np.random.PCG64(np.random.SeedSequence([seed, block]))
    flights = [t for t, c in items for _ in range(c)]
    for i in range(len(flights) - 1, 0, -1):
        j = _below(bits, i + 1)
        flights[i], flights[j] = flights[j], flights[i]
    return tuple(flights)


def _below(bits: np.random.PCG64, n: int) -> int:
    """A uniform integer in [0, n) from raw 64-bit outputs, by rejection (no modulo bias)."""
    limit = _TWO64 - _TWO64 % n
    while True:
        r = int(bits.random_raw())
        if r < limit:
            return r % n


# -- a TWIST-like set of flight types, for tests and the example ------------------------------------
#: flight type names A, B, ... (A the most severe)
TYPE_NAMES = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"


def twist_like_counts(n_types: int = 10, growth: float = 2.4) -> dict[str, int]:
    """Flights per block of ``n_types`` types of decreasing severity: A once, then about
    ``growth`` times more of each milder type (10 types: a block of 4,529 flights)."""
    if not 1 <= n_types <= len(TYPE_NAMES):
        raise ParameterError(f"n_types = {n_types}: give 1 to {len(TYPE_NAMES)}")
    return {TYPE_NAMES[k]: max(1, int(round(growth ** k))) for k in range(n_types)}


def twist_like_levels(limits_kgf: Sequence[float], n_types: int = 10,
                      one_g_share: float = 0.4, gust_share: float = 0.45,
                      ground_share: float = -0.15, seed: int = 0) -> dict[str, np.ndarray]:
    r"""Every flight type's load cases (N channels × M cases, kgf) for channels of force limits
    ``limits_kgf``: a ground load case, take-off to the 1 g level, gust cycles about it, the
    landing and the ground again.

    Channel i's 1 g level is ``one_g_share·limit_i``, its ground level ``ground_share`` of that
    (the structure's own weight the other way); type k (0 = A) has severity
    ``s_k = 1 − 0.85·k/(n − 1)`` and ``n_k = 2 + round(6·s_k)`` gust cycles, cycle j going to
    ``1 g ± a_j`` with ``a_j = gust_share·one_g·s_k·(0.55 + 0.45·u_j)``, ``u_j`` uniform from
    ``seed`` (the same for every channel, the channels' shares differing: the outer channels
    see more of the gust, ``1 + 0.3·i/(N − 1)``), so the load cases' ratios change from case to
    case. Every level stays within 90 % of its channel's limit."""
    limits = np.asarray(limits_kgf, float)
    if limits.ndim != 1 or not len(limits) or not (limits > 0).all():
        raise ParameterError("twist_like_levels needs one positive force limit per channel")
    n = len(limits)
    one_g = one_g_share * limits
    spread = 1 + 0.3 * np.arange(n) / max(n - 1, 1)
    rng = np.random.default_rng(seed)
    out = {}
    for k, name in enumerate(twist_like_counts(n_types)):
        s = 1 - 0.85 * k / max(n_types - 1, 1)
        cycles = 2 + int(round(6 * s))
        cases = [ground_share * one_g, one_g]
        for u in rng.uniform(0, 1, cycles):
            a = gust_share * one_g * spread * s * (0.55 + 0.45 * u)
            cases += [one_g + a, one_g - a]
        cases += [0.9 * one_g, ground_share * one_g]
        levels = np.round(np.array(cases).T, 1)
        np.clip(levels, -0.9 * limits[:, None], 0.9 * limits[:, None], out=levels)
        out[name] = levels
    return out


def write_twist_like(directory: str | Path, names: Sequence[str], limits_kgf: Sequence[float],
                     station: str, controller: str, flights: int = 100_000, n_types: int = 10,
                     counts: Mapping[str, int] | None = None, seed: int = 1,
                     rate_kgf_s: float = 2500.0, name: str = "TWIST-like endurance test") -> Path:
    """Write a TWIST-like test into ``directory``: ``flights/A.csv`` ... (load-case CSVs,
    ``case`` and a column per channel of ``names``; for a stand, ``names = ["level"]``: its one column) and
    ``test.toml`` naming ``station`` and ``controller`` (paths as the test file should hold
    them, relative to ``directory``). Returns the test file's path."""
    from loading.programme_files import write_load_cases
    directory = Path(directory)
    (directory / "flights").mkdir(parents=True, exist_ok=True)
    levels = twist_like_levels(limits_kgf, n_types, seed=seed)
    counts = dict(counts) if counts is not None else twist_like_counts(n_types)
    lines = [f"name = {_toml_str(name)}", f"station = {_toml_str(station)}",
             f"controller = {_toml_str(controller)}", f"rate_kgf_s = {rate_kgf_s!r}",
             f"flights = {int(flights)}", ""]
    for t, lv in levels.items():
        write_load_cases(directory / "flights" / f"{t}.csv", lv, names)
        lines += [f"[flight.{t}]", f'load_cases = "flights/{t}.csv"', ""]
    lines += ["[block]", f"seed = {int(seed)}",
              "flights = { " + ", ".join(f"{t} = {c}" for t, c in counts.items()) + " }", ""]
    path = directory / "test.toml"
    path.write_text("\n".join(lines))
    return path


def _toml_str(text: str) -> str:
    return '"' + str(text).replace("\\", "\\\\").replace('"', '\\"') + '"'
