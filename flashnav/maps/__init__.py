"""Occupancy maps: the grid type, ROS map_server I/O, a seeded generator and the bundled maps."""

from flashnav.maps.grid import OccupancyMap
from flashnav.maps.ros import load_ros_map, save_ros_map
from flashnav.maps.bundled import bundled_map, bundled_map_names, resolve_map

__all__ = [
    "OccupancyMap",
    "load_ros_map",
    "save_ros_map",
    "generate_map",
    "bundled_map",
    "bundled_map_names",
    "resolve_map",
]


def __getattr__(name: str):
    # imported on first use: reading maps needs none of the generator
    if name == "generate_map":
        from flashnav.maps.clutter import generate_map

        return generate_map
    raise AttributeError(name)
