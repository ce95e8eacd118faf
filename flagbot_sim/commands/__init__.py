"""The ``flagbot`` commands (and the ``replay`` console script): one module per command, each with a
``register(subparsers)`` that adds its arguments and a ``cmd_*(args)`` that parses them, calls libraries and
prints. Nothing below this layer imports it: only :mod:`flagbot_sim.cli` (through importlib, by name) and
:mod:`flagbot_sim.console` do (docs/architecture.md; tests/test_import_graph.py keeps it so).
"""
