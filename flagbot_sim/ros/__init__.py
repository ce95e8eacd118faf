"""ROS 2 layer: thin adapters between the physics/beam libraries and ROS messages. Imports rclpy."""
