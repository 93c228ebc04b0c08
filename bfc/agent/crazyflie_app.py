"""`python -m bfc.export policy.pt out_dir --format crazyflie`: a Crazyflie firmware app.

The app is the firmware's out-of-tree controller (`ControllerTypeOot`): the policy header
(bfc.agent.c_export), a firmware-agnostic core (`bfc_crazyflie.h`: the estimator's quantities in the
firmware's units and frames -> the policy's odometry -> four normalised motor forces in the
firmware's motor order) and a thin glue file that includes the firmware's headers. The core is
plain C99 with no firmware header, so the host compiles and flies it (tests/evaluation/
test_crazyflie_app.py, software in the loop) and the Cortex-M4 runs it unchanged. Nothing here is
copied from the firmware (GPL-3): the glue uses the documented fields of its structures.
"""

from __future__ import annotations

import ctypes
import math
import shutil
import tempfile
import weakref
from pathlib import Path

import numpy as np
import torch
from tensordict.nn import TensorDictModuleBase

from bfc import keys
from bfc.agent.atomic import atomic_write
from bfc.agent.c_controller import compile_library
from bfc.agent.c_export import c_float, export_c
from bfc.agent.fed_back import restart_mask
from bfc.agent.policy_file import load_policy

# The stock firmware's THRUST_MAX (platform_defaults.h): the thrust per motor, N, that a normalised
# force of 1 asks for when the firmware compensates the battery voltage (its default on a cf2)
FIRMWARE_THRUST_MAX = 0.1125
# bfc's "x" motors 0 front-left, 1 back-left, 2 back-right, 3 front-right are the Crazyflie's M4,
# M3, M2, M1: firmware motor i (M1..M4) flies bfc motor FIRMWARE_ORDER[i]
FIRMWARE_ORDER = (3, 2, 1, 0)

CORE = r"""/* bfc_crazyflie.h: the bfc policy as a Crazyflie controller, without the firmware's headers.
 * Written by `python -m bfc.export <policy.pt> <dir> --format crazyflie`; do not edit, export again.
 *
 * bfc_cf_step turns the state estimate, in the firmware's units and frames, into the policy's
 * odometry (bfc's layout, SI units, radians), runs the policy (bfc_policy.h) and returns four
 * normalised motor forces in [0, 1] in the firmware's motor order M1..M4:
 *   position[3]      m, world frame, z up (state_t.position)
 *   velocity[3]      m/s, world frame (state_t.velocity)
 *   attitude_deg[3]  roll, pitch, yaw in degrees as state_t.attitude gives them: ZYX angles with the
 *                    pitch inverted (the firmware's legacy convention); bfc's pitch is its negative
 *   gyro_deg_s[3]    body rates, deg/s (sensorData_t.gyro)
 *   goal[3]          m, world frame
 *   forces_out[4]    thrust of M1 (front-right), M2 (back-right), M3 (back-left), M4 (front-left)
 *                    over BFC_CF_THRUST_MAX, clipped to [0, 1] (control_t.normalizedForces)
 * Call it at BFC_POLICY_CONTROL_HZ. bfc_cf_reset before a flight (the policy's fed-back state, and
 * no previous estimate for the difference quotients). */
#ifndef BFC_CRAZYFLIE_H
#define BFC_CRAZYFLIE_H

#include "bfc_policy.h"

/* N per motor that a normalised force of 1 stands for: the firmware's THRUST_MAX by default */
#ifndef BFC_CF_THRUST_MAX
#define BFC_CF_THRUST_MAX {thrust_max}
#endif
#define BFC_CF_MOTOR_CONSTANT {motor_constant} /* N/(rad/s)^2: thrust = k_f w^2 of the trained airframe */
#define BFC_CF_DEG 0.0174532925f /* rad per degree */

typedef struct bfc_cf_state {{
    bfc_policy_state policy;
    float velocity[3]; /* the previous call's, for the acceleration */
    float rates[3];    /* the previous call's body rates (rad/s), for the angular acceleration */
    int fresh;         /* 1 until the first step after a reset */
}} bfc_cf_state;

static inline void bfc_cf_reset(bfc_cf_state *s)
{{
    int k;
    bfc_policy_reset(&s->policy);
    for (k = 0; k < 3; ++k) s->velocity[k] = s->rates[k] = 0.0f;
    s->fresh = 1;
}}

/* The odometry bfc's env gives the policy (bfc_policy.h's layout), from the firmware's estimate */
static inline void bfc_cf_odometry(bfc_cf_state *s, const float position[3], const float velocity[3],
        const float attitude_deg[3], const float gyro_deg_s[3], float odometry[18])
{{
    int k;
    for (k = 0; k < 3; ++k) {{
        float rate = gyro_deg_s[k] * BFC_CF_DEG;
        odometry[k] = position[k];
        odometry[3 + k] = velocity[k];
        odometry[6 + k] = s->fresh ? 0.0f : (velocity[k] - s->velocity[k]) * BFC_POLICY_CONTROL_HZ;
        odometry[12 + k] = rate;
        odometry[15 + k] = s->fresh ? 0.0f : (rate - s->rates[k]) * BFC_POLICY_CONTROL_HZ;
        s->velocity[k] = velocity[k];
        s->rates[k] = rate;
    }}
    odometry[9] = attitude_deg[0] * BFC_CF_DEG;
    odometry[10] = -attitude_deg[1] * BFC_CF_DEG; /* the legacy pitch is inverted */
    odometry[11] = attitude_deg[2] * BFC_CF_DEG;
    s->fresh = 0;
}}

static inline void bfc_cf_step(bfc_cf_state *s, const float position[3], const float velocity[3],
        const float attitude_deg[3], const float gyro_deg_s[3], const float goal[3], float forces_out[4])
{{
    /* bfc motor order[i] drives firmware motor M(i+1) */
    static const int order[4] = {{{order}}};
    float odometry[18], speeds[4];
    int i;
    bfc_cf_odometry(s, position, velocity, attitude_deg, gyro_deg_s, odometry);
    bfc_policy_update(&s->policy, odometry, goal, speeds);
    for (i = 0; i < 4; ++i) {{
        float w = speeds[order[i]];
        forces_out[i] = bfc_policy_clamp(BFC_CF_MOTOR_CONSTANT * w * w / BFC_CF_THRUST_MAX, 0.0f, 1.0f);
    }}
}}

#endif /* BFC_CRAZYFLIE_H */
"""

GLUE = r"""/* bfc_oot.c: the bfc policy as the Crazyflie firmware's out-of-tree controller (ControllerTypeOot).
 * Written by `python -m bfc.export --format crazyflie`; see README.md before a first flight.
 *
 * The stabilizer's task (1 kHz, a 1.8 KB stack) only hands the estimate over at the policy's rate
 * and applies the latest forces every tick; the policy runs in this app's own task (its stack and
 * priority in app-config), which the stabilizer wakes: about 0.8 ms of work per policy step there,
 * outside the stabilizer's tick. */
#include <stdbool.h>
#include <stdint.h>

#include "app.h"
#include "FreeRTOS.h"
#include "task.h"
#include "semphr.h"
#include "controller.h"
#include "stabilizer_types.h"

#include "bfc_crazyflie.h"

typedef struct {
    float position[3], velocity[3], attitude[3], gyro[3], goal[3];
    int reset; /* the policy restarts before this step: sticky until the app task reads it */
} bfc_estimate;

static bfc_estimate bfc_in;    /* written by the stabilizer, read by the app task */
static float bfc_out[4];       /* written by the app task, read by the stabilizer */
static volatile bool bfc_flying; /* a position setpoint is being flown */
static bool bfc_starting;      /* the stabilizer's: the next estimate restarts the policy */
static SemaphoreHandle_t bfc_ready; /* given by the stabilizer at the policy's rate */
static StaticSemaphore_t bfc_ready_buffer;
static bfc_cf_state bfc_state; /* the app task's only */

/* One policy step on the latest estimate (the app task's loop body) */
void bfcAppStep(void)
{
    bfc_estimate e;
    float forces[4];
    int k;
    taskENTER_CRITICAL();
    e = bfc_in;
    bfc_in.reset = 0;
    taskEXIT_CRITICAL();
    if (e.reset) bfc_cf_reset(&bfc_state);
    bfc_cf_step(&bfc_state, e.position, e.velocity, e.attitude, e.gyro, e.goal, forces);
    taskENTER_CRITICAL();
    for (k = 0; k < 4; ++k) bfc_out[k] = bfc_flying ? forces[k] : 0.0f;
    taskEXIT_CRITICAL();
}

void appMain(void)
{
    bfc_ready = xSemaphoreCreateBinaryStatic(&bfc_ready_buffer);
    while (1) {
        if (xSemaphoreTake(bfc_ready, portMAX_DELAY) == pdTRUE) bfcAppStep();
    }
}

void controllerOutOfTreeInit(void)
{
    bfc_flying = false;
}

bool controllerOutOfTreeTest(void)
{
    return true;
}

void controllerOutOfTree(control_t *control, const setpoint_t *setpoint, const sensorData_t *sensors,
        const state_t *state, const uint32_t tick)
{
    int k;
    control->controlMode = controlModeForce;
    /* no position setpoint (nothing commanded, or the supervisor stopped the flight): motors off,
     * and the next flight starts from a reset policy */
    if (setpoint->mode.x != modeAbs || setpoint->mode.y != modeAbs || setpoint->mode.z != modeAbs) {
        bfc_flying = false;
        taskENTER_CRITICAL();
        for (k = 0; k < 4; ++k) bfc_out[k] = 0.0f;
        taskEXIT_CRITICAL();
        for (k = 0; k < 4; ++k) control->normalizedForces[k] = 0.0f;
        return;
    }
    if (!bfc_flying) {
        bfc_flying = true;
        bfc_starting = true;
    }
    if (RATE_DO_EXECUTE((uint32_t)BFC_POLICY_CONTROL_HZ, tick)) {
        taskENTER_CRITICAL();
        bfc_in.position[0] = state->position.x;
        bfc_in.position[1] = state->position.y;
        bfc_in.position[2] = state->position.z;
        bfc_in.velocity[0] = state->velocity.x;
        bfc_in.velocity[1] = state->velocity.y;
        bfc_in.velocity[2] = state->velocity.z;
        bfc_in.attitude[0] = state->attitude.roll;
        bfc_in.attitude[1] = state->attitude.pitch;
        bfc_in.attitude[2] = state->attitude.yaw;
        bfc_in.gyro[0] = sensors->gyro.x;
        bfc_in.gyro[1] = sensors->gyro.y;
        bfc_in.gyro[2] = sensors->gyro.z;
        bfc_in.goal[0] = setpoint->position.x;
        bfc_in.goal[1] = setpoint->position.y;
        bfc_in.goal[2] = setpoint->position.z;
        if (bfc_starting) bfc_in.reset = 1;
        taskEXIT_CRITICAL();
        bfc_starting = false;
        if (bfc_ready != NULL) xSemaphoreGive(bfc_ready);
    }
    taskENTER_CRITICAL();
    for (k = 0; k < 4; ++k) control->normalizedForces[k] = bfc_out[k];
    taskEXIT_CRITICAL();
}
"""

MAKEFILE = """# Build with a crazyflie-firmware checkout (git clone --recursive) beside this folder, or say where:
#   make CRAZYFLIE_BASE=/path/to/crazyflie-firmware
CRAZYFLIE_BASE ?= ../crazyflie-firmware
OOT := $(CURDIR)
OOT_CONFIG := $(CURDIR)/app-config
EXTRA_CFLAGS += -I$(CURDIR)/src
include $(CRAZYFLIE_BASE)/tools/make/oot.mk
"""
KBUILD = "obj-y += src/\n"
SRC_KBUILD = "obj-y += bfc_oot.o\nccflags-y += -I$(src) -Wall -Wextra -Werror\n"
# the app's task runs the policy: 1,000 words (4 KB) of stack for its 1.4 KB call, priority 3
# (below the stabilizer's 5 and the sensors' 4, above the estimator's 2)
APP_CONFIG = "CONFIG_APP_ENABLE=y\nCONFIG_APP_PRIORITY=3\nCONFIG_APP_STACKSIZE=1000\nCONFIG_CONTROLLER_OOT=y\n"

README = """# bfc policy as a Crazyflie out-of-tree controller

Exported from `{source}` by `python -m bfc.export {source} <dir> --format crazyflie`. The policy flies
at {hz:g} Hz from the firmware's 1 kHz stabilizer loop; between its steps the last forces are held.

## Build and flash

```bash
git clone --recursive https://github.com/bitcraze/crazyflie-firmware.git
make CRAZYFLIE_BASE=$PWD/crazyflie-firmware -C <this folder>     # or bench/crazyflie_build.sh in bfc
make CRAZYFLIE_BASE=$PWD/crazyflie-firmware -C <this folder> cload   # over the radio (cfclient's bootloader)
```

Select the controller with the parameter `stabilizer.controller` = 6, e.g. in cfclient
(ControllerTypeOot in crazyflie-firmware 2a18fc29: after auto, PID, Mellinger, INDI, Brescianini
and Lee; check your version's `controller.h`).

## What it does

- `src/bfc_policy.h`: the policy (bfc's C export). `src/bfc_crazyflie.h`: the estimate in the firmware's
  units (m, m/s, degrees with the legacy inverted pitch, gyro in deg/s) to bfc's odometry, the policy,
  and its rotor speeds to normalised forces thrust / BFC_CF_THRUST_MAX ({thrust_max:g} N, the firmware's
  THRUST_MAX; motor order M1 front-right, M2 back-right, M3 back-left, M4 front-left). `src/bfc_oot.c`:
  the firmware glue.
- It flies to the position setpoint (x, y, z all absolute: e.g. `cf.commander.send_position_setpoint`
  or the high-level commander); with no such setpoint it commands zero force and resets the policy,
  so each flight starts as the policy was trained (hover as the previous command, no integral).

## Not flown yet

The policy runs in this app's task (4 KB of stack, priority 3), woken by the stabilizer at
{hz:g} Hz; its forces reach the motors at the next stabilizer tick. This has been built against
the firmware and run in simulation, not flown: watch the firmware's stack and loop-rate warnings
(cfclient's console) on a first power-up, props off.

## Before a first flight

1. Props off: give a setpoint 0.5 m above the drone and check each motor spins up, and that tilting
   the drone by hand raises the motors on the low side (M1 front-right ... M4 front-left).
2. Check the propeller directions: M1 and M3 counter-clockwise, M2 and M4 clockwise seen from above
   (the policy was trained with these spins).
3. The trained airframe's thrust at full speed is {trained_max:.3g} N per motor; the firmware's THRUST_MAX
   is {thrust_max:g} N, so commands above it are clipped (set BFC_CF_THRUST_MAX if your build differs).
4. Fly first in a net or tethered, low, with the supervisor's tumble detection on (it cuts the
   motors when the drone tilts past its limit for a while) and a kill switch at hand (the client's
   emergency stop): the policy recovers from steep tilts that the supervisor may cut first.
"""


def export_crazyflie(policy_path, out_dir) -> Path:
    """Write the Crazyflie firmware app for the policy at `policy_path` into `out_dir`. ValueError
    (one line) for a policy not trained on an airframe laid out as a Crazyflie."""
    out_dir = Path(out_dir)
    spec, _ = load_policy(policy_path)
    a = spec.nominal_airframe
    if a.layout != "x" or a.rotor_spins != (1.0, -1.0, 1.0, -1.0):
        raise ValueError(
            f"--format crazyflie needs a policy trained on an 'x' airframe with the Crazyflie's spins "
            f"(env.airframe=crazyflie); this one flies {a.name!r} ({a.layout!r}, spins {list(a.rotor_spins)})"
        )
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"{out_dir} exists and is not a folder")
    (out_dir / "src").mkdir(parents=True, exist_ok=True)
    export_c(policy_path, out_dir / "src" / "bfc_policy.h")
    core = CORE.format(
        thrust_max=c_float(FIRMWARE_THRUST_MAX),
        motor_constant=c_float(a.motor_constant),
        order=", ".join(str(k) for k in FIRMWARE_ORDER),
    )
    source = Path(policy_path).name
    readme = README.format(
        source=source,
        hz=spec.control_hz,
        thrust_max=FIRMWARE_THRUST_MAX,
        trained_max=a.motor_constant * a.max_rotor_speed**2,
    )
    files = {
        "src/bfc_crazyflie.h": core,
        "src/bfc_oot.c": GLUE,
        "src/Kbuild": SRC_KBUILD,
        "Makefile": MAKEFILE,
        "Kbuild": KBUILD,
        "app-config": APP_CONFIG,
        "README.md": readme,
    }
    for name, text in files.items():
        atomic_write(out_dir / name, lambda tmp, text=text: tmp.write_text(text), name)
    return out_dir


def copy_core(out_dir, build_dir) -> None:
    """The firmware-agnostic part of an exported app (the two headers), for a host build."""
    for name in ("bfc_policy.h", "bfc_crazyflie.h"):
        shutil.copyfile(Path(out_dir) / "src" / name, Path(build_dir) / name)


# Software in the loop: the exported core compiled for this machine, one state per drone
_SITL = r"""#include <stddef.h>
#include "bfc_crazyflie.h"

size_t bfc_sitl_state_size(void) { return sizeof(bfc_cf_state); }

void bfc_sitl_reset(bfc_cf_state *states, int n, const unsigned char *mask)
{
    int r;
    for (r = 0; r < n; ++r) if (!mask || mask[r]) bfc_cf_reset(states + r);
}

void bfc_sitl_step(bfc_cf_state *states, int n, const float *position, const float *velocity,
        const float *attitude_deg, const float *gyro_deg_s, const float *goal, float *forces)
{
    int r;
    for (r = 0; r < n; ++r)
        bfc_cf_step(states + r, position + 3 * r, velocity + 3 * r, attitude_deg + 3 * r, gyro_deg_s + 3 * r,
            goal + 3 * r, forces + 4 * r);
}

double bfc_sitl_setting(int which)
{
    switch (which) {
    case 0: return BFC_POLICY_CONTROL_HZ;
    case 1: return BFC_CF_THRUST_MAX;
    default: return BFC_CF_MOTOR_CONSTANT;
    }
}
"""


class CrazyflieAppController(TensorDictModuleBase):
    """The exported app's firmware-agnostic core (`bfc_crazyflie.h` with the policy header),
    compiled for this machine and flown by `fly` as the firmware would run it: bfc's odometry is
    given to it as the firmware's estimate (degrees, the legacy inverted pitch, the gyro in deg/s),
    and its normalised forces (M1..M4) go back to the motors as rotor speeds in bfc's order.

    `fly(CrazyflieAppController(app_dir), starts, control_hz=c.control_hz, nominal=...)`. thrust_max:
    N per motor a force of 1 stands for (default: the firmware's THRUST_MAX, as the app is built;
    the trained airframe's full thrust flies the policy unclipped)."""

    def __init__(self, app_dir, thrust_max: float | None = None, cc: str | None = None):
        super().__init__()
        self.in_keys, self.out_keys = [keys.ODOMETRY, keys.GOAL], [keys.ACTION]
        build = Path(tempfile.mkdtemp(prefix="bfc-crazyflie-"))
        self._cleanup = weakref.finalize(self, shutil.rmtree, str(build), True)
        copy_core(app_dir, build)
        (build / "sitl.c").write_text(_SITL)
        defines = [] if thrust_max is None else [f"-DBFC_CF_THRUST_MAX={float(thrust_max)!r}f"]
        library = compile_library(build / "sitl.c", build / "libbfc_crazyflie.so", "the app's core", cc, defines)
        lib = ctypes.CDLL(str(library))
        lib.bfc_sitl_state_size.restype = ctypes.c_size_t
        lib.bfc_sitl_reset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_void_p]
        lib.bfc_sitl_step.argtypes = [ctypes.c_void_p, ctypes.c_int] + [ctypes.c_void_p] * 6
        lib.bfc_sitl_setting.argtypes = [ctypes.c_int]
        lib.bfc_sitl_setting.restype = ctypes.c_double
        self._lib, self._size = lib, int(lib.bfc_sitl_state_size())
        self.control_hz, self.thrust_max, self.motor_constant = (lib.bfc_sitl_setting(k) for k in range(3))
        self._states = None

    def begin_flight(self) -> None:
        self._states = None

    def reset(self) -> None:
        self._states = None

    def forward(self, td):
        odometry = td.get(keys.ODOMETRY).detach().cpu().numpy().astype(np.float64)
        n = odometry.shape[0]
        goal = td.get(keys.GOAL).expand(n, 3).detach().cpu().numpy()
        if self._states is None or len(self._states) != n * self._size:
            self._states = np.zeros(n * self._size, dtype=np.uint8)
            self._lib.bfc_sitl_reset(self._ptr(self._states), n, None)
        mask = restart_mask(td)
        if mask is not None and mask.any():
            self._lib.bfc_sitl_reset(self._ptr(self._states), n, self._ptr(mask.astype(np.uint8)))
        deg = 180.0 / math.pi
        parts = (
            odometry[:, 0:3],
            odometry[:, 3:6],
            odometry[:, 9:12] * np.array([deg, -deg, deg]),  # the firmware's legacy inverted pitch
            odometry[:, 12:15] * deg,
            goal,
        )
        arrays = [np.ascontiguousarray(p, dtype=np.float32) for p in parts]
        forces = np.zeros((n, 4), dtype=np.float32)
        self._lib.bfc_sitl_step(self._ptr(self._states), n, *(self._ptr(a) for a in arrays), self._ptr(forces))
        speeds = np.zeros((n, 4), dtype=np.float32)
        speeds[:, list(FIRMWARE_ORDER)] = np.sqrt(forces * (self.thrust_max / self.motor_constant))
        td.set(keys.ACTION, torch.from_numpy(speeds).to(td.get(keys.ODOMETRY).device))
        return td

    @staticmethod
    def _ptr(array):
        return array.ctypes.data_as(ctypes.c_void_p)
