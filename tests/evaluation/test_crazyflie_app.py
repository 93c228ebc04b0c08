"""The Crazyflie firmware app (`python -m bfc.export policy.pt dir --format crazyflie`): its files,
its core flown in the loop as the torch policy flies, the same numbers on the Cortex-M4, and a glue
that compiles against structures shaped like the firmware's (defined here from their documented
fields: the firmware is GPL-3 and nothing of it is copied)."""

import dataclasses
import shutil
import subprocess

import numpy as np
import pytest

from bfc.agent.crazyflie_app import FIRMWARE_THRUST_MAX
from bfc.config import airframe_params
from bfc.evaluation import fly, protocol_starts
from bfc.evaluation.suites import any_starts, score
from bfc.export import CrazyflieAppController, export_crazyflie, main
from tests import cortex_m4
from tests.export_helpers import CRAZYFLIE, PRETRAINED

CF = airframe_params("crazyflie")
CC = shutil.which("cc")
needs_cc = pytest.mark.skipif(CC is None, reason="no system C compiler `cc` on the PATH (apt-get install gcc)")
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror"]


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    return export_crazyflie(CRAZYFLIE, tmp_path_factory.mktemp("app") / "bfc_app")


def test_the_app_has_the_firmware_examples_layout(app, tmp_path, capsys):
    for name in ("Makefile", "Kbuild", "app-config", "README.md", "src/Kbuild", "src/bfc_oot.c"):
        assert (app / name).is_file(), name
    assert "CONFIG_CONTROLLER_OOT=y" in (app / "app-config").read_text()
    core = (app / "src" / "bfc_crazyflie.h").read_text()
    assert "#include" in core and "bfc_policy.h" in core and "FreeRTOS" not in core  # no firmware header
    assert main([str(PRETRAINED), str(tmp_path / "hb"), "--format", "crazyflie"]) == 2
    assert "needs a policy trained on an 'x' airframe" in capsys.readouterr().err


@needs_cc
@pytest.mark.parametrize("starts", ["protocol", "any"])
def test_its_core_flies_in_the_loop_as_the_torch_policy(app, starts):
    """The whole adapter (units, the inverted pitch, degrees, the motor order, rotor speed to
    normalised force and back) flown by `fly` on the Crazyflie: the torch policy's flights, point
    for point with a force of 1 standing for the trained full thrust, and with the same verdicts as
    the app is built, at the stock firmware's THRUST_MAX (the built-in Crazyflie trains at 2,212
    rad/s, 0.04% above it: a recovery at full thrust then takes another path to the same hover)."""
    chosen = protocol_starts(20, seed=0) if starts == "protocol" else any_starts(20, seed=0)
    full = CF.motor_constant * CF.max_rotor_speed**2
    assert abs(full / FIRMWARE_THRUST_MAX - 1) < 1e-3  # trained at the firmware's limit
    by_torch = fly(CRAZYFLIE, chosen, seconds=10.0)
    a = score(by_torch)
    for thrust_max in (full, None):
        controller = CrazyflieAppController(app, thrust_max=thrust_max)
        assert controller.control_hz == 50.0  # the policy's own rate, read from the app
        by_app = fly(controller, chosen, seconds=10.0, control_hz=50.0, nominal=dataclasses.asdict(CF))
        b = score(by_app)
        assert a["success_rate"] == b["success_rate"] and a["crashes"] == b["crashes"]
        assert abs(a["hover_error_m"] - b["hover_error_m"]) < 0.001  # within 0.1 cm
        if thrust_max is not None:
            position = (by_app.get(("state", "position")) - by_torch.get(("state", "position"))).abs()
            assert float(position.max()) < 0.01


# Structures shaped like the firmware's, from their documented fields (stabilizer_types.h: state_t,
# sensorData_t, setpoint_t, control_t; the app and FreeRTOS calls the glue makes)
FIRMWARE_STUBS = {
    "app.h": "",
    "FreeRTOS.h": """#include <stdint.h>
#include <stddef.h>
#define M2T(ms) (ms)
#define pdTRUE 1
#define portMAX_DELAY 0xffffffffu
""",
    "task.h": """extern int stub_critical;
#define taskENTER_CRITICAL() (++stub_critical)
#define taskEXIT_CRITICAL() (--stub_critical)
""",
    "semphr.h": """typedef struct { int given; } StaticSemaphore_t;
typedef StaticSemaphore_t *SemaphoreHandle_t;
static inline SemaphoreHandle_t xSemaphoreCreateBinaryStatic(StaticSemaphore_t *b) { b->given = 0; return b; }
static inline int xSemaphoreGive(SemaphoreHandle_t s) { s->given = 1; return pdTRUE; }
static inline int xSemaphoreTake(SemaphoreHandle_t s, uint32_t wait)
{ int g = s->given; (void)wait; s->given = 0; return g; }
""",
    "controller.h": '#include "stabilizer_types.h"\n',
    "stabilizer_types.h": """#ifndef STUB_TYPES
#define STUB_TYPES
#include <stdint.h>
#include <stdbool.h>
typedef struct { float x, y, z; } vec3;
typedef struct { float roll, pitch, yaw; } attitude_t;
typedef struct { attitude_t attitude; vec3 position; vec3 velocity; } state_t;
typedef struct { vec3 gyro; } sensorData_t;
typedef enum { modeDisable = 0, modeAbs, modeVelocity } stab_mode_t;
typedef struct { stab_mode_t x, y, z; } setpoint_mode_t;
typedef struct { vec3 position; setpoint_mode_t mode; } setpoint_t;
typedef enum { controlModeLegacy = 0, controlModeForceTorque, controlModeForce } control_mode_t;
typedef struct { control_mode_t controlMode; float normalizedForces[4]; } control_t;
#define RATE_DO_EXECUTE(RATE_HZ, TICK) ((TICK % (1000 / RATE_HZ)) == 0)
#endif
""",
}

# The stabilizer's ticks and the app task's steps, one after the other: before a setpoint, the
# first ticks of one (the forces the app task has not computed yet), after its first step
GLUE_RUN = r"""#include <stdio.h>
#include "stabilizer_types.h"
int stub_critical = 0;
void controllerOutOfTreeInit(void);
void controllerOutOfTree(control_t *, const setpoint_t *, const sensorData_t *, const state_t *, const uint32_t);
void bfcAppStep(void);
static void put(const control_t *c) { printf("%d %g %g %g %g\n", (int)c->controlMode, c->normalizedForces[0],
    c->normalizedForces[1], c->normalizedForces[2], c->normalizedForces[3]); }
int main(void)
{
    state_t state = {{0.0f, 0.0f, 0.0f}, {0.3f, -0.2f, 1.2f}, {0.0f, 0.0f, 0.0f}};
    sensorData_t sensors = {{0.0f, 0.0f, 0.0f}};
    setpoint_t none = {{0.0f, 0.0f, 1.5f}, {modeDisable, modeDisable, modeDisable}};
    setpoint_t goal = {{0.0f, 0.0f, 1.5f}, {modeAbs, modeAbs, modeAbs}};
    control_t control;
    uint32_t tick;
    controllerOutOfTreeInit();
    controllerOutOfTree(&control, &none, &sensors, &state, 0);
    put(&control);
    controllerOutOfTree(&control, &goal, &sensors, &state, 0);
    put(&control);
    bfcAppStep();
    for (tick = 1; tick < 10; ++tick) controllerOutOfTree(&control, &goal, &sensors, &state, tick);
    put(&control);
    controllerOutOfTree(&control, &none, &sensors, &state, 10);
    put(&control);
    printf("%d\n", stub_critical);
    return 0;
}
"""


@needs_cc
def test_the_glue_hands_the_estimate_to_the_app_task_and_commands_nothing_without_a_setpoint(app, tmp_path):
    """The glue against structures and FreeRTOS calls shaped like the firmware's (stubs defined
    here): zero force and controlModeForce without a setpoint, nothing before the app task's first
    step, its forces after it, zero again once the setpoint goes; critical sections balanced."""
    stubs = tmp_path / "stubs"
    stubs.mkdir()
    for name, text in FIRMWARE_STUBS.items():
        (stubs / name).write_text(text)
    (tmp_path / "run.c").write_text(GLUE_RUN)
    exe = tmp_path / "glue"
    cmd = [
        CC,
        *STRICT,
        "-I",
        str(stubs),
        "-I",
        str(app / "src"),
        str(app / "src" / "bfc_oot.c"),
        str(tmp_path / "run.c"),
    ]
    done = subprocess.run([*cmd, "-o", str(exe), "-lm"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.splitlines()
    rows = [[float(v) for v in line.split()] for line in lines[:4]]
    assert all(row[0] == 2 for row in rows)  # controlModeForce
    assert rows[0][1:] == [0.0] * 4 and rows[1][1:] == [0.0] * 4  # no setpoint; no step yet
    assert all(0.0 < f <= 1.0 for f in rows[2][1:])  # 0.3 m below the goal: it climbs
    assert rows[3][1:] == [0.0] * 4 and lines[4] == "0"


def _rows(n: int = 2000) -> np.ndarray:
    """Estimates in the firmware's units (position, velocity, attitude in degrees, gyro in deg/s,
    goal) over the protocol's states and beyond: 15 floats per row."""
    g = np.random.default_rng(0)
    scale = np.array([2, 2, 2, 3, 3, 3, 70, 70, 180, 400, 400, 400, 0.5, 0.5, 0.5])
    rows = (2 * g.random((n, 15)) - 1) * scale
    rows[:, [2, 14]] += 1.5
    return rows.astype(np.float32)


CORE_RUN = r"""#include <stdio.h>
#include "bfc_crazyflie.h"
/* each row: a reset, two steps on the row (the second with the row's velocity and rates again, so
 * the difference quotients are zero then nonzero), eight forces out */
int main(int argc, char **argv)
{
    float row[15], out[8];
    bfc_cf_state s;
    FILE *in = fopen(argc > 1 ? argv[1] : "rows.bin", "rb"), *dst = fopen(argc > 2 ? argv[2] : "out.bin", "wb");
    if (!in || !dst) return 1;
    while (fread(row, sizeof(float), 15, in) == 15) {
        float vel[3] = {row[3] + 0.5f, row[4], row[5]};
        bfc_cf_reset(&s);
        bfc_cf_step(&s, row, row + 3, row + 6, row + 9, row + 12, out);
        bfc_cf_step(&s, row, vel, row + 6, row + 9, row + 12, out + 4);
        fwrite(out, sizeof(float), 8, dst);
    }
    fclose(in);
    fclose(dst);
    return 0;
}
"""


def _run_core(app, tmp_path, target: str) -> np.ndarray:
    d = tmp_path / target
    d.mkdir()
    for name in ("bfc_policy.h", "bfc_crazyflie.h"):
        shutil.copyfile(app / "src" / name, d / name)
    (d / "run.c").write_text(CORE_RUN)
    _rows().tofile(d / "rows.bin")
    if target == "host":
        subprocess.run([CC, *STRICT, "-I", str(d), str(d / "run.c"), "-o", str(d / "run"), "-lm"], check=True)
        subprocess.run([str(d / "run"), "rows.bin", "out.bin"], cwd=d, check=True)
    else:
        cortex_m4.run(cortex_m4.build([d / "run.c"], d / "run.elf", [*STRICT[:2], "-Wall", "-Wextra", "-Werror"]), d)
    return np.fromfile(d / "out.bin", dtype=np.float32).reshape(-1, 8)


@needs_cc
@pytest.mark.skipif(cortex_m4.MISSING is not None, reason=cortex_m4.MISSING or "")
def test_the_core_gives_the_same_forces_on_the_cortex_m4(app, tmp_path):
    host, target = _run_core(app, tmp_path, "host"), _run_core(app, tmp_path, "cortex-m4")
    assert host.shape == target.shape == (2000, 8)
    assert np.abs(host - target).max() <= 1e-4  # forces in [0, 1]: float rounding, two libms
    assert (host > 0).mean() > 0.5 and not np.array_equal(host[:, :4], host[:, 4:])
