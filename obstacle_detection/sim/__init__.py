"""The scene generator: primitives, truth, sensor noise, the renderer, named scenes, sequences."""
