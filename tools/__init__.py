"""The command lines, installed as the package ``obstacle_detection.tools`` (setup.py).

Each module is one command (``ros2 run obstacle_detection <name>``, ``.venv/bin/<name>``,
``python tools/<name>.py``): it validates its arguments, calls the library and returns an exit
code. The file stays so the editable install (PEP 660) maps ``obstacle_detection.tools`` here;
nothing imports a top-level ``tools``.
"""
