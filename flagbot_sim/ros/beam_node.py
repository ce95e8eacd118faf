"""beam_node: the paper's beam-theory prediction for the current motor command, for comparison with sim_node.

Subscribes to ``cmd_omega`` and publishes the predicted head speed and the split of omega_T into head and
flagellar spin under ``beam/``. Solves run in a worker thread with a cache keyed by omega_T, so the executor is
never blocked; outputs are latched (transient local) so late subscribers get the current prediction.
"""
from __future__ import annotations

import math
import sys
import threading
from collections import OrderedDict

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from ..beam import REGIMES, BeamParams, solve_balance
from ..scene import SceneError
from . import convert
from .. import topics as names
from ..values import ParamSpec, command_refusal, node_scene, one_line, refusal
from .params import declare, help_text, scene_request
from .runtime import run_node, wants_help

PARAMS = [
    ParamSpec("scene", "design1", "built-in scene name or path to a .toml scene file"),
    ParamSpec("n_flagella", 0, "number of flagella; 0 keeps the scene's value", range=(0, 12)),
    ParamSpec("scene_overrides", [], "scene values to override, each 'section.key=value'"),
    ParamSpec("regime", "nlb", "beam regime", choices=REGIMES),
    ParamSpec("initial_omega", 0.0, "motor speed assumed before the first cmd_omega", "rad/s", range=(-1e4, 1e4)),
    ParamSpec("publish_rate", 10.0, "rate at which the current prediction is republished (wall clock)", "Hz",
              range=(0.1, 100.0)),
    ParamSpec("max_omega", 50.0, "largest |cmd_omega| accepted", "rad/s", range=(1e-3, 1e4)),
]
CACHE_SIZE = 4096


class BeamNode(Node):
    def __init__(self):
        super().__init__("beam_node")
        declare(self, PARAMS)
        p = {s.name: self.get_parameter(s.name).value for s in PARAMS}
        self.params = BeamParams.for_free_robot(node_scene(p["scene"], p["n_flagella"], p["scene_overrides"]))
        self.regime = p["regime"]
        self.max_omega = p["max_omega"]
        self._cache: OrderedDict = OrderedDict()
        self._lock = threading.Condition()
        self._wanted = float(p["initial_omega"])
        self._result = None            # (omega_T, BalanceResult) last good prediction
        self._last_error = ""
        self._stop = False
        self.rejected = 0
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_speed = self.create_publisher(Float64, names.BEAM_SPEED, latched)
        self.pub_omega_h = self.create_publisher(Float64, names.BEAM_OMEGA_H, latched)
        self.pub_omega_t = self.create_publisher(Float64, names.BEAM_OMEGA_T, latched)
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, QoSProfile(depth=10))
        self.create_subscription(Float64, names.CMD_OMEGA, self._on_cmd, QoSProfile(depth=10))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.timer = self.create_timer(1.0 / p["publish_rate"], self._publish)
        self.diag_timer = self.create_timer(1.0, self._publish_diagnostics)
        self.worker = threading.Thread(target=self._work, name="beam-solver", daemon=True)
        self.worker.start()
        self.get_logger().info(f"beam theory ({self.regime}) for n = {self.params.n}; waiting for {names.CMD_OMEGA}")

    # ------------------------------------------------------------------ input
    def _on_cmd(self, msg: Float64) -> None:
        w = msg.data
        why = command_refusal(w, self.max_omega)
        if why is not None:
            self.rejected += 1
            self.get_logger().warn(f"rejected {names.CMD_OMEGA} = {w!r} rad/s: {why}", throttle_duration_sec=2.0)
            return
        with self._lock:
            self._wanted = w
            self._lock.notify()

    def _on_set_parameters(self, params) -> SetParametersResult:
        new = {p.name: p.value for p in params}
        reason = refusal(PARAMS, new)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        try:
            scene = scene_request(self, new)
            bp = None if scene is None else BeamParams.for_free_robot(scene)
        except SceneError as exc:
            return SetParametersResult(successful=False, reason=one_line(str(exc)))
        except Exception as exc:  # noqa: BLE001 - no value may kill the node: refuse what was not foreseen
            return SetParametersResult(successful=False, reason=one_line(f"{type(exc).__name__}: {exc}"))
        with self._lock:
            if bp is not None:
                self.params = bp
            if "regime" in new:
                self.regime = new["regime"]
            if "max_omega" in new:
                self.max_omega = new["max_omega"]
            if bp is not None or "regime" in new:
                self._cache.clear()
                self._result = None
                self._lock.notify()
        if "publish_rate" in new:
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(1.0 / new["publish_rate"], self._publish)
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ solving
    def predict(self, omega_T: float):
        """Cached balance solve (the library call; runs in the worker thread)."""
        key = (self.regime, self.params, round(omega_T, 12))
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        res = solve_balance(self.params, omega_T, regime=self.regime, raise_on_failure=False)
        self._cache[key] = res
        if len(self._cache) > CACHE_SIZE:
            self._cache.popitem(last=False)
        return res

    def _work(self) -> None:
        while True:
            with self._lock:
                while not self._stop and self._result is not None and self._result[0] == self._wanted:
                    self._lock.wait()
                if self._stop:
                    return
                omega = self._wanted
            res = self.predict(omega)
            with self._lock:
                if res.converged and all(math.isfinite(x) for x in (res.v_h, res.omega_h, res.omega_t)):
                    self._result = (omega, res)
                    self._last_error = ""
                else:
                    self._result = (omega, self._result[1] if self._result else None)
                    self._last_error = f"no beam prediction at omega_T = {omega:g} rad/s: {res.message}"
                    self.get_logger().error(self._last_error, throttle_duration_sec=5.0)
            try:
                self._publish()
            except Exception:          # the context was shut down under us (SIGINT/SIGTERM): just stop
                if rclpy.ok():
                    raise
                return

    # ------------------------------------------------------------------ output
    def _publish(self) -> None:
        with self._lock:
            r = self._result[1] if self._result else None
        if r is None:
            return
        self.pub_speed.publish(convert.float_msg(r.v_h))
        self.pub_omega_h.publish(convert.float_msg(r.omega_h))
        self.pub_omega_t.publish(convert.float_msg(r.omega_t))

    def _publish_diagnostics(self) -> None:
        with self._lock:
            omega, r = self._result if self._result else (self._wanted, None)
            err = self._last_error
        level = "ERROR" if err else "OK"
        values = {"regime": self.regime, "n_flagella": self.params.n, "omega_T_rad_s": f"{omega:.6g}",
                  "rejected_commands": self.rejected, "cached_solutions": len(self._cache)}
        if r is not None:
            values.update(v_h_m_s=f"{r.v_h:.6g}", omega_h_rad_s=f"{r.omega_h:.6g}", omega_t_rad_s=f"{r.omega_t:.6g}",
                          w_tip_over_L=f"{r.w_tip_over_L:.4g}", bvp_solves=r.bvp_solves)
        stamp_t = self.get_clock().now().nanoseconds * 1e-9
        self.pub_diag.publish(convert.diagnostics_msg(stamp_t, "flagbot_sim: beam", level, err or "ok", values))

    def close(self) -> None:
        with self._lock:
            self._stop = True
            self._lock.notify()
        self.worker.join(timeout=5.0)


def main(argv: list[str] | None = None) -> int:
    process_exit = argv is None             # the console script / python -m: the process ends with this
    argv = sys.argv if argv is None else argv
    if wants_help(argv):
        print(help_text("beam_node", __doc__.strip().splitlines()[0], PARAMS,
                        "topics: sub cmd_omega; pub beam/speed, beam/omega_h, beam/omega_t, /diagnostics"))
        return 0
    return run_node(BeamNode, argv, process_exit=process_exit)


if __name__ == "__main__":
    sys.exit(main())
