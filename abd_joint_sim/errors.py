"""One exception type per subsystem; messages name the value and what was done."""


class SceneError(ValueError):
    """A scene file or dict is invalid. The message names the source, the field and why."""


class SimulationError(RuntimeError):
    """A step could not produce a finite state even after sub-stepping.

    The world's state is left at the last good step, so nothing recorded is lost.
    """
