"""Tensordict keys shared by the env, the transforms, training and evaluation.

Keys are the contract between the packages: name them once, import them everywhere.
"""

# the policy network's activations (model.activation): bfc.agent.actor maps each to its module and
# bfc.config checks the name before torch loads, so the names live in this leaf
ACTIVATION_NAMES = ("tanh", "relu", "elu")
# The observation's scales, clip and integral constants a policy carries (their values for a new
# policy: bfc.transforms.observation.OBSERVATION_SCALES; `model.observation_scales` overrides any)
OBSERVATION_SCALE_NAMES = (
    "position_clip",
    "velocity_scale",
    "angular_velocity_scale",
    "acceleration_scale",
    "integral_radius",
    "integral_limit",
    "integral_scale",
    "integral_settled_radius",
    "integral_settled_speed",
)

ACTION = "action"  # (N, 4) motor speed commands, rad/s, motor order of AirframeParams.motor_order()
ODOMETRY = "odometry"  # (N, 18) what the sensors report (noise transforms act here)
GOAL = "goal"  # (N, 3) desired position, world frame
STATE = "state"  # ground truth sub-tensordict, never touched by noise
POSITION = (STATE, "position")  # (N, 3) world
QUATERNION = (STATE, "quaternion")  # (N, 4) w, x, y, z
LINEAR_VELOCITY = (STATE, "linear_velocity")  # (N, 3) world
ANGULAR_VELOCITY = (STATE, "angular_velocity")  # (N, 3) body
MOTOR_SPEEDS = (STATE, "motor_speeds")  # (N, 4) rad/s
START_STATE = "start_state"  # (N, 12) reset input: pos, roll/pitch/yaw, lin vel, body ang vel
OBSERVATION = "observation"  # policy input, built by bfc.transforms.observation
REWARD = "reward"
DONE = "done"
TERMINATED = "terminated"
TRUNCATED = "truncated"
RESET = "_reset"

# Layout of the 18 odometry numbers (the paper's order).
ODOM_POSITION = slice(0, 3)
ODOM_LINEAR_VELOCITY = slice(3, 6)
ODOM_LINEAR_ACCELERATION = slice(6, 9)
ODOM_ATTITUDE = slice(9, 12)
ODOM_ANGULAR_VELOCITY = slice(12, 15)
ODOM_ANGULAR_ACCELERATION = slice(15, 18)

# Layout of the 12 start-state numbers.
START_POSITION = slice(0, 3)
START_ATTITUDE = slice(3, 6)
START_LINEAR_VELOCITY = slice(6, 9)
START_ANGULAR_VELOCITY = slice(9, 12)
