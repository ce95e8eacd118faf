"""The Foxglove layout shipped with the package (:data:`~.live.LAYOUT_FILE`): the 3-D robot and its plots at once.

The file is this module's :func:`layout` written as JSON (``python -m flagbot_sim.view.layout`` rewrites it; a
test checks the shipped file is current and names only topics and fields the live view publishes). It is in the
format the Foxglove app's Layouts -> Import from file reads (``configById`` + a ``layout`` split tree, as the app
exports). Left: a 3-D panel following the head's position (not its spin: the head turns at up to omega_T) with a
5 cm grid; right: omega_T / omega_h / omega_t, the forward speed v and the motor torque against simulated time.
"""
from __future__ import annotations

import json
import sys

from .live import LAYOUT_FILE, TOPIC_SCENE, TOPIC_STATE, TOPIC_TF, TOPIC_TUBE

THREE_D = "3D!flagbot"
PLOT_RATES = "Plot!flagbot_rates"
PLOT_SPEED = "Plot!flagbot_speed"
PLOT_TORQUE = "Plot!flagbot_torque"


def _plot(title: str, fields: list[tuple[str, str]]) -> dict:
    return {"title": title,
            "paths": [{"value": f"{TOPIC_STATE}.{f}", "enabled": True, "timestampMethod": "receiveTime",
                       "label": label} for f, label in fields],
            "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True, "legendDisplay": "floating",
            "showPlotValuesInLegend": True, "isSynced": True, "xAxisVal": "timestamp", "sidebarDimension": 240}


def layout() -> dict:
    return {
        "configById": {
            THREE_D: {
                "cameraState": {"distance": 0.45, "perspective": True, "phi": 60.0, "thetaOffset": 35.0,
                                "target": [0.0, 0.0, 0.0], "targetOffset": [-0.07, 0.0, 0.0],
                                "targetOrientation": [0.0, 0.0, 0.0, 1.0], "fovy": 45.0, "near": 0.005,
                                "far": 50.0},
                "followMode": "follow-position",
                "followTf": "head",
                "fixedFrame": "world",
                "scene": {"backgroundColor": "#15171c", "transforms": {"showLabel": False, "axisSize": 0.03}},
                "topics": {TOPIC_SCENE: {"visible": True}, TOPIC_TUBE: {"visible": True},
                           TOPIC_TF: {"visible": True}},
                "layers": {"grid": {"visible": True, "instanceId": "grid", "layerId": "foxglove.Grid",
                                    "label": "Grid (5 cm)", "frameId": "world", "size": 1.0, "divisions": 20,
                                    "lineWidth": 1, "color": "#ffffff30", "position": [0.3, 0.0, -0.06],
                                    "rotation": [0, 0, 0], "frameLocked": True}},
            },
            PLOT_RATES: _plot("spin rates (rad/s)", [("omega_T", "omega_T"), ("omega_h", "omega_h (head)"),
                                                     ("omega_t", "omega_t (flagella)")]),
            PLOT_SPEED: _plot("forward speed v (m/s)", [("v", "v")]),
            PLOT_TORQUE: _plot("motor torque (N m)", [("motor_torque", "motor torque")]),
        },
        "globalVariables": {},
        "userNodes": {},
        "linkedGlobalVariables": [],
        "playbackConfig": {"speed": 1.0, "messageOrder": "receiveTime"},
        "layout": {"direction": "row", "first": THREE_D, "splitPercentage": 62,
                   "second": {"direction": "column", "first": PLOT_RATES, "splitPercentage": 40,
                              "second": {"direction": "column", "first": PLOT_SPEED, "second": PLOT_TORQUE,
                                         "splitPercentage": 50}}},
    }


def text() -> str:
    return json.dumps(layout(), indent=2, allow_nan=False) + "\n"


if __name__ == "__main__":
    if sys.argv[1:]:                  # --help or anything else: say what it does, write nothing
        print(f"usage: python -m flagbot_sim.view.layout\n\nrewrites {LAYOUT_FILE} from this module (no arguments)",
              file=sys.stderr)
        sys.exit(0 if sys.argv[1:] in (["-h"], ["--help"]) else 2)
    LAYOUT_FILE.write_text(text())
    print(f"wrote {LAYOUT_FILE}", file=sys.stderr)
