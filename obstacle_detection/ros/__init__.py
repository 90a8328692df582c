"""The ROS layer: messages to and from numpy, parameters, the frame gate, the node."""


class RosInputError(ValueError):
    """The ROS layer's one error: a message, stream or params file that cannot be used."""
