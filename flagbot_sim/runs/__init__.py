"""Recorded runs as data, a library (no ROS, no argparse): :mod:`.summary` (``bag-summary``'s omega_T steps and
their steady state, its text and plot) and :mod:`.resim` (re-simulation of a recording and its verdict). The
commands that print them are :mod:`flagbot_sim.commands.bag` and :mod:`flagbot_sim.commands.replay`.
"""
