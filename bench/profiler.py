"""Where a step's time goes: its compiled parts timed alone, the cost of a call from Python,
and a `perf` profile per compiled function.

    python bench/profiler.py step               # the parts of a step (docs/speed.md "What a step costs")
    python bench/profiler.py calls              # one World.step() call against the same step in step(n)
    python bench/profiler.py devices            # each compiler device's µs per step, with it and without it"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / 'lib'))
import dispatch  # noqa: E402

COMMANDS = {
    'step': ('step_profile', "each part of the compiled step timed in a compiled loop, µs per call"),
    'calls': ('call_cost', 'what one World.step() call costs beyond the same step inside World.step(n)'),
    'perf': ('perf_profile', "Linux perf samples of World.step(n), by compiled function"),
    'devices': ('devices', 'µs per step with and without each compiler device (jit/, the ring), side by side'),
}

if __name__ == '__main__':
    sys.exit(dispatch.run('bench/profiler.py', __doc__, COMMANDS))
