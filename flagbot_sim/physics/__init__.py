"""Discrete-elastic-rod model of the flagellated robot. numpy/scipy only: no ROS imports here."""
from .model import RobotModel, State
from .simulation import Simulation
from .stepper import StepFailed, Stepper, StepStats

__all__ = ["RobotModel", "State", "Simulation", "StepFailed", "Stepper", "StepStats"]
