# Source this file to keep ROS 2 / Fast DDS traffic on 127.0.0.1 in this shell:
#   source tools/loopback_env.sh            # ROS_DOMAIN_ID 42 unless already set
# Fast DDS 2.14 (Jazzy) reads FASTRTPS_DEFAULT_PROFILES_FILE, later releases
# FASTDDS_DEFAULT_PROFILES_FILE: both are set. Check with: ss -uanp | grep -v 127.0.0.1
_od_here=$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)
export FASTDDS_DEFAULT_PROFILES_FILE="$_od_here/../obstacle_detection/ros/fastdds_loopback.xml"
export FASTRTPS_DEFAULT_PROFILES_FILE="$_od_here/../obstacle_detection/ros/fastdds_loopback.xml"
export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-42}
unset ROS_LOCALHOST_ONLY ROS_AUTOMATIC_DISCOVERY_RANGE ROS_STATIC_PEERS _od_here
