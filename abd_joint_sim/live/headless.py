"""The live view of a headless run (``run_headless --live``, ``replay_bag --live``): real-time
pacing and the loop's own pause / unpause / step / reset services, and for a replay Foxglove's
playback control (docs/live.md). Pacing decides only when the steps are taken, never what they
compute: the run's results are those of the same run without the live view.
"""
from __future__ import annotations

import sys
import threading
import time
from typing import Any, Optional

BATCH_STEPS = 16          # most steps between two publishes/real-time checks
FAST_STEPS = 256          # most steps per advance while seeking
IDLE = 0.05               # s between looks while paused


class Restart(Exception):
    """A seek backward: run again from the start up to :attr:`RealTimePacer.seek_ns`."""


class RealTimePacer:
    """The hook ``HeadlessSim.run`` calls before each advance: it publishes the state to
    `live` (the ``LiveServer``), sleeps until the next step is due at real time x `speed`,
    waits while paused (``step`` lets one through) and returns how many steps to take now.
    `loop`: the ``SimLoop`` (``replace_loop`` after a :class:`Restart`); `end_ns`: the
    replay's last time (the playback range; a seek backward or ``reset`` restarts the run),
    None for a run that records (it refuses ``reset``: its bag holds one run)."""

    def __init__(self, loop: Any, speed: float = 1.0, end_ns: Optional[int] = None):
        self.loop = loop
        self.speed = float(speed)
        self.end_ns = end_ns            # None: not seekable
        self.live = None
        self._lock = threading.Lock()
        self._paused = self._restart = self.ended = False
        self._steps_allowed = 0
        self._anchor: Optional[tuple[float, float]] = None     # (wall, simulated time)
        self.seek_ns: Optional[int] = None

    def services(self) -> dict:
        return {'pause': self._pause, 'unpause': self._unpause, 'step': self._step,
                'reset': self._reset}

    # ------------------------------------------------------------------- requests ----
    def _pause(self):
        with self._lock:
            was, self._paused = self._paused, True
        self._broadcast()
        return True, f'paused at t={self.loop.world.time:.6f} s' + (' (already)' if was else '')

    def _unpause(self):
        with self._lock:
            was, self._paused = self._paused, False
            self._anchor = None
        self._broadcast()
        return True, f'running from t={self.loop.world.time:.6f} s' + (
            '' if was else ' (was not paused)')

    def _step(self):
        with self._lock:
            if not self._paused:
                return False, 'not paused: call pause first'
            self._steps_allowed += 1
        return True, f'one step from t={self.loop.world.time:.6f} s'

    def _reset(self):
        if self.end_ns is None:
            return False, 'a headless run records one run into its bag: no reset (run it again)'
        self.seek(0)
        return True, 'replaying from t=0'

    def seek(self, t_ns: int) -> None:
        """Go to simulated time `t_ns` (clipped to the playback range)."""
        t_ns = max(0, min(int(t_ns), self.end_ns or 0))
        with self._lock:
            self.seek_ns = t_ns
            self._restart = t_ns < self.loop.time_ns or self.ended
            self._anchor = None

    def on_playback_control_request(self, request) -> Any:
        """Foxglove's playback control (play/pause, speed, seek): the new playback state."""
        from foxglove.websocket import PlaybackCommand
        if request.playback_speed and request.playback_speed > 0:
            self.speed = float(request.playback_speed)
            with self._lock:
                self._anchor = None
        if request.seek_time is not None:
            self.seek(request.seek_time)
        if request.playback_command == PlaybackCommand.Pause:
            self._pause()
        elif request.playback_command == PlaybackCommand.Play:
            self._unpause()
        return self.playback_state(request.request_id, request.seek_time is not None)

    def playback_state(self, request_id: Optional[str] = None, did_seek: bool = False):
        from foxglove.websocket import PlaybackState, PlaybackStatus
        status = (PlaybackStatus.Ended if self.ended and self.seek_ns is None else
                  PlaybackStatus.Paused if self._paused else PlaybackStatus.Playing)
        now = self.seek_ns if self.seek_ns is not None else self.loop.time_ns
        return PlaybackState(status=status, current_time=int(now), playback_speed=self.speed,
                             did_seek=did_seek, request_id=request_id)

    def _broadcast(self, did_seek: bool = False) -> None:
        server = getattr(self.live, '_server', None)
        if self.end_ns is not None and server is not None:
            server.broadcast_playback_state(self.playback_state(None, did_seek))

    # --------------------------------------------------------------------- pacing ----
    def __call__(self, n: int) -> int:
        """Steps to take now (1..n), after waiting for them to be due."""
        live, loop = self.live, self.loop
        if self.seek_ns is not None:
            if self._restart:
                raise Restart()
            if loop.time_ns < self.seek_ns:            # on the way: as fast as possible
                dt_ns = max(1, int(round(loop.world.dt * 1e9)))
                return max(1, min(n, FAST_STEPS, -(-(self.seek_ns - loop.time_ns) // dt_ns)))
            with self._lock:
                self.seek_ns = None
                self._anchor = None
            live.publish_loop(loop, force=True)
            self._broadcast(did_seek=True)
        while True:
            with self._lock:
                paused, allowed = self._paused, self._steps_allowed
                if paused and allowed:
                    self._steps_allowed -= 1
            if self.seek_ns is not None:
                return self(n)
            if not paused:
                break
            if allowed:
                live.publish_loop(loop, force=True)
                return 1
            if live.refresh_due:
                live.publish_loop(loop, force=True)
            time.sleep(IDLE)
        live.publish_loop(loop)
        if self.speed <= 0.0:
            return min(n, BATCH_STEPS)
        now, t, dt = time.monotonic(), loop.world.time, loop.world.dt
        with self._lock:
            if self._anchor is None:
                self._anchor = (now, t)
            anchor = self._anchor
        due_wall = anchor[0] + (t + dt - anchor[1]) / self.speed
        if due_wall > now:
            time.sleep(due_wall - now)
            now = time.monotonic()
        due = int(((now - anchor[0]) * self.speed - (t - anchor[1])) / dt + 1e-6)
        return max(1, min(n, due, BATCH_STEPS))

    def replace_loop(self, loop: Any) -> None:
        """A restarted run's loop (after :class:`Restart`)."""
        with self._lock:
            self.loop = loop
            self._restart = False
            self.ended = False
            self._anchor = None

    def wait_at_end(self) -> None:
        """The replay reached its end: publish the last state, say so, and wait for a seek
        (returns then) while serving the clients that subscribe."""
        self.ended = True
        self.live.publish_loop(self.loop, force=True)
        self._broadcast()
        while self.seek_ns is None:
            if self.live.refresh_due:
                self.live.publish_loop(self.loop, force=True)
            time.sleep(IDLE)


def start_live(prog: str, scene: Any, pacer: RealTimePacer, port: int, host: str, source: str,
               **options: Any) -> Any:
    """The started ``LiveServer`` of a headless run paced by `pacer` (and attached to it);
    LiveError if it cannot listen. Its log lines go to stderr as ``PROG: LEVEL: text``."""
    from .server import LiveServer
    pacer.live = LiveServer(scene, pacer.loop.joint_names, port, host,
                            world_frame=pacer.loop.config.marker_frame_id,
                            services=pacer.services(), name=prog, source=source,
                            log=lambda level, text: print(f'{prog}: {level}: {text}',
                                                          file=sys.stderr), **options).start()
    return pacer.live
