"""A zenoh router of whatever eclipse-zenoh release runs it (1.6.2 in
tests/test_ros2_zenoh_releases.py), standing in for the ``rmw_zenohd`` an rmw_zenoh release bundles:
a session in router mode, multicast scouting off, listening on the one endpoint given. It prints
``listening on <endpoint>`` once it does, and closes its session when its standard input ends::

    python tests/zenoh_release_router.py tcp/127.0.0.1:7447
"""

from __future__ import annotations

import json
import sys

import zenoh


def main() -> int:
    (endpoint,) = sys.argv[1:]
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    with zenoh.open(config):
        print(f"listening on {endpoint}", flush=True)
        sys.stdin.read()
    return 0


if __name__ == "__main__":
    sys.exit(main())
