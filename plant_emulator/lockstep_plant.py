"""The plant in lockstep: one communication period per SYNC, computed ahead in blocks.

The command of a period first acts a transport delay later. With ``m`` whole sub-steps of delay
and ``sub`` sub-steps per period, the force at the ends of the next ``B = m // sub + 1`` periods
depends only on commands already received, whatever the commands still to come. So one
:meth:`~plant.PlantModel.advance` call computes ``B`` periods (one numpy pass instead of ``B``:
at τ = 50 ms, 2 ms periods and 0.5 ms steps, B = 26), with the current command standing in for
the periods not yet commanded; as each period ends, its real command replaces the stand-in in
the delay line, long before the delay brings it to the valve. The result is the same as
advancing period by period (to rounding: one cumulative sum instead of several).

If the period changes while periods are computed ahead, the block is undone: the state is
restored from the block's start and the periods that have ended are replayed with their real
commands.
"""
from __future__ import annotations

import copy
import math
from collections import deque

import numpy as np

from plant import PlantModel


class LockstepPlant:
    """``step(period_s, command)``: the period that just ended ran with ``command``; returns the
    force at its end."""

    def __init__(self, model: PlantModel, y0: float, step_s: float) -> None:
        self.model = model
        self.step_s = step_s
        self.dt = step_s
        self.state = model.new_state(1, step_s, y0=y0)
        self.period: float | None = None
        self.sub = 1
        self.force = float(y0)
        self._ahead: deque[float] = deque()   # forces at the ends of periods computed ahead
        self._start = None                    # state at the block's start (to undo it)
        self._commands: list[float] = []      # real commands of the block's ended periods
        self._block_periods = 0
        self._blocks = self._periods = 0

    @property
    def periods_per_block(self) -> float:
        """Periods computed per advance call, on average (for benchmarks and tests)."""
        return self._periods / self._blocks if self._blocks else 0.0

    def step(self, period_s: float, command: float) -> float:
        if period_s != self.period:
            self._regrid(period_s, command)
        if self._ahead:
            self._confirm(command)
            self.force = self._ahead.popleft()
        else:
            self.force = self._block(command)
        return self.force

    def restart_clock(self) -> None:
        """A run begins: the plant's time counts from zero again (the periods computed ahead
        are dropped first, they carry the old time)."""
        self._undo()
        self.state.t[:] = 0.0

    # -- inside ---------------------------------------------------------------------------------
    def _regrid(self, period_s: float, command: float) -> None:
        self._undo()
        sub = max(1, math.ceil(period_s / self.step_s - 1e-9))
        dt = period_s / sub
        if dt != self.dt:   # keep the force and time, re-grid the delay line on the command
            self.state = self.model.new_state(1, dt, y0=self.state.y, u0=command, t0=self.state.t)
            self.dt = dt
        self.period, self.sub = period_s, sub

    def _block(self, command: float) -> float:
        sub = self.sub
        periods = self.model.delay_steps(self.dt) // sub + 1
        self._start = copy.deepcopy(self.state) if periods > 1 else None
        self._commands = [command]
        self._block_periods = periods
        y = self.model.advance(self.state, np.full((1, periods * sub), command), self.dt)[0]
        ends = y[sub - 1::sub].tolist()
        self._ahead.extend(ends[1:])
        self._blocks += 1
        self._periods += periods
        return ends[0]

    def _confirm(self, command: float) -> None:
        """The block's next period ended with ``command``: put it in the delay line in place of
        the stand-in (the line's last ``(B − 1)·sub`` entries are the block's later periods)."""
        i = len(self._commands)              # period i of the block (0 ran with a real command)
        self._commands.append(command)
        if command != self._commands[0]:     # else the stand-in was right
            h = self.state.history
            end = h.shape[1] - (self._block_periods - 1 - i) * self.sub
            h[:, end - self.sub:end] = command

    def _undo(self) -> None:
        """Forget the periods computed ahead: back to the block's start, replay the ended ones."""
        if self._ahead and self._start is not None:
            self.state = self._start
            for c in self._commands:
                self.model.advance(self.state, np.full((1, self.sub), c), self.dt)
        self._ahead.clear()
        self._start = None
        self._commands = []
