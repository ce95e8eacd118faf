"""Process entry helper: init, spin, and a clean shutdown on SIGINT/SIGTERM (no traceback)."""
from __future__ import annotations

import sys
from typing import Callable

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor


def wants_help(argv: list[str]) -> bool:
    """-h/--help before any --ros-args."""
    user = argv[1:argv.index("--ros-args")] if "--ros-args" in argv else argv[1:]
    return "-h" in user or "--help" in user


def run_node(make_node: Callable[[], object], argv: list[str] | None = None) -> int:
    """Create the node, spin it until SIGINT/SIGTERM or rclpy shutdown, then tear everything down in order."""
    argv = sys.argv if argv is None else argv
    rclpy.init(args=argv)      # rclpy installs SIGINT/SIGTERM handlers that shut the context down
    node = None
    executor = SingleThreadedExecutor()
    code = 0
    try:
        node = make_node()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:
        # A callback interrupted by SIGINT/SIGTERM fails on the already-invalid context: that is the shutdown,
        # not an error. Anything else (a bad parameter, a bad scene at startup) is one line, not a traceback.
        if rclpy.ok():
            print(f"error: {exc}", file=sys.stderr)
            code = 2
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            executor.remove_node(node)
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code
