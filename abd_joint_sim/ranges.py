"""The sane range of every number a scene carries: beyond it, a SceneError (docs/robustness.md)."""

RANGES = {
    # name: (lowest, highest, unit); positive quantities must lie in [lowest, highest],
    # signed ones in magnitude below highest. Far wider than any mechanism needs, and
    # narrow enough that the solver's arithmetic (masses ~ density * size^3, stiffness ~
    # kappa * volume / dt^2, 1/dt) stays inside float64 with digits to spare.
    'dt': (1e-6, 1.0, 's'),
    'gravity': (0.0, 1e4, 'm/s^2'),
    'length': (1e-4, 1e3, 'm'),
    'position': (0.0, 1e4, 'm'),
    'angle': (0.0, 1e4, 'rad'),
    'speed': (0.0, 1e4, 'm/s'),
    'angular_speed': (0.0, 1e4, 'rad/s'),
    'density': (1e-6, 1e12, 'kg/m^3'),
    'mass': (1e-12, 1e15, 'kg'),
    'inertia': (0.0, 1e9, 'kg m^2'),
    'volume': (1e-12, 1e9, 'm^3'),
    'kappa': (1.0, 1e16, 'Pa'),
    'strength': (1e-6, 1e9, ''),
    'torque': (0.0, 1e9, 'N m'),
    'effort_limit': (1e-9, 1e9, 'N m'),
    'damping': (0.0, 1e9, 'N m s/rad'),
    'force': (0.0, 1e9, 'N'),
    'force_limit': (1e-9, 1e9, 'N'),
    'slide_damping': (0.0, 1e9, 'N s/m'),
    'tolerance': (1e-12, 1e3, ''),
}
