"""Names in the configuration are matched whole: ``$`` matches before a trailing newline, so a
pattern ``^...$`` took ``"map\\n"`` as a frame; each is anchored with ``\\A`` and ``\\Z`` (the ROS 2
section's frames, node name and namespace). Plain: no zenoh."""

from __future__ import annotations

import pytest

from services.config import NAMESPACE, ConfigError, load_config


@pytest.mark.parametrize(
    "field",
    ["ros2.map_frame", "ros2.odom_frame", "ros2.base_frame", "ros2.scan_frame", "ros2.imu_frame", "ros2.node_name"],
)
@pytest.mark.parametrize("value", ["map\n", "\nmap", "base_link\n"])
def test_a_name_with_a_newline_is_a_configuration_error_naming_the_field(field: str, value: str) -> None:
    with pytest.raises(ConfigError, match=field.split(".")[1]):
        load_config(overrides={field: value})


def test_a_namespace_with_a_trailing_newline_is_refused_and_a_plain_one_taken() -> None:
    assert NAMESPACE.pattern.startswith("\\A") and NAMESPACE.search("robot1\n") is None
    with pytest.raises(ConfigError, match="namespace"):
        load_config(overrides={"ros2.namespace": "robot1\n"})
    assert load_config(overrides={"ros2.namespace": "/fleet/robot1"}).ros2.namespace == "/fleet/robot1"
    assert load_config(overrides={"ros2.map_frame": "world"}).ros2.map_frame == "world"
