"""sim_node under load: its real-time factor and per-step cost, a command flood over DDS, a
long soak, and the size and cost of the body markers.

    python bench/node_load.py rtf               # docs/speed.md "Through sim_node"
    python bench/node_load.py flood             # docs/robustness.md's flood figures"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / 'lib'))
import dispatch  # noqa: E402

COMMANDS = {
    'rtf': ('node_rtf', "sim_node's µs per step in one process and its real-time factor end to end"),
    'flood': ('flood', 'torque commands at kHz rates from another process; lag, memory, RTF'),
    'soak': ('soak', 'many steps with changing commands (headless, or --node over DDS); memory, drift'),
    'markers': ('markers', 'bytes per simulated second recorded with and without markers; build cost'),
    'live': ('live_cost', "the live view's share of a step (nobody connected, one client), the RTF "
                          'with one client, publish-to-page latency in headless chromium (docs/live.md)'),
}

if __name__ == '__main__':
    sys.exit(dispatch.run('bench/node_load.py', __doc__, COMMANDS))
