"""Topic and service names of the flagbot nodes, in one place (msg_docs/ documents each; a test compares).

Names without a leading slash are relative: they follow the node's namespace (``--ros-args -r __ns:=/bot1``).
"""
CMD_OMEGA = "cmd_omega"              # std_msgs/Float64, motor speed command omega_T (rad/s)
CLOCK = "/clock"                     # rosgraph_msgs/Clock, simulation time
HEAD_POSE = "head_pose"              # geometry_msgs/PoseStamped
ODOM = "odom"                        # nav_msgs/Odometry
JOINT_STATES = "joint_states"        # sensor_msgs/JointState: head_spin, flagella_spin
OMEGA_H = "omega_h"                  # std_msgs/Float64 (rad/s)
OMEGA_T = "omega_t"                  # std_msgs/Float64 (rad/s)
SPEED = "speed"                      # std_msgs/Float64 (m/s, positive = head first)
MARKERS = "markers"                  # visualization_msgs/MarkerArray
DIAGNOSTICS = "/diagnostics"         # diagnostic_msgs/DiagnosticArray
ROBOT_DESCRIPTION = "robot_description"   # std_msgs/String, URDF of head and plate (transient local)
# diagnostic_msgs/DiagnosticArray (transient local), one per restart of the simulated state: a ~/reset call or a
# rebuild (new scene, n_flagella or overrides); what lets `replay --resimulate` follow a run across it
RESETS = "resets"
# tf2_msgs/TFMessage, absolute as tf2 uses them: world -> head and the URDF's moving joints (each published step),
# its fixed joints (latched); sim_node publishes them where tf2_msgs is installed, a recording always has them
TF = "/tf"
TF_STATIC = "/tf_static"
BEAM_SPEED = "beam/speed"            # std_msgs/Float64 (m/s)
BEAM_OMEGA_H = "beam/omega_h"        # std_msgs/Float64 (rad/s)
BEAM_OMEGA_T = "beam/omega_t"        # std_msgs/Float64 (rad/s)

# services in the simulator node's own namespace (/sim_node/reset): two simulators do not collide
RESET = "~/reset"                    # std_srvs/Trigger
PAUSE = "~/pause"                    # std_srvs/SetBool

SIM_PUBLISHED = [CLOCK, HEAD_POSE, ODOM, JOINT_STATES, OMEGA_H, OMEGA_T, SPEED, MARKERS, DIAGNOSTICS,
                 ROBOT_DESCRIPTION, RESETS]
#: what sim_node publishes only where tf2_msgs is importable (and a recorder derives elsewhere)
SIM_TF = [TF, TF_STATIC]
BEAM_PUBLISHED = [BEAM_SPEED, BEAM_OMEGA_H, BEAM_OMEGA_T]
#: what the recorder records by default: every flagbot topic, the command stream and the clock
DEFAULT_RECORD_TOPICS = [CMD_OMEGA] + SIM_PUBLISHED + SIM_TF + BEAM_PUBLISHED


def node_overrides(n_flagella: int, scene_overrides) -> list[str]:
    """The scene overrides a node's parameters mean: its ``scene_overrides`` entries, then n_flagella unless it is
    0. Here, with the names, because the nodes (values.node_scene) and the re-simulation of their recordings
    (runs.resim) must read the parameters the same way, and the library may not import the ROS layer."""
    extra = [str(o) for o in scene_overrides if str(o).strip()]
    if n_flagella:
        extra.append(f"robot.n_flagella={int(n_flagella)}")
    return extra
