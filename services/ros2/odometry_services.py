"""The bridge's odometry services, as ros2_controllers offers them: diff_drive_controller's
``~/set_odometry`` (control_msgs/srv/SetOdometry: x, y and yaw taken; z, roll and pitch ignored, as
upstream) and ``~/reset_odometry`` (std_srvs/srv/Empty, as tricycle_controller's: the pose (0, 0, 0)),
private names of the bridge's node (``/invent_bridge/set_odometry``), beside the shell
(services/ros2/service.py).

What they set is what those services set in ROS: ``odom -> base_link`` and ``/odom``, the bridge's
continuous odometry (services/ros2/core.py, ``ContinuousOdometry.set_pose``), at the bridge's next
tick; ``map -> odom`` takes the change, so ``map -> base_link`` does not move. The stack's own
odometry (``odometry/pose``, the pose in ``map`` the drive follows) is the odometry service's, set
on ``odometry/set_pose`` (docs/odometry.md). The reply says the request is taken, as upstream's
("Odometry set request accepted"): it applies at the next tick. Bad input (a request without
rmw_zenoh's attachment, malformed or oversized CDR, a pose not finite or beyond
``input.max_coordinate``) is counted under the service's key and refused: an error reply for the
reset (Empty's response cannot say no), ``success: false`` and why for the set; ``odom`` does not
move.
"""

from __future__ import annotations

from typing import Any

import zenoh

from schemas.codec import BadInput
from services.ros2 import interfaces
from services.ros2.action_calls import Tokens, caller_of, reply_error, request_payload, serve
from services.ros2.core import ContinuousOdometry
from services.ros2.graph import OdometryService
from services.runtime.node import Node

MAX_REQUEST_PAYLOAD = 64
"""Bytes of CDR a request may have: a SetOdometry request is 52, an Empty one 5."""


class OdometryServices:
    """One bridge's ``~/reset_odometry`` and ``~/set_odometry``."""

    def __init__(self, node: Node, tokens: Tokens, odometry: ContinuousOdometry) -> None:
        self.node = node
        self.odometry = odometry
        self.calls = {"reset": 0, "set": 0, "refused": 0}
        self.keys, self._queryables = serve(node, tokens, tokens.bridge.odometry_services, self._take_call)

    def _take_call(self, service: OdometryService, key: str, query: zenoh.Query) -> None:
        try:
            caller = caller_of(query, key)
        except BadInput as error:
            self._refused(key, str(error))
            reply_error(query, str(error))
            return
        setting = service is OdometryService.SET
        try:
            payload = request_payload(query, MAX_REQUEST_PAYLOAD, f"{service} request")
            request = interfaces.deserialize(
                payload, interfaces.SET_ODOMETRY_REQUEST if setting else interfaces.EMPTY_REQUEST
            )
            pose = (request.x, request.y, request.yaw) if setting else (0.0, 0.0, 0.0)
            self.odometry.set_pose(*pose)
        except BadInput as error:
            self._refused(key, str(error))
            if setting:
                caller.reply(_set_response(False, f"refused: {error}"))
            else:
                caller.refuse(str(error))
            return
        self.calls["set" if setting else "reset"] += 1
        self.node.log.info("%s: odom -> base_link to (%g, %g, %g) at the next tick", key, *pose)
        if setting:
            caller.reply(_set_response(True, "Odometry set request accepted"))
        else:
            caller.reply(interfaces.message_class(interfaces.EMPTY_RESPONSE)())

    def _refused(self, key: str, reason: str) -> None:
        self.node.bad_inputs.record(key, reason)
        self.calls["refused"] += 1

    def status(self) -> dict[str, Any]:
        return dict(self.calls)

    def close(self) -> None:
        for queryable in self._queryables:
            queryable.undeclare()


def _set_response(success: bool, message: str) -> Any:
    return interfaces.message_class(interfaces.SET_ODOMETRY_RESPONSE)(success=success, message=message)
