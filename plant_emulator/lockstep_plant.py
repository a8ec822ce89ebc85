"""The plant in lockstep: one communication period per SYNC, computed ahead in blocks.

The command of a period first acts a transport delay later. With ``m`` whole sub-steps of delay
and ``sub`` sub-steps per period, the force at the ends of the next ``B = m // sub + 1`` periods
depends only on commands already received, whatever the commands still to come. So one
:meth:`~plant.PlantModel.advance` call computes ``B`` periods (one numpy pass instead of ``B``:
at τ = 50 ms, 2 ms periods and 0.5 ms steps, B = 26), with the current command standing in for
the periods not yet commanded; as each period ends, its real command replaces the stand-in in
the delay line, long before the delay brings it to the valve. The result is the same as
advancing period by period (to rounding: one cumulative sum instead of several).

A rig (:class:`LockstepRig`) is the same with N channels coupled by the structure
(:class:`plant.rig.RigModel`): every channel's force depends on every channel's delayed flow,
so a block is as long as the shortest delay allows, ``B = min_i m_i // sub + 1``, and each
channel's real command replaces its own stand-in. :class:`LockstepPlant` is the one-channel
case.

If the period changes while periods are computed ahead, the block is undone: the state is
restored from the block's start and the periods that have ended are replayed with their real
commands.

**Computed before it is needed** (:meth:`LockstepRig.prefetch`, real time). A block computed
when the periods ahead run out is computed at the SYNC that finds none ahead, and that SYNC's
answers wait for it (0.5-1.7 ms for 16 channels, against a synchronous window of 1.5 ms: most
of a 16-channel rig's stale readings). The real-time emulator instead extends the block at a
quiet moment between a cycle's commands and its next SYNC, while a few periods are still
ahead: the forces at the ends of the ``B − 1`` periods after the present depend only on
commands already received (the present period's command is not final yet), so the periods
ahead are topped up to ``B − 1`` from where the block ends, the present command standing in
for the new ones (each period ahead keeps the stand-in it was computed with, for
:meth:`~LockstepRig._confirm`). One advance call of the new periods, no copy: ~0.15 ms for
16 channels where a block from the present, undone first, cost 0.44 ms. The block's start
(what an undo goes back to) stays where it was until the periods ended since exceed
:data:`REBASE_BLOCKS` blocks; then the block is undone and computed again from the present,
so an undo never replays more than that.

**Stand time.** The plant keeps its own clock, the time it has advanced since it was made (plus
``start_s``), as a count of steps so that a block computed ahead and the same periods computed
one by one see the same times: a structure's scheduled change (:class:`plant.rig.StructureChange`)
acts from the same step either way, so a lockstep run is the same bit for bit with it. The
channels' own clocks (``restart_clock``: a run's effects of time) are apart from it.
"""
from __future__ import annotations

import copy
import math
from collections import deque
from typing import Sequence

import numpy as np

from plant import PlantModel
from plant.rig import RigModel

#: :meth:`LockstepRig.prefetch` starts a block from the present again (rather than extending
#: the one ahead) once this many blocks' periods have ended since its start
REBASE_BLOCKS = 2


class LockstepRig:
    """``step(period_s, commands)``: the period that just ended ran with ``commands`` (one per
    channel, %); returns the forces at its end (kgf, one per channel)."""

    def __init__(self, model: RigModel, y0: Sequence[float] | float, step_s: float,
                 start_s: float = 0.0) -> None:
        self.model = model
        self.step_s = step_s
        self.dt = step_s
        self.states = model.new_state(step_s, y0)
        #: the states' stand time: ``_base_s + _steps·dt`` (``_base_s`` moves on when dt does)
        self._base_s = float(start_s)
        self._steps = 0
        self.period: float | None = None
        self.sub = 1
        self.forces: list[float] = [float(st.y[0]) for st in self.states]
        self._ahead: deque[list[float]] = deque()   # forces at the ends of periods computed ahead
        self._start = None                    # states at the block's start (to undo it)
        self._commands: list[list[float]] = []  # real commands of the block's ended periods
        self._assumed: deque[list[float]] = deque()   # the stand-ins of the periods ahead
        #: confirmed periods whose commands are not in the delay lines yet: (sub-steps from
        #: the lines' end, real commands, stand-ins), :meth:`_write_confirmed`
        self._unconfirmed: list[tuple[int, list[float], list[float]]] = []
        self._blocks = self._periods = 0
        #: blocks computed by :meth:`prefetch` (the others were computed when a step found
        #: none ahead: :attr:`blocks_on_demand`)
        self.prefetched_blocks = 0

    @property
    def stand_time_s(self) -> float:
        """The stand time of the forces last returned (the end of the period that just ended;
        the periods computed ahead are not counted)."""
        return self._clock_s() - len(self._ahead) * self.sub * self.dt

    def _clock_s(self) -> float:
        """The states' stand time (ahead of :attr:`stand_time_s` inside a block)."""
        return self._base_s + self._steps * self.dt

    def _advance(self, u: np.ndarray) -> np.ndarray:
        """The model advanced by ``u`` (N, K) from the states' stand time, the clock with it."""
        self._write_confirmed()
        y = self.model.advance(self.states, u, self.dt, self._clock_s())
        self._steps += u.shape[1]
        return y

    @property
    def periods_ahead(self) -> int:
        """Periods computed ahead of the present."""
        return len(self._ahead)

    @property
    def blocks_on_demand(self) -> int:
        """Blocks computed when a step found no period ahead (in real time: at a SYNC or a
        command, which then waited for it)."""
        return self._blocks - self.prefetched_blocks

    @property
    def periods_per_block(self) -> float:
        """Periods computed per advance call, on average (for benchmarks and tests)."""
        return self._periods / self._blocks if self._blocks else 0.0

    def step(self, period_s: float, commands: Sequence[float]) -> list[float]:
        commands = list(commands)
        if period_s != self.period:
            self._regrid(period_s, commands)
        if self._ahead:
            self._confirm(commands)
            self.forces = self._ahead.popleft()
        else:
            self.forces = self._block(commands)
        return self.forces

    def hold(self, periods: int, period_s: float, commands: Sequence[float]) -> list[float]:
        """``periods`` periods that all ran with ``commands``: as ``periods`` calls of
        :meth:`step`, but a gap longer than a block goes in one advance call (the real-time
        emulator catching up on the wall clock). Returns the forces at the end."""
        commands = list(commands)
        if periods <= 0:
            return self.forces
        if period_s != self.period:
            self._regrid(period_s, commands)
        while self._ahead and periods > 0:
            LockstepRig.step(self, period_s, commands)     # the rig's step, for any subclass
            periods -= 1
        if periods > self._block_periods_now():
            self._undo()                      # nothing ahead: the states are at the present
            u = np.repeat(np.asarray(commands, float)[:, None], (periods - 1) * self.sub, axis=1)
            self._advance(u)
            periods = 1
        for _ in range(periods):
            LockstepRig.step(self, period_s, commands)
        return self.forces

    def prefetch(self, commands: Sequence[float], periods_left: int) -> bool:
        """If fewer than ``periods_left`` periods are computed ahead, compute ahead now, up to
        ``B − 1`` periods after the present (module docstring, "Computed before it is
        needed"), ``commands`` (those applied now) standing in for the new periods; the
        present (forces, stand time) is kept. Returns whether anything was computed (not
        where ``B − 1`` is no more than ``periods_left``, nor before the period is known)."""
        if self.period is None or len(self._ahead) >= periods_left:
            return False
        periods = self._block_periods_now() - 1      # the present period is not over yet
        if periods <= periods_left:
            return False
        commands = list(commands)
        if not self._ahead or self._start is None or len(self._commands) >= REBASE_BLOCKS * periods:
            self._undo()                    # a block from the present
            self._start = (_copy_states(self.states), self._steps)
            self._commands = []
        new = periods - len(self._ahead)
        self._ahead.extend(self._periods_of(commands, new))
        self._assumed.extend([commands] * new)
        self.prefetched_blocks += 1
        return True

    def restart_clock(self, channels: Sequence[int] | None = None) -> None:
        """A run begins on ``channels`` (default: all): their plant's time counts from zero
        again (the periods computed ahead are dropped first, they carry the old time)."""
        self._undo()
        for i in range(self.model.n) if channels is None else channels:
            self.states[i].t[:] = 0.0

    # -- inside ---------------------------------------------------------------------------------
    def _regrid(self, period_s: float, commands: list[float]) -> None:
        self._undo()
        sub = max(1, math.ceil(period_s / self.step_s - 1e-9))
        dt = period_s / sub
        if dt != self.dt:   # keep the forces and time, re-grid the delay lines on the commands
            self.states = [m.new_state(1, dt, y0=st.y, u0=c, t0=st.t)
                           for m, st, c in zip(self.model.channels, self.states, commands)]
            self._base_s, self._steps = self._clock_s(), 0
            self.dt = dt
        self.period, self.sub = period_s, sub

    def _block_periods_now(self) -> int:
        """Periods a block computes ahead: as many as the shortest delay allows (asked at every
        real-time catch-up: kept per step and sub-steps)."""
        key = (self.dt, self.sub)
        cached = self.__dict__.get("_block_cache")
        if cached is None or cached[0] != key:
            periods = min(m.delay_steps(self.dt) for m in self.model.channels) // self.sub + 1
            cached = self._block_cache = (key, periods)
        return cached[1]

    def _block(self, commands: list[float]) -> list[float]:
        periods = self._block_periods_now()
        self._write_confirmed()
        self._start = (_copy_states(self.states), self._steps) if periods > 1 else None
        self._commands = [commands]
        self._assumed = deque([commands] * (periods - 1))
        ends = self._periods_of(commands, periods)
        self._ahead.extend(ends[1:])
        return ends[0]

    def _periods_of(self, commands: list[float], periods: int) -> list[list[float]]:
        """The states advanced ``periods`` periods with ``commands`` in one call (a block, or
        a prefetch's new periods): the forces at each period's end."""
        sub = self.sub
        u = np.repeat(np.asarray(commands, float)[:, None], periods * sub, axis=1)
        y = self._advance(u)
        self._blocks += 1
        self._periods += periods
        return y[:, sub - 1::sub].T.tolist()

    def _confirm(self, commands: list[float]) -> None:
        """The next period ahead ended with ``commands``: each goes into its channel's delay
        line in place of the stand-in it was computed with, written with the others of the
        block by :meth:`_write_confirmed` before the states next advance or are copied (one
        slice a channel a block instead of one a channel a period: ~11 µs a cycle at 16
        channels)."""
        stand_ins = self._assumed.popleft()
        self._commands.append(commands)
        if commands != stand_ins or self._unconfirmed:    # (a run of periods, for one slice)
            self._unconfirmed.append(((len(self._ahead) - 1) * self.sub, commands, stand_ins))

    def _write_confirmed(self) -> None:
        """The confirmed commands into the delay lines: a period ``back`` sub-steps before the
        line's end (the periods still ahead at its confirmation) takes the ``sub`` entries
        before that. The pending periods are consecutive: between two writes the periods ahead
        only end, one per step (what adds periods ahead advances the states, and writes first)."""
        pending = self._unconfirmed
        if not pending:
            return
        self._unconfirmed = []
        sub = self.sub
        first, last = pending[0][0], pending[-1][0]
        real = np.asarray([c for _, c, _ in pending], float)
        changed = (real != np.asarray([a for _, _, a in pending], float)).any(axis=0)
        for j in np.flatnonzero(changed):
            h = self.states[j].history
            end = h.shape[1]
            h[:, end - first - sub:end - last] = np.repeat(real[:, j], sub)

    def _undo(self) -> None:
        """Forget the periods computed ahead: back to the block's start, replay the ended ones."""
        if not (self._ahead and self._start is not None):
            self._write_confirmed()           # the states are the present's: complete them
        else:
            self._unconfirmed = []            # (the replay below has the real commands)
            self.states, self._steps = self._start
            # the ended periods in one call (one per period cost ~0.1 ms per channel each: a
            # real-time block of 100 steps took 90 ms to undo for 8 channels)
            if self._commands:
                u = np.repeat(np.asarray(self._commands, float).T, self.sub, axis=1)
                self._advance(u)
        self._ahead.clear()
        self._assumed.clear()
        self._start = None
        self._commands = []


def _copy_states(states):
    """The states, every array copied (what ``copy.deepcopy`` gives, at a fraction of its
    cost: 16 channels' states took ~0.1 ms to deep-copy at every block)."""
    out = []
    for st in states:
        c = copy.copy(st)
        c.y, c.t, c.history = st.y.copy(), st.t.copy(), st.history.copy()
        c.reading = None if st.reading is None else st.reading.copy()
        c.valve_last = None if st.valve_last is None else st.valve_last.copy()
        c.effects = [{k: (v.copy() if isinstance(v, np.ndarray) else copy.deepcopy(v))
                      for k, v in eff.items()} for eff in st.effects]
        out.append(c)
    return out


class LockstepPlant(LockstepRig):
    """One channel: ``step(period_s, command)``: the period that just ended ran with
    ``command``; returns the force at its end."""

    def __init__(self, model: PlantModel, y0: float, step_s: float) -> None:
        super().__init__(RigModel([model]), y0, step_s)

    @property
    def force(self) -> float:
        return self.forces[0]

    def step(self, period_s: float, command: float) -> float:  # type: ignore[override]
        return super().step(period_s, (command,))[0]
