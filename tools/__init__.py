"""The command lines, installed as the package ``obstacle_detection.tools`` (setup.py)."""
