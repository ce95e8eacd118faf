"""The virtual device: sim_node + beam_node on one scene, optionally a command profile and a recording.

    ros2 launch flagbot_sim flagbot.launch.py
    ros2 launch flagbot_sim flagbot.launch.py scene:=design2 n_flagella:=3 record:=run.mcap \
        profile:='steps 50:20,100:20,150:20 --rpm --sim-time'

    ros2 launch flagbot_sim flagbot.launch.py lifecycle:=true autostart:=true    # sim_node as a managed node

Launch arguments: scene (built-in name or .toml path), n_flagella (0 keeps the scene's), record (MCAP file; ''
records nothing), regime (beam_node's beam regime), real_time_factor (0 = as fast as possible), profile (the
arguments of cmd_profile, e.g. 'constant 100 --rpm'; '' starts no cmd_profile), lifecycle (true: sim_node as a
managed node, left unconfigured for an operator or a lifecycle manager), autostart (with lifecycle: configure
it, then activate it once inactive). Every parameter and executable named here is checked against the installed
package by tests/test_packaging.py.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from launch_ros.parameter_descriptions import ParameterValue
from lifecycle_msgs.msg import Transition

ARGUMENTS = [
    ("scene", "design1", "built-in scene name (design1, design2, clamped_flagellum) or path to a .toml scene"),
    ("n_flagella", "0", "number of flagella; 0 keeps the scene's value"),
    ("record", "", "MCAP file to record the run to ('' records nothing)"),
    ("regime", "nlb", "beam_node's beam regime: lb, nlb-nohead or nlb"),
    ("real_time_factor", "1.0", "simulated seconds per wall second; 0 = as fast as possible"),
    ("profile", "", "cmd_profile arguments, e.g. 'steps 50:20,100:20 --rpm --sim-time' ('' = no cmd_profile)"),
    ("lifecycle", "false", "true: sim_node as a managed (lifecycle) node, started unconfigured"),
    ("autostart", "false", "with lifecycle:=true, configure and then activate sim_node at launch"),
]


def _true(config, context) -> bool:
    return config.perform(context).strip().lower() in ("true", "1", "yes")


def _command_profile(context):
    """cmd_profile takes its profile as command-line words, which one launch argument carries as one string."""
    words = LaunchConfiguration("profile").perform(context).split()
    if not words:
        return []
    return [Node(package="flagbot_sim", executable="cmd_profile", name="cmd_profile", output="screen",
                 arguments=words)]


def _simulator(context):
    """sim_node, plain or managed; a managed one with autostart is configured at launch and activated once it
    reports the inactive state (the transitions a lifecycle manager would request)."""
    # typed parameter values: without a type, launch_ros reads the text as YAML, so '' would be refused (null)
    # and real_time_factor:=2 would arrive as an integer, which the node's double parameter refuses
    sim_parameters = [{"scene": ParameterValue(LaunchConfiguration("scene"), value_type=str),
                       "n_flagella": ParameterValue(LaunchConfiguration("n_flagella"), value_type=int),
                       "record": ParameterValue(LaunchConfiguration("record"), value_type=str),
                       "real_time_factor": ParameterValue(LaunchConfiguration("real_time_factor"),
                                                          value_type=float)}]
    if not _true(LaunchConfiguration("lifecycle"), context):
        return [Node(package="flagbot_sim", executable="sim_node", name="sim_node", output="screen",
                     parameters=sim_parameters)]
    # the node's class is chosen from its command line, so lifecycle goes there, not into the parameters file
    sim = LifecycleNode(package="flagbot_sim", executable="sim_node", name="sim_node", namespace="",
                        output="screen", parameters=sim_parameters, ros_arguments=["-p", "lifecycle:=true"])
    if not _true(LaunchConfiguration("autostart"), context):
        return [sim]

    def change(transition):
        return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(sim), transition_id=transition))
    return [sim,
            RegisterEventHandler(OnStateTransition(target_lifecycle_node=sim, start_state="configuring",
                                                   goal_state="inactive",
                                                   entities=[change(Transition.TRANSITION_ACTIVATE)])),
            change(Transition.TRANSITION_CONFIGURE)]


def generate_launch_description():
    scene = {"scene": ParameterValue(LaunchConfiguration("scene"), value_type=str),
             "n_flagella": ParameterValue(LaunchConfiguration("n_flagella"), value_type=int)}
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=doc) for name, default, doc in ARGUMENTS),
        OpaqueFunction(function=_simulator),
        Node(package="flagbot_sim", executable="beam_node", name="beam_node", output="screen",
             parameters=[{**scene, "regime": ParameterValue(LaunchConfiguration("regime"), value_type=str)}]),
        OpaqueFunction(function=_command_profile),
    ])
