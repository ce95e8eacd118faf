"""flagbot_sim: a soft flagellated robot in granular media, as a ROS 2 virtual device."""
__version__ = "0.1.0"
