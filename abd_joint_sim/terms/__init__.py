from .base import EnergyTerm, StepContext  # noqa: F401
