"""The C export of a policy file: one self-contained C99 header for a flight computer.

The header computes what the ONNX graph (bfc/agent/onnx.py) computes, for one drone per call:
the observation map (`PolicyObservation.integrate` and `.build`), the actor's mean (the MLP, tanh
when the spec squashes), the action map (`MotorSpeedAction.to_command`) and the env's clip to
[0, max_rotor_speed]. Weights are `static const float` arrays, the code is `static inline`
functions on caller-owned arrays: no allocation, nothing but <math.h>. Every constant is read
from the policy file's PolicySpec and the map objects it builds (the same objects the env and the
ONNX export run), so the C code restates the maps' arithmetic but none of their settings;
tests/test_export_c.py checks the two against each other. See docs/export.md, "C export".
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from torch import nn

from bfc.agent.actor import ACTIVATIONS
from bfc.agent.atomic import atomic_write, check_output_path
from bfc.agent.policy_file import POLICY_FORMAT, load_policy
from bfc.agent.spec import PolicySpec
from bfc.transforms import MotorSpeedAction, PolicyObservation

C_FORMAT = "bfc-c-v1"
PREFIX = "bfc_policy"
# activation -> the C statement applied to `h[i]` (NaN passes through, as in torch)
_ACTIVATION_C = {
    "relu": "h[i] = h[i] < 0.0f ? 0.0f : h[i];",
    "tanh": "h[i] = tanhf(h[i]);",
    "elu": "h[i] = h[i] > 0.0f ? h[i] : {alpha} * expm1f(h[i]);",
}


def c_float(value: float) -> str:
    """A C float literal that reads back as the float32 nearest `value` (9 significant digits)."""
    value = float(np.float32(value))
    if not math.isfinite(value):
        raise ValueError(f"the C export needs finite numbers, got {value!r}")
    text = f"{value:.9g}"
    if not any(ch in text for ch in ".e"):
        text += ".0"
    return text + "f"


def _layers(spec: PolicySpec, net) -> list[tuple[np.ndarray, np.ndarray, str | None, float]]:
    """[(weight (out, in), bias (out,), activation after it or None, ELU alpha)] of the actor's MLP;
    ValueError (one line) for anything the C code cannot express."""
    if spec.activation not in _ACTIVATION_C:
        raise ValueError(
            f"the C export does not support activation {spec.activation!r} "
            f"(supported: {', '.join(sorted(_ACTIVATION_C))})"
        )
    activation_class = ACTIVATIONS[spec.activation]
    layers: list = []
    for module in net.mlp:
        if isinstance(module, nn.Linear):
            weight = module.weight.detach().numpy().astype(np.float32)
            bias = np.zeros(weight.shape[0], np.float32)
            if module.bias is not None:
                bias = module.bias.detach().numpy().astype(np.float32)
            layers.append([weight, bias, None, 1.0])
        elif isinstance(module, activation_class) and layers and layers[-1][2] is None:
            layers[-1][2] = spec.activation
            layers[-1][3] = float(getattr(module, "alpha", 1.0))
        else:
            raise ValueError(f"the C export does not support the layer {type(module).__name__} in the actor's MLP")
    if not layers or layers[-1][2] is not None or any(layer[2] is None for layer in layers[:-1]):
        raise ValueError("the C export supports an MLP of Linear layers with an activation between them only")
    for weight, bias, _, _ in layers:
        if not (np.isfinite(weight).all() and np.isfinite(bias).all()):
            raise ValueError("the policy's weights are not all finite: the C export refuses them")
    return [tuple(layer) for layer in layers]


def _array(name: str, values: np.ndarray, per_line: int = 8) -> str:
    """`static const float bfc_policy_<name>[a][b] = {...};`, one block per row of a matrix."""
    dims = "".join(f"[{d}]" for d in values.shape)

    def row_text(row, indent):
        numbers = [c_float(v) for v in row]
        return ",\n".join(indent + ", ".join(numbers[i : i + per_line]) for i in range(0, len(numbers), per_line))

    if values.ndim == 1:
        inner = row_text(values, "    ")
    else:
        inner = ",\n".join("    {\n" + row_text(row, "        ") + "\n    }" for row in values)
    return f"static const float {PREFIX}_{name}{dims} = {{\n{inner}\n}};\n"


def _observation_code(spec: PolicySpec, obs: PolicyObservation) -> str:
    """The body of `bfc_policy_observation`: PolicyObservation.build, one drone."""
    integral = spec.position_integral
    P = PREFIX.upper()
    if obs.kind == "odometry":
        lines = [
            "    int k;",
            "    (void)previous_action; /* the paper's observation has no previous command */",
            "    /* 0:3 the position relative to the goal, then 3:18 odometry columns 3:18 as they come */",
            "    for (k = 0; k < 3; ++k) obs[k] = odometry[k] - goal[k];",
            "    for (k = 3; k < 18; ++k) obs[k] = odometry[k];",
        ]
        if not integral:
            return "\n".join([*lines, "    (void)integral;", "    (void)history_action;"])
        return "\n".join(
            [
                "    const float c = cosf(odometry[11]), s = sinf(odometry[11]); /* the yaw */",
                *lines,
                "    /* 18:21 the position-error integral, heading frame (world turned by the yaw), scaled */",
                f"    obs[18] = (c * integral[0] + s * integral[1]) * {P}_INTEGRAL_SCALE;",
                f"    obs[19] = (c * integral[1] - s * integral[0]) * {P}_INTEGRAL_SCALE;",
                f"    obs[20] = integral[2] * {P}_INTEGRAL_SCALE;",
                "    (void)history_action;",
            ]
        )
    lines = [
        "    /* roll, pitch, yaw (odometry 9:12) */",
        "    const float cr = cosf(odometry[9]), sr = sinf(odometry[9]);",
        "    const float cp = cosf(odometry[10]), sp = sinf(odometry[10]);",
        "    const float c = cosf(odometry[11]), s = sinf(odometry[11]);",
        "    const float ex = odometry[0] - goal[0], ey = odometry[1] - goal[1], ez = odometry[2] - goal[2];",
        "    int k;",
        "    /* 0:3 the position relative to the goal, heading frame (world turned by the yaw), clipped */",
        f"    obs[0] = {PREFIX}_clamp(c * ex + s * ey, -{P}_POSITION_CLIP, {P}_POSITION_CLIP);",
        f"    obs[1] = {PREFIX}_clamp(c * ey - s * ex, -{P}_POSITION_CLIP, {P}_POSITION_CLIP);",
        f"    obs[2] = {PREFIX}_clamp(ez, -{P}_POSITION_CLIP, {P}_POSITION_CLIP);",
        "    /* 3:12 the rotation matrix of roll and pitch only (Ry(pitch) Rx(roll)), row by row */",
        "    obs[3] = cp; obs[4] = sp * sr; obs[5] = sp * cr;",
        "    obs[6] = 0.0f; obs[7] = cr; obs[8] = -sr;",
        "    obs[9] = -sp; obs[10] = cp * sr; obs[11] = cp * cr;",
        "    /* 12:15 the linear velocity, heading frame, scaled */",
        f"    obs[12] = (c * odometry[3] + s * odometry[4]) * {P}_VELOCITY_SCALE;",
        f"    obs[13] = (c * odometry[4] - s * odometry[3]) * {P}_VELOCITY_SCALE;",
        f"    obs[14] = odometry[5] * {P}_VELOCITY_SCALE;",
        "    /* 15:18 the body rates, scaled */",
        f"    for (k = 0; k < 3; ++k) obs[15 + k] = odometry[12 + k] * {P}_ANGULAR_VELOCITY_SCALE;",
        "    /* 18:22 the previous action (the previous command in the policy's action space) */",
        "    for (k = 0; k < 4; ++k) obs[18 + k] = previous_action[k];",
    ]
    at = 22
    if spec.include_acceleration:
        lines += [
            f"    /* {at}:{at + 6} the linear (odometry 6:9) and angular (15:18) accelerations, scaled */",
            f"    for (k = 0; k < 3; ++k) obs[{at} + k] = odometry[6 + k] * {P}_ACCELERATION_SCALE;",
            f"    for (k = 0; k < 3; ++k) obs[{at + 3} + k] = odometry[15 + k] * {P}_ACCELERATION_SCALE;",
        ]
        at += 6
    if integral:
        lines += [
            f"    /* {at}:{at + 3} the position-error integral, heading frame, scaled */",
            f"    obs[{at}] = (c * integral[0] + s * integral[1]) * {P}_INTEGRAL_SCALE;",
            f"    obs[{at + 1}] = (c * integral[1] - s * integral[0]) * {P}_INTEGRAL_SCALE;",
            f"    obs[{at + 2}] = integral[2] * {P}_INTEGRAL_SCALE;",
        ]
        at += 3
    else:
        lines.append("    (void)integral;")
    if spec.command_history:
        lines += [
            f"    /* {at}:{at + 4 * spec.command_history} the commands before the previous one, newest first, "
            "in the policy's action space */",
            f"    for (k = 0; k < 4 * {P}_COMMAND_HISTORY; ++k) obs[{at} + k] = history_action[k];",
        ]
    else:
        lines.append("    (void)history_action;")
    return "\n".join(lines)


def _action_code(action: MotorSpeedAction) -> tuple[str, str]:
    """(command -> action, action -> command): MotorSpeedAction.to_action / to_command, one motor."""
    P = PREFIX.upper()
    if action.action_map == "thrust":
        to_action = (
            f"    const float q = command / {P}_HOVER_SPEED;\n"
            "    /* thrust map: the thrust relative to hover, minus one, halved */\n"
            "    return (q * q - 1.0f) / 2.0f;"
        )
        to_command = (
            "    /* thrust map: speed = hover sqrt(1 + 2a), the root's argument clipped to [0, (max/hover)^2] */\n"
            f"    return {P}_HOVER_SPEED * sqrtf({PREFIX}_clamp(1.0f + 2.0f * action, 0.0f, {P}_THRUST_RATIO_MAX));"
        )
    else:
        to_action = f"    /* speed map: speed / hover - 1 */\n    return command / {P}_HOVER_SPEED - 1.0f;"
        to_command = (
            "    /* speed map: speed = hover (1 + a), clipped to [0, max] */\n"
            f"    return {PREFIX}_clamp({P}_HOVER_SPEED * (1.0f + action), 0.0f, {P}_MAX_ROTOR_SPEED);"
        )
    return to_action, to_command


def generate_c(spec: PolicySpec, net, source: str = "policy.pt", name: str = "policy.h") -> str:
    """The header's text for `spec` and its network (see `export_c`); `source` and `name`, the
    policy file's and the header's names, go in its comment."""
    layers = _layers(spec, net)
    obs = spec.make_observation_map(1)
    action = spec.make_action_map()
    P, p = PREFIX.upper(), PREFIX
    widths = [w.shape[0] for w, _, _, _ in layers[:-1]]
    macs = sum(w.size for w, _, _, _ in layers)
    sizes = " -> ".join([str(obs.size)] + [str(w) for w in widths] + ["4"])
    integral = spec.position_integral
    K = spec.command_history
    to_action, to_command = _action_code(action)
    # the history's parameters: in the signature only for a policy that has one
    history_params = ", history_in, history_out" if K else ""
    history_decl_in = f",\n        const float history_in[{K}][4]" if K else ""
    history_decl_out = f", float history_out[{K}][4]" if K else ""

    odometry_note = "" if obs.kind == "odometry" or spec.include_acceleration else " (6:9 and 15:18 unused here)"
    order = spec.nominal_airframe.motor_order()
    if integral:
        integral_lines = [
            " *   integral_in[3] the position-error integral (m s, world frame): the integral_out of the",
            " *                  previous step, zeros after a reset (NULL reads as zeros)",
            " * Outputs:",
            f" *   motor_speeds_out[4]  rad/s in [0, {P}_MAX_ROTOR_SPEED]; motor order {order}",
            " *   integral_out[3]  the integral after this step, to pass back next time (NULL: not written)",
        ]
    else:
        integral_lines = [
            " *   integral_in[3] unused: this policy has no position-error integral (pass NULL)",
            " * Outputs:",
            f" *   motor_speeds_out[4]  rad/s in [0, {P}_MAX_ROTOR_SPEED]; motor order {order}",
            " *   integral_out[3]  not written (pass NULL)",
        ]
    parts = [f"{obs.kind} observation, {obs.size} numbers"]
    parts += ["with accelerations"] if spec.include_acceleration and obs.kind == "heading" else []
    parts += ["with the position-error integral"] if integral else []
    parts += [f"with the {K} commands before the previous one"] if K else []
    history_lines = (
        [
            f" *   history_in[{K}][4]  rad/s: the commands before previous_motor_speeds, newest first (the",
            f" *                  history_out of the previous step), {P}_HOVER_SPEED after a reset",
            f" *   history_out[{K}][4]  the history after this step, to pass back next time",
        ]
        if K
        else []
    )
    comment = [
        f"/* {name}: the bfc policy `{source}` as C99 code ({C_FORMAT}, from a {POLICY_FORMAT} policy file),",
        " * written by `python -m bfc.export <policy.pt> <out>.h` (bfc.export.export_c). Do not edit: export again.",
        " *",
        " * The deterministic policy (the Gaussian's mean, no sampling) with its observation and action",
        " * maps, for one drone per call, as the ONNX export computes it (docs/export.md):",
        f" *   observation  {', '.join(parts)}",
        f" *   network      MLP {sizes}, {spec.activation}"
        + (", tanh on the mean" if spec.squash else "")
        + f" ({macs} multiply-adds)",
        f" *   action map   {action.action_map}; the output clipped to [0, {P}_MAX_ROTOR_SPEED]",
        " *",
        f" * {p}_step(odometry, goal, previous_motor_speeds, integral_in, motor_speeds_out, integral_out"
        + history_params
        + ")",
        " * Inputs (float, SI units, world frame with z up unless said):",
        " *   odometry[18]   0:3 position (m), 3:6 linear velocity (m/s), 6:9 linear acceleration (m/s^2),",
        " *                  9:12 roll, pitch, yaw (rad, ZYX), 12:15 angular velocity (rad/s, body),",
        f" *                  15:18 angular acceleration (rad/s^2, body){odometry_note}",
        " *   goal[3]        the position to fly to (m)",
        " *   previous_motor_speeds[4]  rad/s: the motor_speeds_out of the previous control step,",
        f" *                  {P}_HOVER_SPEED after a reset (take-off, a new flight)",
        *integral_lines,
        *history_lines,
        " * Outputs may alias inputs. Call it at " + f"{P}_CONTROL_HZ: the policy was trained at that rate",
        " * (and the integral integrates at it)." if integral else " * and flies at that rate only.",
        f" * Or keep that state in a {p}_state: {p}_reset(&state) at a reset, then",
        f" * {p}_update(&state, odometry, goal, motor_speeds_out) once per control step.",
        f" * Stack: about {4 * (2 * obs.size + 2 * max(widths) + 16)} bytes. No allocation; needs <math.h> (link -lm).",
        " */",
    ]
    head = (
        "\n".join(comment)
        + f"""
#ifndef {P}_H
#define {P}_H

#include <math.h>

/* sizes */
#define {P}_ODOMETRY_SIZE 18
#define {P}_GOAL_SIZE 3
#define {P}_NUM_MOTORS 4
#define {P}_INTEGRAL_SIZE 3
#define {P}_OBSERVATION_SIZE {obs.size}
#define {P}_HIDDEN_MAX {max(widths)}
#define {P}_MACS {macs} /* multiply-adds of the MLP per call */

/* how to fly it */
#define {P}_CONTROL_HZ {c_float(spec.control_hz)} /* the rate the policy was trained at: call it at this rate */
#define {P}_HOVER_SPEED {c_float(action.hover_speed)} /* rad/s: previous_motor_speeds after a reset */
#define {P}_MAX_ROTOR_SPEED {c_float(action.max_speed)} /* rad/s: the top of the output range */
#define {P}_HAS_INTEGRAL {int(integral)} /* 1: integral_in / integral_out carry the position-error integral */
#define {P}_COMMAND_HISTORY {K} /* > 0: history_in / history_out carry that many older commands */
#define {P}_ACCELERATION_USED {int(spec.include_acceleration and obs.kind == "heading")}
#define {P}_ACTION_MAP "{action.action_map}"
#define {P}_OBSERVATION "{obs.kind}"

/* the maps' constants (PolicyObservation, MotorSpeedAction) */
#define {P}_POSITION_CLIP {c_float(obs.position_clip)} /* m */
#define {P}_VELOCITY_SCALE {c_float(obs.velocity_scale)}
#define {P}_ANGULAR_VELOCITY_SCALE {c_float(obs.angular_velocity_scale)}
#define {P}_ACCELERATION_SCALE {c_float(obs.acceleration_scale)}
#define {P}_INTEGRAL_SCALE {c_float(obs.integral_scale)}
#define {P}_INTEGRAL_DT {c_float(obs.dt)} /* s: 1 / control rate */
#define {P}_INTEGRAL_RADIUS_SQ {c_float(obs.integral_radius**2)} /* m^2: integrate within this of the goal */
#define {P}_INTEGRAL_SETTLED_RADIUS_SQ {c_float(obs.integral_settled_radius**2)} /* m^2: and this while settled */
#define {P}_INTEGRAL_SETTLED_SPEED_SQ {c_float(obs.integral_settled_speed**2)} /* (m/s)^2: settled: slower than this */
#define {P}_INTEGRAL_LIMIT {c_float(obs.integral_limit)} /* m s: the integral's clip */
#define {P}_THRUST_RATIO_MAX {c_float((action.max_speed / action.hover_speed) ** 2)} /* (max / hover)^2 */

"""
    )
    weights = [f"/* ---- the actor's weights: MLP {sizes} ---- */\n"]
    for i, (w, b, act, _) in enumerate(layers):
        what = f"then {act}" if act else ("the mean action, then tanh" if spec.squash else "the mean action")
        weights.append(f"/* layer {i}: Linear {w.shape[1]} -> {w.shape[0]}, {what} */\n")
        weights.append(_array(f"weight{i}", w))
        weights.append(_array(f"bias{i}", b))
        weights.append("\n")

    mlp = []
    src = "obs"
    norm = net.obs_norm
    if norm is not None:  # ObservationNorm: clip((obs - mean) / sqrt(var + eps), -clip, clip)
        std = (norm.var + norm.eps).sqrt()
        weights.append(f"/* the observation's running statistics (ObservationNorm, clip {c_float(norm.clip)}) */\n")
        weights.append(_array("obs_mean", norm.mean.detach().numpy()))
        weights.append(_array("obs_std", std.detach().numpy()))
        weights.append("\n")
        mlp.append("    /* the observation's running statistics */")
        bound = c_float(norm.clip)
        mlp.append(
            f"    for (i = 0; i < {P}_OBSERVATION_SIZE; ++i) "
            f"x[i] = {p}_clamp((obs[i] - {p}_obs_mean[i]) / {p}_obs_std[i], -{bound}, {bound});"
        )
        src = "x"
    for i, (w, _, act, alpha) in enumerate(layers):
        dst = "action" if i == len(layers) - 1 else ("h0" if i % 2 == 0 else "h1")
        mlp.append(f"    /* layer {i}: Linear {w.shape[1]} -> {w.shape[0]} */")
        mlp.append(f"    {p}_dense(&{p}_weight{i}[0][0], {p}_bias{i}, {w.shape[1]}, {w.shape[0]}, {src}, {dst});")
        if act:
            stmt = _ACTIVATION_C[act].format(alpha=c_float(alpha)).replace("h[i]", f"{dst}[i]")
            mlp.append(f"    for (i = 0; i < {w.shape[0]}; ++i) {stmt} /* {act} */")
        src = dst
    if spec.squash:
        mlp.append("    /* squash: tanh on the mean */")
        mlp.append("    for (i = 0; i < 4; ++i) action[i] = tanhf(action[i]);")
    hidden_decl = "h0[{0}], h1[{0}]".format(f"{P}_HIDDEN_MAX") if len(widths) > 1 else f"h0[{P}_HIDDEN_MAX]"
    if norm is not None:
        hidden_decl += f", x[{P}_OBSERVATION_SIZE]"

    if integral:
        integral_code = (
            "    /* the position-error integral including this step's error */\n"
            f"    {p}_integrate(integral_in, odometry, goal, integral);"
        )
        store_code = "    if (integral_out) {\n        for (k = 0; k < 3; ++k) integral_out[k] = integral[k];\n    }"
    else:
        integral_code = (
            "    (void)integral_in; /* no integral in this policy */\n"
            "    integral[0] = integral[1] = integral[2] = 0.0f;"
        )
        store_code = "    (void)integral_out;"
    if K:
        history_code = (
            f"    float history_action[4 * {K}], previous_copy[4];\n"
            "    /* the older commands in the policy's action space, clipped to [-1, 1] */\n"
            f"    for (k = 0; k < 4 * {K}; ++k) history_action[k] = "
            f"{p}_clamp({p}_to_action(history_in[k / 4][k % 4]), -1.0f, 1.0f);\n"
            "    for (k = 0; k < 4; ++k) previous_copy[k] = previous_motor_speeds[k];"
        )
        # newest first; from the oldest end down, so history_out may alias history_in
        store_code += (
            f"\n    for (k = 4 * {K} - 1; k >= 4; --k) history_out[k / 4][k % 4] = history_in[k / 4 - 1][k % 4];"
            "\n    for (k = 0; k < 4; ++k) history_out[0][k] = previous_copy[k];"
        )
        history_arg = "history_action"
        state_field = f"\n    float history[{K}][4];          /* rad/s: the commands before it, newest first */"
        reset_history = f"\n    for (k = 0; k < 4 * {K}; ++k) state->history[k / 4][k % 4] = {P}_HOVER_SPEED;"
        update_history = ", (const float (*)[4])state->history, state->history"  # C99: no implicit const for 2-D
    else:
        history_code, history_arg, state_field, reset_history, update_history = "", "NULL", "", "", ""

    code = f"""/* ---- helpers ---- */

/* clip x to [lo, hi] (a NaN stays NaN, as torch.clamp) */
static inline float {p}_clamp(float x, float lo, float hi)
{{
    return x < lo ? lo : (x > hi ? hi : x);
}}

/* y = W x + b: W is (n_out, n_in), row-major as torch's Linear.weight */
static inline void {p}_dense(const float *weight, const float *bias, int n_in, int n_out, const float *x, float *y)
{{
    int o, i;
    for (o = 0; o < n_out; ++o) {{
        const float *row = weight + o * n_in;
        float sum = bias[o];
        for (i = 0; i < n_in; ++i) sum += row[i] * x[i];
        y[o] = sum;
    }}
}}

/* ---- the action map (MotorSpeedAction) ---- */

/* a motor command (rad/s) -> the policy's action that commands it */
static inline float {p}_to_action(float command)
{{
{to_action}
}}

/* the policy's action -> a motor command (rad/s) */
static inline float {p}_to_command(float action)
{{
{to_command}
}}

/* ---- the observation map (PolicyObservation) ---- */

/* the position-error integral after this control step (PolicyObservation.integrate): add the
 * error times dt when within the radius of the goal, or within the settled radius while slower
 * than the settled speed, then clip each axis to +-limit */
static inline void {p}_integrate(const float integral_in[3], const float odometry[18], const float goal[3],
        float integral_out[3])
{{
    const float e[3] = {{odometry[0] - goal[0], odometry[1] - goal[1], odometry[2] - goal[2]}};
    const float d2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
    const float v2 = odometry[3] * odometry[3] + odometry[4] * odometry[4] + odometry[5] * odometry[5];
    const int settled = v2 < {P}_INTEGRAL_SETTLED_SPEED_SQ && d2 < {P}_INTEGRAL_SETTLED_RADIUS_SQ;
    const float near = (d2 < {P}_INTEGRAL_RADIUS_SQ || settled) ? 1.0f : 0.0f;
    int k;
    for (k = 0; k < 3; ++k) {{
        const float before = integral_in ? integral_in[k] : 0.0f;
        integral_out[k] = {p}_clamp(before + near * e[k] * {P}_INTEGRAL_DT, -{P}_INTEGRAL_LIMIT, {P}_INTEGRAL_LIMIT);
    }}
}}

/* the network's input (PolicyObservation.build): previous_action in [-1, 1]^4, integral (m s,
 * world frame) already integrated for this step */
static inline void {p}_observation(const float odometry[18], const float goal[3], const float previous_action[4],
        const float integral[3], const float *history_action, float obs[{P}_OBSERVATION_SIZE])
{{
{_observation_code(spec, obs)}
}}

/* ---- the network (GaussianActor.mean) ---- */

static inline void {p}_mean(const float obs[{P}_OBSERVATION_SIZE], float action[4])
{{
    float {hidden_decl};
    int i;
{chr(10).join(mlp)}
}}

/* ---- the policy: one control step ---- */

static inline void {p}_step(const float odometry[18], const float goal[3], const float previous_motor_speeds[4],
        const float integral_in[3], float motor_speeds_out[4], float integral_out[3]{history_decl_in}{history_decl_out})
{{
    float previous_action[4], integral[3], obs[{P}_OBSERVATION_SIZE], action[4];
    int k;
{history_code}
    /* the previous command in the policy's action space, clipped to [-1, 1] */
    for (k = 0; k < 4; ++k) previous_action[k] = {p}_clamp({p}_to_action(previous_motor_speeds[k]), -1.0f, 1.0f);
{integral_code}
    {p}_observation(odometry, goal, previous_action, integral, {history_arg}, obs);
    {p}_mean(obs, action);
    /* the motor commands, clipped to [0, max] as the env clips them */
    for (k = 0; k < 4; ++k) motor_speeds_out[k] = {p}_clamp({p}_to_command(action[k]), 0.0f, {P}_MAX_ROTOR_SPEED);
{store_code}
}}

/* ---- the state to feed back, for callers that keep it here ---- */

typedef struct {p}_state {{
    float previous_motor_speeds[4]; /* rad/s: the last command */
    float integral[3];              /* m s, world frame: the position-error integral (zeros if unused) */{state_field}
}} {p}_state;

/* after a reset (take-off, a new flight): hover as the previous command, a zero integral */
static inline void {p}_reset({p}_state *state)
{{
    int k;
    for (k = 0; k < 4; ++k) state->previous_motor_speeds[k] = {P}_HOVER_SPEED;
    for (k = 0; k < 3; ++k) state->integral[k] = 0.0f;{reset_history}
}}

/* one control step that feeds its own command (and integral) back through `state` */
static inline void {p}_update({p}_state *state, const float odometry[18], const float goal[3],
        float motor_speeds_out[4])
{{
    int k;
    {p}_step(odometry, goal, state->previous_motor_speeds, state->integral, state->previous_motor_speeds,
        state->integral{update_history});
    for (k = 0; k < 4; ++k) motor_speeds_out[k] = state->previous_motor_speeds[k];
}}

#endif /* {P}_H */
"""
    return head + "".join(weights) + code


def export_c(policy_path, out_path) -> Path:
    """Write the deterministic policy of `policy_path` (a policy.pt) as one C99 header at `out_path`.

    Raises FileNotFoundError / ValueError for a missing or foreign policy file, ValueError (one
    line) for a spec or network the C code cannot express, OSError when `out_path` cannot be
    written. Returns the path written (written atomically).
    """
    out_path = Path(out_path)
    check_output_path(out_path, "policy.h")
    spec, net = load_policy(policy_path)
    text = generate_c(spec, net, source=Path(policy_path).name, name=out_path.name)
    return atomic_write(out_path, lambda tmp: tmp.write_text(text), "the C header")
