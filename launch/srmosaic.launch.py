"""`ros2 launch srmosaic_ros srmosaic.launch.py namespace:=uav1`: the graph of srmosaic.launch.xml
(its arguments: namespace, params_file, georef_standalone, sr, map), for setups that launch Python files."""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import AnyLaunchDescriptionSource


def generate_launch_description() -> LaunchDescription:
    xml = os.path.join(get_package_share_directory('srmosaic_ros'), 'launch', 'srmosaic.launch.xml')
    return LaunchDescription([IncludeLaunchDescription(AnyLaunchDescriptionSource(xml))])
