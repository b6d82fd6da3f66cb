"""The live view of a headless run (``run_headless --live PORT``): real-time pacing and the
loop's own pause / unpause / step services.

:class:`RealTimePacer` is the hook ``HeadlessSim.run`` calls before each advance: it
publishes the state to the live server, sleeps until the next step is due at real time x
`rtf`, waits while paused (a ``step`` lets one step through) and returns how many steps may
be taken now. The run's results are those of the same run without ``--live``: pacing only
decides when the steps are taken, never what they compute. ``reset`` is refused: the bag
records one run.
"""
from __future__ import annotations

import threading
import time
from typing import Any

from .server import LiveServer

BATCH_STEPS = 16          # most steps between two publishes/real-time checks
IDLE = 0.05               # s between looks while paused


class RealTimePacer:
    def __init__(self, loop: Any, rtf: float = 1.0):
        self.loop = loop
        self.rtf = float(rtf)
        self.live: LiveServer = None        # set by the caller after start
        self._lock = threading.Lock()
        self._paused = False
        self._steps_allowed = 0
        self._anchor = None                 # (wall, simulated time)

    def services(self) -> dict:
        return {'pause': self._pause, 'unpause': self._unpause, 'step': self._step,
                'reset': self._reset}

    def _pause(self):
        with self._lock:
            was, self._paused = self._paused, True
        return True, f'paused at t={self.loop.world.time:.6f} s' + (' (already)' if was else '')

    def _unpause(self):
        with self._lock:
            was, self._paused = self._paused, False
            self._anchor = None
        return True, f'running from t={self.loop.world.time:.6f} s' + (
            '' if was else ' (was not paused)')

    def _step(self):
        with self._lock:
            if not self._paused:
                return False, 'not paused: call pause first'
            self._steps_allowed += 1
        return True, f'one step from t={self.loop.world.time:.6f} s'

    def _reset(self):
        return False, 'a headless run records one run into its bag: no reset (run it again)'

    def __call__(self, n: int) -> int:
        """Steps to take now (1..n), after waiting for them to be due."""
        live, loop = self.live, self.loop
        while True:
            with self._lock:
                paused, allowed = self._paused, self._steps_allowed
                if paused and allowed:
                    self._steps_allowed -= 1
            if not paused:
                break
            if allowed:
                live.publish_loop(loop, force=True)
                return 1
            if live.refresh_due:
                live.publish_loop(loop, force=True)
            time.sleep(IDLE)
        live.publish_loop(loop)
        if self.rtf <= 0.0:
            return min(n, BATCH_STEPS)
        now, t, dt = time.monotonic(), loop.world.time, loop.world.dt
        if self._anchor is None:
            self._anchor = (now, t)
        due_wall = self._anchor[0] + (t + dt - self._anchor[1]) / self.rtf
        if due_wall > now:
            time.sleep(due_wall - now)
            now = time.monotonic()
        due = int(((now - self._anchor[0]) * self.rtf - (t - self._anchor[1])) / dt + 1e-6)
        return max(1, min(n, due, BATCH_STEPS))
