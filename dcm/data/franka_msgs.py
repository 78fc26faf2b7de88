"""The ``franka_msgs`` robot-state message, for ROS bags written and read without a ROS install (``rosbags``).

rosbags' built-in typestores hold the standard messages but not franka_ros's. A ROS 1 bag stores each
message definition in its connection header, so real ROS 1 bags decode with their own definition; ROS 2
bags recorded with MCAP storage or from Iron on store it too. For the rest (ROS 2 Humble ``.db3``) and for
writing bags, :func:`franka_typestore` registers the definitions below. They must match the robot's
``franka_msgs`` field for field: ROS 1 checks the definition's MD5 and ROS 2's CDR layout has no field
names, so a shortened definition would misread every field after the first difference.

The field lists restate the interface of franka_ros's ``franka_msgs/msg/FrankaState.msg`` (ROS 1; upper-case
libfranka names) and franka_ros2's ``franka_msgs/msg/FrankaState.msg`` (ROS 2 Humble releases; lower-case,
with commanded-motion fields), with their ``Errors`` messages. Newer franka_ros2 releases publish
``FrankaRobotState`` instead (poses and wrenches as ``PoseStamped`` / ``WrenchStamped``); the importer reads
it from bags that carry its definition.
"""

from __future__ import annotations

from typing import Any

_ROBOT_MODES = ("OTHER", "IDLE", "MOVE", "GUIDING", "REFLEX", "USER_STOPPED", "AUTOMATIC_ERROR_RECOVERY")
_ERRORS_ROS1 = (
    "joint_position_limits_violation", "cartesian_position_limits_violation", "self_collision_avoidance_violation",
    "joint_velocity_violation", "cartesian_velocity_violation", "force_control_safety_violation", "joint_reflex",
    "cartesian_reflex", "max_goal_pose_deviation_violation", "max_path_pose_deviation_violation",
    "cartesian_velocity_profile_safety_violation", "joint_position_motion_generator_start_pose_invalid",
    "joint_motion_generator_position_limits_violation", "joint_motion_generator_velocity_limits_violation",
    "joint_motion_generator_velocity_discontinuity", "joint_motion_generator_acceleration_discontinuity",
    "cartesian_position_motion_generator_start_pose_invalid", "cartesian_motion_generator_elbow_limit_violation",
    "cartesian_motion_generator_velocity_limits_violation", "cartesian_motion_generator_velocity_discontinuity",
    "cartesian_motion_generator_acceleration_discontinuity", "cartesian_motion_generator_elbow_sign_inconsistent",
    "cartesian_motion_generator_start_elbow_invalid", "cartesian_motion_generator_joint_position_limits_violation",
    "cartesian_motion_generator_joint_velocity_limits_violation",
    "cartesian_motion_generator_joint_velocity_discontinuity",
    "cartesian_motion_generator_joint_acceleration_discontinuity", "cartesian_position_motion_generator_invalid_frame",
    "force_controller_desired_force_tolerance_violation", "controller_torque_discontinuity",
    "start_elbow_sign_inconsistent", "communication_constraints_violation", "power_limit_violation",
)
_ERRORS_ROS2 = _ERRORS_ROS1 + ("joint_p2p_insufficient_torque_for_planning", "tau_j_range_violation",
                               "instability_detected")

# (type, name) in message order; arrays as "float64[N]".
_STATE_ROS1 = (
    ("float64[6]", "cartesian_collision"), ("float64[6]", "cartesian_contact"), ("float64[7]", "q"),
    ("float64[7]", "q_d"), ("float64[7]", "dq"), ("float64[7]", "dq_d"), ("float64[7]", "theta"),
    ("float64[7]", "dtheta"), ("float64[7]", "tau_J"), ("float64[7]", "dtau_J"), ("float64[7]", "tau_J_d"),
    ("float64[6]", "K_F_ext_hat_K"), ("float64[2]", "elbow"), ("float64[2]", "elbow_d"),
    ("float64[7]", "joint_collision"), ("float64[7]", "joint_contact"), ("float64[6]", "O_F_ext_hat_K"),
    ("float64[7]", "tau_ext_hat_filtered"), ("float64", "m_ee"), ("float64[3]", "F_x_Cee"), ("float64[9]", "I_ee"),
    ("float64", "m_load"), ("float64[3]", "F_x_Cload"), ("float64[9]", "I_load"), ("float64", "m_total"),
    ("float64[3]", "F_x_Ctotal"), ("float64[9]", "I_total"), ("float64[16]", "O_T_EE"), ("float64[16]", "O_T_EE_d"),
    ("float64[16]", "F_T_EE"), ("float64[16]", "EE_T_K"), ("float64", "time"),
    ("float64", "control_command_success_rate"),
)
_STATE_ROS2 = (
    ("float64[6]", "cartesian_collision"), ("float64[6]", "cartesian_contact"), ("float64[7]", "q"),
    ("float64[7]", "q_d"), ("float64[7]", "dq"), ("float64[7]", "dq_d"), ("float64[7]", "ddq_d"),
    ("float64[7]", "theta"), ("float64[7]", "dtheta"), ("float64[7]", "tau_j"), ("float64[7]", "dtau_j"),
    ("float64[7]", "tau_j_d"), ("float64[6]", "k_f_ext_hat_k"), ("float64[2]", "elbow"), ("float64[2]", "elbow_d"),
    ("float64[2]", "elbow_c"), ("float64[2]", "delbow_c"), ("float64[2]", "ddelbow_c"),
    ("float64[7]", "joint_collision"), ("float64[7]", "joint_contact"), ("float64[6]", "o_f_ext_hat_k"),
    ("float64[6]", "o_dp_ee_d"), ("float64[6]", "o_dp_ee_c"), ("float64[6]", "o_ddp_ee_c"),
    ("float64[7]", "tau_ext_hat_filtered"), ("float64", "m_ee"), ("float64[3]", "f_x_cee"), ("float64[9]", "i_ee"),
    ("float64", "m_load"), ("float64[3]", "f_x_cload"), ("float64[9]", "i_load"), ("float64", "m_total"),
    ("float64[3]", "f_x_ctotal"), ("float64[9]", "i_total"), ("float64[16]", "o_t_ee"), ("float64[16]", "o_t_ee_d"),
    ("float64[16]", "o_t_ee_c"), ("float64[16]", "f_t_ee"), ("float64[16]", "ee_t_k"), ("float64", "time"),
    ("float64", "control_command_success_rate"),
)
STATE_TYPE = "franka_msgs/msg/FrankaState"
ERRORS_TYPE = "franka_msgs/msg/Errors"


def _state_text(fields: tuple[tuple[str, str], ...], errors_type: str) -> str:
    lines = ["std_msgs/Header header"] + [f"{kind} {name}" for kind, name in fields]
    lines += [f"uint8 ROBOT_MODE_{mode}={value}" for value, mode in enumerate(_ROBOT_MODES)]
    lines += ["uint8 robot_mode", f"{errors_type} current_errors", f"{errors_type} last_motion_errors"]
    return "\n".join(lines) + "\n"


def definitions(ros2: bool) -> dict[str, str]:
    """Message type name -> ``.msg`` text of the robot state and its errors, for ROS 1 or ROS 2."""
    errors = _ERRORS_ROS2 if ros2 else _ERRORS_ROS1
    state = _state_text(_STATE_ROS2, "Errors") if ros2 else _state_text(_STATE_ROS1, "franka_msgs/Errors")
    return {ERRORS_TYPE: "".join(f"bool {name}\n" for name in errors), STATE_TYPE: state}


def franka_typestore(ros2: bool) -> Any:
    """rosbags' ROS 1 Noetic or ROS 2 Humble typestore plus the franka robot state."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    types: dict[str, Any] = {}
    for name, text in definitions(ros2).items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
