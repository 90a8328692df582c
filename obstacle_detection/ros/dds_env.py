"""The loopback-only DDS environment for every process of ours that starts rclpy."""

from __future__ import annotations

import os
from pathlib import Path

LOOPBACK_PROFILE = Path(__file__).resolve().parent / 'fastdds_loopback.xml'

#: Variables that would override the profile's locators in ways it does not expect.
CONFLICTING = ('ROS_LOCALHOST_ONLY', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS')


def loopback_env(domain_id: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """Return a full environment (``base`` or os.environ) keeping DDS on 127.0.0.1."""
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
