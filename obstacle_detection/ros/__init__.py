"""The ROS layer: messages to and from numpy, parameters, the frame gate, the node.

Only :mod:`.node` imports rclpy; the other modules use message types alone, so they serve
the offline bag tools as well.
"""
