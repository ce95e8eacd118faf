"""See the robot: a live 3-D view in Foxglove and the paper's Fig. 1 snapshots.

- :mod:`.geometry`   :class:`RobotGeometry`, the drawable shape at one instant (from a simulation or a recording);
                     pure numpy;
- :mod:`.scene_msgs` Foxglove messages of it (SceneUpdate, FrameTransforms, the plotted numbers): ``[view]`` extra;
- :mod:`.live`       :class:`~.live.LiveView`, the Foxglove WebSocket server (``flagbot run --view``, sim_node);
- :mod:`.replay`     a recording played into a LiveView (``flagbot replay --view``), no ROS needed;
- :mod:`.render`     the paper's Fig. 1 layout drawn with matplotlib, and its GIF (the ``flagbot render`` command is
                     :mod:`flagbot_sim.commands.render`);
- :mod:`.cli`        the live view of ``flagbot run --view`` and ``flagbot replay --view``; :mod:`.args` their options.

Nothing here imports ROS; only :mod:`.scene_msgs` and :mod:`.live` need foxglove-sdk, and only when used.
"""
__all__ = ["RobotGeometry"]


def __getattr__(name):        # lazily: the --view options (view.args) must not import the geometry
    if name == "RobotGeometry":
        from .geometry import RobotGeometry
        return RobotGeometry
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
