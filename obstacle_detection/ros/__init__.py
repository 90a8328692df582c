"""The ROS layer: messages to and from numpy, parameters, the frame gate, the node."""


class RosInputError(ValueError):
    """The ROS layer's one error: a message, stream or params file that cannot be used.

    kind: for a compressed depth image 'format', 'header', 'corrupt' or 'size'; else ''.
    """

    def __init__(self, message: str, kind: str = '') -> None:
        super().__init__(message)
        self.kind = kind
