"""Discrete-elastic-rod model of the flagellated robot. numpy/scipy/numba only: no ROS imports here.

The names below load on first use, so that importing a submodule (``physics.effects`` for the scene's list of
effects) does not build the whole simulator.
"""
from importlib import import_module

_EXPORTS = {"RobotModel": "model", "State": "model", "Simulation": "simulation", "StepFailed": "stepper",
            "Stepper": "stepper", "StepStats": "stepper", "Snapshot": "observe"}

__all__ = list(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
