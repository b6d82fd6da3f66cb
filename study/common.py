"""Small helpers shared by the studies: paths, Markdown tables, optional matplotlib."""
from __future__ import annotations

import csv
import math
import os
import platform
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:          # run as `python study/x.py` from a checkout
    sys.path.insert(0, str(REPO))


#: what the studies record in their 'backend' column: the one compiled implementation
BACKEND = 'compiled'


def make_world(scene_dict):
    """A World for a scene dict."""
    from abd_joint_sim import Scene, World
    return World(Scene.from_dict(scene_dict))


def backend_note(used=()):
    """One line naming the implementation, for the summaries."""
    import numba
    return (f'Physics: the compiled step (numba {numba.__version__}; '
            '`python -m abd_joint_sim.jit.warmup` compiles it once per machine).')


def pyplot():
    """matplotlib.pyplot with the Agg backend, or None when matplotlib is not installed."""
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def fmt(x, digits=3):
    if isinstance(x, bool):
        return 'yes' if x else 'no'
    if isinstance(x, float):
        if math.isnan(x):
            return 'nan'
        if x == 0.0:
            return '0'
        if abs(x) >= 1e4 or abs(x) < 1e-2:
            return f'{x:.{digits - 1}e}'
        return f'{x:.{digits}g}'
    return str(x)


def md_table(rows, columns, headers=None):
    headers = headers or columns
    out = ['| ' + ' | '.join(headers) + ' |', '|' + '---|' * len(columns)]
    for r in rows:
        out.append('| ' + ' | '.join(fmt(r.get(c, '')).replace('|', '/') for c in columns) + ' |')
    return '\n'.join(out)


def write_csv(path, rows, columns):
    with open(path, 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=columns, extrasaction='ignore')
        w.writeheader()
        for r in rows:
            w.writerow({c: (repr(r[c]) if isinstance(r.get(c), float) else r.get(c, '')) for c in columns})


def machine():
    import numpy
    import scipy
    return (f'Python {platform.python_version()}, numpy {numpy.__version__}, scipy {scipy.__version__}, '
            f'{platform.machine()}, {os.cpu_count()} CPU(s) (shared)')
