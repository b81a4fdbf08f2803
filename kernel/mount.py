"""Where the camera sits on the robot (design §2 "The mount").

The method's bearings are measured from the camera, its motion from the base's odometry,
which reports the robot's rotation centre. With the camera at ``T_robot_camera`` (ahead
of the centre, or turned) a turn in place moves the camera along an arc that the
robot's odometry calls no motion at all. So the method works in the camera's poses: the
odometry it is handed is the camera's, ``odom_T_camera = odom_T_robot ∘ T_robot_camera``
(learning, the depth EKF, the sensor models and the map's transitions all see the
camera move), and a place's frame is the camera's pose at its reference. The robot's
own pose is given out, and taken in, at the service's edge: ``T_x_robot = T_x_camera ∘
T_robot_camera⁻¹`` (the map → odom transform is the same either way).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from kernel.angles import wrap_angle
from kernel.se2 import SE2, UncertainSE2, compose_many
from kernel.types import Odometry


@dataclass(frozen=True)
class Mount:
    """``T_robot_camera``: the camera's position (m) and yaw (rad) in the robot's frame."""

    robot_camera: SE2 = SE2()

    @property
    def centred(self) -> bool:
        return self.robot_camera == SE2()

    def camera_odometry(self, samples: list[Odometry]) -> list[Odometry]:
        """The camera's odometry from the robot's: odom_T_camera = odom_T_robot ∘ M."""
        if self.centred:
            return samples
        out = []
        for s in samples:
            x, y, yaw = SE2(s.x, s.y, s.yaw).compose(self.robot_camera).as_tuple()
            out.append(dataclasses.replace(s, x=x, y=y, yaw=yaw))
        return out

    def robot_odometry(self, camera: Odometry) -> Odometry:
        """The inverse of :meth:`camera_odometry` for one sample."""
        x, y, yaw = SE2(camera.x, camera.y, camera.yaw).compose(
            self.robot_camera.inverse()).as_tuple()
        return dataclasses.replace(camera, x=x, y=y, yaw=yaw)

    def robot_pose(self, camera_pose: SE2) -> SE2:
        """T_x_robot of T_x_camera."""
        return camera_pose.compose(self.robot_camera.inverse())

    def robot_poses(self, camera_poses: np.ndarray) -> np.ndarray:
        """:meth:`robot_pose` of N x 3 (x, y, yaw) poses at once (a particle cloud)."""
        if self.centred:
            return camera_poses
        p = np.asarray(camera_poses, dtype=float)
        x, y, yaw = compose_many((p[:, 0], p[:, 1], p[:, 2]),
                                 self.robot_camera.inverse().as_tuple())
        return np.stack([x, y, np.asarray(wrap_angle(yaw))], axis=1)

    def camera_pose(self, robot_pose: SE2) -> SE2:
        """T_x_camera of T_x_robot."""
        return robot_pose.compose(self.robot_camera)

    def robot_estimate(self, camera_pose: SE2, covariance: np.ndarray
                       ) -> tuple[SE2, np.ndarray]:
        """The robot's pose and its covariance from the camera's (first order: the yaw's
        uncertainty swings the robot's centre round the camera on the lever arm)."""
        robot = UncertainSE2(camera_pose, covariance).compose(
            UncertainSE2(self.robot_camera.inverse()))
        return robot.mean, robot.covariance

    def robot_in_robot_frame(self, camera_in_place: SE2) -> SE2:
        """The robot's pose relative to its own pose at a place's reference, from the
        camera's pose in the place's frame (the camera's at the reference): M ∘ p ∘ M⁻¹
        (for comparing with a truth kept in the robot's poses)."""
        return self.robot_camera.compose(camera_in_place).compose(self.robot_camera.inverse())
