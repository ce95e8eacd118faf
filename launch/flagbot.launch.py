"""The virtual device: sim_node + beam_node on one scene, optionally a command profile and a recording.

    ros2 launch flagbot_sim flagbot.launch.py
    ros2 launch flagbot_sim flagbot.launch.py scene:=design2 n_flagella:=3 record:=run.mcap \
        profile:='steps 50:20,100:20,150:20 --rpm --sim-time'

Launch arguments: scene (built-in name or .toml path), n_flagella (0 keeps the scene's), record (MCAP file; ''
records nothing), regime (beam_node's beam regime), real_time_factor (0 = as fast as possible), profile (the
arguments of cmd_profile, e.g. 'constant 100 --rpm'; '' starts no cmd_profile). Every parameter and executable
named here is checked against the installed package by tests/test_packaging.py.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

ARGUMENTS = [
    ("scene", "design1", "built-in scene name (design1, design2, clamped_flagellum) or path to a .toml scene"),
    ("n_flagella", "0", "number of flagella; 0 keeps the scene's value"),
    ("record", "", "MCAP file to record the run to ('' records nothing)"),
    ("regime", "nlb", "beam_node's beam regime: lb, nlb-nohead or nlb"),
    ("real_time_factor", "1.0", "simulated seconds per wall second; 0 = as fast as possible"),
    ("profile", "", "cmd_profile arguments, e.g. 'steps 50:20,100:20 --rpm --sim-time' ('' = no cmd_profile)"),
]


def _command_profile(context):
    """cmd_profile takes its profile as command-line words, which one launch argument carries as one string."""
    words = LaunchConfiguration("profile").perform(context).split()
    if not words:
        return []
    return [Node(package="flagbot_sim", executable="cmd_profile", name="cmd_profile", output="screen",
                 arguments=words)]


def generate_launch_description():
    # typed parameter values: without a type, launch_ros reads the text as YAML, so '' would be refused (null)
    # and real_time_factor:=2 would arrive as an integer, which the node's double parameter refuses
    scene = {"scene": ParameterValue(LaunchConfiguration("scene"), value_type=str),
             "n_flagella": ParameterValue(LaunchConfiguration("n_flagella"), value_type=int)}
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=doc) for name, default, doc in ARGUMENTS),
        Node(package="flagbot_sim", executable="sim_node", name="sim_node", output="screen",
             parameters=[{**scene,
                          "record": ParameterValue(LaunchConfiguration("record"), value_type=str),
                          "real_time_factor": ParameterValue(LaunchConfiguration("real_time_factor"),
                                                             value_type=float)}]),
        Node(package="flagbot_sim", executable="beam_node", name="beam_node", output="screen",
             parameters=[{**scene, "regime": ParameterValue(LaunchConfiguration("regime"), value_type=str)}]),
        OpaqueFunction(function=_command_profile),
    ])
