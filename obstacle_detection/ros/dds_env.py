"""The loopback-only DDS environment for every process of ours that starts rclpy.

Fast DDS announces itself by multicast on every interface by default; the profile
``fastdds_loopback.xml`` beside this module keeps discovery and data on 127.0.0.1. The Fast DDS
2.14 of the ROS 2 Jazzy wheels reads only ``FASTRTPS_DEFAULT_PROFILES_FILE``, later releases
``FASTDDS_DEFAULT_PROFILES_FILE``: both are set. The demo and the tests use this function
(``tools/loopback_env.sh`` does the same for a shell).
"""

from __future__ import annotations

import os
from pathlib import Path

LOOPBACK_PROFILE = Path(__file__).resolve().parent / 'fastdds_loopback.xml'

#: Variables that would override the profile's locators in ways it does not expect.
CONFLICTING = ('ROS_LOCALHOST_ONLY', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS')


def loopback_env(domain_id: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """Return a full environment (``base`` or os.environ) keeping DDS on 127.0.0.1.

    domain_id: the ROS_DOMAIN_ID, one of the caller's own (0-232).
    """
    env = dict(os.environ if base is None else base)
    env.update({
        'FASTDDS_DEFAULT_PROFILES_FILE': str(LOOPBACK_PROFILE),
        'FASTRTPS_DEFAULT_PROFILES_FILE': str(LOOPBACK_PROFILE),
        'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp',
        'ROS_DOMAIN_ID': str(domain_id),
    })
    for name in CONFLICTING:
        env.pop(name, None)
    return env
