"""Optional numba backend: the same step as the numpy core, compiled (docs/fast-backend.md).

`World(scene, backend=...)` takes 'auto' (default), 'numpy' or 'numba'; `resolve` turns that
into the backend a World uses:
- 'numpy': the reference implementation (world.py `_single`, solver/, terms/).
- 'numba': `fast.step.single`, one compiled call per (sub-)step. Raises if numba is missing
  or its kernels fail to compile; a model it does not support (a loop of more than 8 free
  bodies) keeps numpy, with a warning.
- 'auto': the environment variable ABD_BACKEND ('numpy' | 'numba') if set, else numba when
  it is importable AND its kernels have been compiled for these very files (a marker that
  `warm_up()` leaves beside numba's cache), else numpy with one warning per process. A cold
  compile takes ~45 s, far too long to happen silently inside a node's constructor or a
  test; `python -m abd_joint_sim.fast --warm-up` does it once per install (the scripts run it).
numba is imported lazily (on the first World), never by `import abd_joint_sim`.
`warm_up()` compiles (first run on a machine, ~1 min) or loads from numba's on-disk cache
(~1 s) every kernel, on a tiny scene.
"""
from __future__ import annotations

import hashlib
import importlib.metadata
import importlib.util
import os
from pathlib import Path
import sys
import time
import warnings

import numpy as np

BACKENDS = ('auto', 'numpy', 'numba')
ENV_VAR = 'ABD_BACKEND'

_state = {'available': None, 'reason': '', 'ready': False, 'warned': False, 'warm_up': None}


def _marker() -> Path:
    """Marker of a completed warm-up of exactly these kernel sources. numba's own cache index
    is keyed on the source files' modification times, so the marker is too (a copy made by
    an install gets a new mtime and needs its own warm-up)."""
    here = Path(__file__).resolve().parent
    key = hashlib.sha1()
    for name in ('kernels.py', 'step.py'):
        f = here / name
        st = f.stat()
        key.update(f.read_bytes())
        key.update(f'{st.st_mtime_ns}:{st.st_size}'.encode())
    key.update(importlib.metadata.version('numba').encode())
    key.update(sys.version.encode())
    return here / '__pycache__' / f'abd_fast_compiled_{key.hexdigest()[:16]}'


def compiled() -> bool:
    """True when `warm_up()` has completed for these kernel files (cheap: no numba import)."""
    try:
        return importlib.util.find_spec('numba') is not None and _marker().exists()
    except (OSError, importlib.metadata.PackageNotFoundError):
        return False


def _check_import() -> bool:
    if _state['available'] is None:
        try:
            import numba  # noqa: F401
            from . import kernels  # noqa: F401
            _state['available'] = True
        except Exception as exc:        # missing, or an incompatible numba/llvmlite/numpy
            _state['available'] = False
            _state['reason'] = f'numba is not importable ({type(exc).__name__}: {exc})'
    return _state['available']


def __getattr__(name):
    if name == 'AVAILABLE':             # lazy: importing numba takes ~1 s
        return _check_import()
    raise AttributeError(name)


def _tiny_scene():
    from ..scene import Scene
    box = dict(box=[0.2, 0.1, 0.1], density=1000.0)
    return Scene.from_dict(dict(
        dt=0.01, gravity=[0.0, 0.0, -9.81], integrator='bdf2',
        bodies=[dict(name='base', position=[0.0, 0.0, 0.0], fixed=True, **box),
                dict(name='a', position=[0.2, 0.0, 0.0], **box),
                dict(name='b', position=[0.4, 0.0, 0.0], **box)],
        joints=[dict(name='j1', parent='base', child='a', p0=[0.1, 0, -0.05], p1=[0.1, 0, 0.05],
                     external_torque=dict(torque=1.0, enabled=True),
                     driving=dict(aim_angle=0.5, enabled=True),
                     limit=dict(lower=-0.1, upper=0.1)),
                dict(name='j2', parent='a', child='b', p0=[0.3, 0, -0.05], p1=[0.3, 0, 0.05],
                     external_torque=dict(torque=-1.0, enabled=True))]))


def warm_up() -> dict:
    """Compile, or load from the on-disk cache, every kernel (one call of the whole-step
    kernel on a tiny scene, both linear-solve paths). Returns {'seconds', 'cache_hits'}.
    Raises ImportError if numba is not importable; compile errors propagate."""
    if not _check_import():
        raise ImportError(_state['reason'])
    from ..model import compile_scene
    from ..state import Control, State
    from . import kernels, step
    t0 = time.perf_counter()
    model = compile_scene(_tiny_scene())
    s, c = State.initial(model), Control.initial(model)
    pk = step.pack_model(model)
    for kind in (kernels.KIND_TREE, kernels.KIND_DENSE):
        pk.mi[6] = kind
        for bdf2 in (False, True):
            kernels.step_kernel(pk.mi, pk.mf, s.q, s.v, s.q_prev, s.v_prev, s.warm_start, s.joint_angle,
                                c.torque_value, c.torque_enabled, c.drive_aim, c.drive_enabled,
                                c.drive_passive, model.dt, bdf2, np.empty((3, model.body_count, 12)),
                                np.empty((2, model.joint_count)), pk.skipped, pk.info)
            kernels.batch_kernel(pk.mi, pk.mf, s.q, s.v, s.q_prev, s.v_prev, s.warm_start,
                                 s.joint_angle, c.torque_value, c.torque_enabled, c.drive_aim,
                                 c.drive_enabled, c.drive_passive, model.dt, bdf2, bdf2, 2, 1.0,
                                 1.0, np.empty((2, 3, model.body_count, 12)),
                                 np.empty((2, 2, model.joint_count)), pk.skipped, np.empty((2, 7)))
    hits = sum(sum(d.stats.cache_hits.values()) for d in (kernels.step_kernel, kernels.batch_kernel))
    out = {'seconds': time.perf_counter() - t0, 'cache_hits': hits}
    _state['warm_up'] = out
    try:
        marker = _marker()
        marker.parent.mkdir(exist_ok=True)
        marker.write_text(f'{out}\n')
    except OSError:            # read-only install: numba could not cache either
        pass
    return out


def _usable() -> bool:
    """numba importable and its kernels compiled/loaded (once per process)."""
    if not _state['ready']:
        if not _check_import():
            return False
        try:
            warm_up()
        except Exception as exc:
            _state['available'] = False
            _state['reason'] = f'numba kernels failed to compile ({type(exc).__name__}: {exc})'
            return False
        _state['ready'] = True
    return True


def _warn_once(msg):
    if not _state['warned']:
        _state['warned'] = True
        warnings.warn(msg, RuntimeWarning, stacklevel=4)


def resolve(requested, model) -> str:
    """The backend ('numpy' | 'numba') a World of `model` uses when `requested` is asked."""
    if requested not in BACKENDS:
        raise ValueError(f'backend {requested!r}: must be one of {", ".join(BACKENDS)}')
    explicit = requested != 'auto'
    if requested == 'auto':
        env = os.environ.get(ENV_VAR, '').strip().lower()
        if env and env not in BACKENDS:
            raise ValueError(f'{ENV_VAR}={env!r}: must be one of {", ".join(BACKENDS)}')
        if env in ('numpy', 'numba'):
            requested, explicit = env, True
    if requested == 'numpy':
        return 'numpy'
    if not explicit and _check_import() and not _state['ready'] and not compiled():
        _warn_once('the numba kernels are not compiled for this install yet; using the numpy '
                   'backend (run `python -m abd_joint_sim.fast --warm-up` once, ~1 min)')
        return 'numpy'
    if not _usable():
        if explicit:
            raise RuntimeError(f'backend numba requested but {_state["reason"]}')
        _warn_once(f'{_state["reason"]}; using the numpy backend '
                   '(pip install -r requirements-fast.txt for the fast one)')
        return 'numpy'
    from .step import supports
    if not supports(model):
        if explicit:
            warnings.warn('numba backend: this scene has a loop of more than 8 free bodies, '
                          'which only the numpy linear solvers handle; using numpy',
                          RuntimeWarning, stacklevel=3)
        return 'numpy'
    return 'numba'
