"""C export (bfc/agent/c_export.py): the header compiled by the system C compiler matches the torch
policy as the ONNX export does, flies the protocol as the torch policy does, and bad inputs fail
with one line."""

import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch
from torch import nn

from bfc.agent import PolicySpec, load_policy, save_policy
from bfc.export import CController, export_c, main
from tests import cortex_m4
from tests.export_helpers import (
    CRAZYFLIE,
    PRETRAINED,
    ROOT,
    SCALED,
    TOLERANCE,
    X500,
    hover_speed_difference,
    parity_rows,
    set_statistics,
    tiny_policy,
    torch_reference,
)

CC = shutil.which("cc")
needs_cc = pytest.mark.skipif(CC is None, reason="no system C compiler `cc` on the PATH (apt-get install gcc)")
CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]

# Reads rows of 28 floats (odometry 18, goal 3, previous command 4, integral 3) and writes rows of
# 35: [0:7] bfc_policy_step on the row (speeds, next integral); [7:14] the step after a reset,
# hover and a NULL integral; [14:21] bfc_policy_update on a freshly reset state (speeds, the
# state's integral); [21:28] the step fed [14:21] back; [28:35] a second update. The integral
# outputs start at -7: a policy without an integral leaves them alone. A policy with a command
# history gets the hover speed as its history at every call (what a reset gives it).
HARNESS = r"""
#include <stdio.h>
#include "policy.h"
#include "policy.h" /* twice: the include guard holds */

static void put(float *dst, const float *speeds, const float *integral)
{
    int k;
    for (k = 0; k < 4; ++k) dst[k] = speeds[k];
    for (k = 0; k < 3; ++k) dst[4 + k] = integral[k];
}

#if BFC_POLICY_COMMAND_HISTORY > 0
static float hist[BFC_POLICY_COMMAND_HISTORY][4];
#define HISTORY , (const float (*)[4])hist, hist
static void hover_history(void)
{
    int k;
    for (k = 0; k < 4 * BFC_POLICY_COMMAND_HISTORY; ++k) hist[k / 4][k % 4] = BFC_POLICY_HOVER_SPEED;
}
#else
#define HISTORY
static void hover_history(void) {}
#endif

int main(int argc, char **argv)
{
    float in[28], out[35], hover[4], speeds[4], integral[3];
    bfc_policy_state state;
    int k;
    FILE *src, *dst;
    if (argc != 3 || !(src = fopen(argv[1], "rb")) || !(dst = fopen(argv[2], "wb"))) return 1;
    for (k = 0; k < 4; ++k) hover[k] = BFC_POLICY_HOVER_SPEED;
    while (fread(in, sizeof(float), 28, src) == 28) {
        const float *odometry = in, *goal = in + 18, *previous = in + 21, *integral_in = in + 25;
        for (k = 0; k < 3; ++k) integral[k] = -7.0f;
        hover_history();
        bfc_policy_step(odometry, goal, previous, integral_in, speeds, integral HISTORY);
        put(out, speeds, integral);
        for (k = 0; k < 3; ++k) integral[k] = -7.0f;
        hover_history();
        bfc_policy_step(odometry, goal, hover, NULL, speeds, integral HISTORY);
        put(out + 7, speeds, integral);
        bfc_policy_reset(&state);
        bfc_policy_update(&state, odometry, goal, speeds);
        put(out + 14, speeds, state.integral);
        for (k = 0; k < 3; ++k) integral[k] = -7.0f;
        hover_history();
        bfc_policy_step(odometry, goal, out + 14, out + 18, speeds, integral HISTORY);
        put(out + 21, speeds, integral);
        bfc_policy_update(&state, odometry, goal, speeds);
        put(out + 28, speeds, state.integral);
        if (fwrite(out, sizeof(float), 35, dst) != 35) return 1;
    }
    fclose(src);
    return fclose(dst) == 0 ? 0 : 1;
}
"""


@pytest.fixture(scope="module")
def headers(tmp_path_factory):
    d = tmp_path_factory.mktemp("c")
    tiny = tiny_policy(d / "tiny.pt")
    scaled = tiny_policy(d / "scaled.pt", scales=SCALED)
    return {
        "pretrained": (PRETRAINED, export_c(PRETRAINED, d / "pretrained" / "policy.h")),
        "crazyflie": (CRAZYFLIE, export_c(CRAZYFLIE, d / "crazyflie" / "policy.h")),
        "x500": (X500, export_c(X500, d / "x500" / "policy.h")),
        "tiny": (tiny, export_c(tiny, d / "tiny" / "policy.h")),
        "scaled": (scaled, export_c(scaled, d / "scaled" / "policy.h")),
    }


def run_harness(header, rows: np.ndarray, target: str = "host") -> np.ndarray:
    """The harness's 35 outputs per row, built for and run on `target`: this machine (`cc`) or an
    emulated Cortex-M4F (tests/cortex_m4.py), from the same C."""
    harness = header.parent / "harness.c"
    harness.write_text(HARNESS)
    rows.astype(np.float32).tofile(header.parent / "rows.bin")
    if target == "cortex-m4":
        cortex_m4.run(cortex_m4.build([harness], header.parent / "harness.elf", CFLAGS), header.parent)
    else:
        binary = header.parent / "harness"
        compiled = subprocess.run(
            [CC, *CFLAGS, str(harness), "-o", str(binary), "-lm"], capture_output=True, text=True, timeout=300
        )
        assert compiled.returncode == 0, compiled.stderr  # no warning either (-Werror)
        ran = subprocess.run([str(binary), "rows.bin", "out.bin"], cwd=header.parent, timeout=120)
        assert ran.returncode == 0
    return np.fromfile(header.parent / "out.bin", dtype=np.float32).reshape(len(rows), 35)


needs_cortex_m4 = pytest.mark.skipif(bool(cortex_m4.MISSING), reason=str(cortex_m4.MISSING))
TARGETS = [pytest.param("host", marks=needs_cc), pytest.param("cortex-m4", marks=[needs_cc, needs_cortex_m4])]


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("name", ["pretrained", "crazyflie", "x500", "tiny", "scaled"])
def test_compiled_header_matches_the_torch_policy(headers, name, target):
    """On this machine and on the Crazyflie's instruction set (an emulated Cortex-M4F, whose libm
    and float code differ from the host's in the last bits: it is held to the same bound against
    torch, and to it against the host build)."""
    policy_path, header = headers[name]
    spec, _ = load_policy(policy_path)
    hover, top = spec.nominal_airframe.hover_speed, spec.nominal_airframe.max_rotor_speed
    odometry, goal, previous, integral, _ = parity_rows(spec)
    rows = torch.cat([odometry, goal, previous, integral], -1).numpy()
    out = run_harness(header, rows, target)
    if target == "cortex-m4":
        host = run_harness(header, rows, "host")
        assert hover_speed_difference(out[:, 0:4], host[:, 0:4], spec) <= TOLERANCE
        assert np.abs(out[:, 4:7] - host[:, 4:7]).max() <= 1e-6  # the integral: a few flops

    history = torch.full((2000, spec.command_history, 4), hover) if spec.command_history else None  # the harness's
    expected, _ = torch_reference(policy_path, odometry, goal, previous, integral, history)
    diff = hover_speed_difference(out[:, 0:4], expected, spec)  # away from the thrust map's 0
    assert diff <= TOLERANCE, f"max |C - torch| = {diff:.2e} hover speeds"
    inside = (expected > 0) & (expected < top)  # not all saturated motors
    assert inside.float().mean() > 0.5
    assert out[:, 0:4].min() >= 0.0 and out[:, 0:4].max() <= top
    # after a reset: hover as the previous command, a zero (here NULL) integral. Compared in the
    # policy's action units: near zero speed the thrust map's square root blows float32 rounding
    # up in rad/s (on these rows by up to 0.008 rad/s for the ONNX model too)
    after_reset, _ = torch_reference(
        policy_path, odometry, goal, torch.full((2000, 4), hover), torch.zeros(2000, 3), history
    )
    to_action = spec.make_action_map().to_action
    assert (to_action(torch.from_numpy(out[:, 7:11])) - to_action(after_reset)).abs().max() <= TOLERANCE
    observation = spec.make_observation_map(2000)
    if spec.position_integral:  # the integral it returns is PolicyObservation.integrate's
        np.testing.assert_allclose(
            out[:, 4:7], observation.integrate(integral, odometry, goal).numpy(), rtol=0, atol=1e-7
        )
        np.testing.assert_allclose(
            out[:, 11:14], observation.integrate(torch.zeros(2000, 3), odometry, goal).numpy(), rtol=0, atol=1e-7
        )
        assert np.abs(out[:, 4:7]).max() > 0.1
    else:  # and a policy without one never writes integral_out
        assert (out[:, 4:7] == -7.0).all() and (out[:, 11:14] == -7.0).all()
    # the state helpers: reset + update is the step after a reset, and the second update the
    # step fed the first one's command and integral, bit for bit
    np.testing.assert_array_equal(out[:, 14:18], out[:, 7:11])
    np.testing.assert_array_equal(out[:, 28:35][:, :4], out[:, 21:25])
    if spec.position_integral:
        np.testing.assert_array_equal(out[:, 18:21], out[:, 11:14])
        np.testing.assert_array_equal(out[:, 32:35], out[:, 25:28])


def test_header_is_self_contained_and_names_its_settings(headers):
    text = headers["pretrained"][1].read_text()
    includes = [line for line in text.splitlines() if line.startswith("#include")]
    assert includes == ["#include <math.h>"]
    assert "malloc" not in text and "static inline void bfc_policy_step(" in text
    spec, net = load_policy(PRETRAINED)
    assert "#define BFC_POLICY_CONTROL_HZ 100.0f" in text and "#define BFC_POLICY_HAS_INTEGRAL 1" in text
    assert "#define BFC_POLICY_MAX_ROTOR_SPEED 838.0f" in text and '#define BFC_POLICY_ACTION_MAP "thrust"' in text
    macs = sum(m.weight.numel() for m in net.mlp if isinstance(m, nn.Linear))
    assert f"#define BFC_POLICY_MACS {macs} " in text and macs == 41 * 128 + 128 * 128 + 128 * 4  # 41: with a history
    tiny = headers["tiny"][1].read_text()
    assert "#define BFC_POLICY_CONTROL_HZ 250.0f" in tiny and "#define BFC_POLICY_HAS_INTEGRAL 0" in tiny
    assert "expm1f" in tiny and '#define BFC_POLICY_ACTION_MAP "speed"' in tiny


@needs_cc
@pytest.mark.parametrize(
    "spec",
    [
        PolicySpec(observation="odometry", position_integral=True, hidden=(8,), activation="tanh", squash=True),
        PolicySpec(observation="odometry", hidden=(8, 8, 8), activation="relu", action_map="thrust"),
        PolicySpec(include_acceleration=True, position_integral=True, hidden=(8, 8, 8), activation="elu", squash=True),
        PolicySpec(observation="odometry", hidden=(8, 8), activation="tanh", normalize_observation=True),
    ],
    ids=["odometry-integral-tanh-squash", "odometry-3-layers", "heading-all-elu-squash", "paper-normalized"],
)
def test_every_observation_kind_and_activation(tmp_path, spec):
    """The paper's observation, the squash, three hidden layers: the other branches of the maps."""
    torch.manual_seed(4)
    net = spec.make_net()
    with torch.no_grad():
        for p in net.mlp.parameters():
            p.normal_(0.0, 0.3)
        set_statistics(net)
    save_policy(tmp_path / "p.pt", spec, net)
    header = export_c(tmp_path / "p.pt", tmp_path / "policy.h")
    odometry, goal, previous, integral, _ = parity_rows(spec)
    out = run_harness(header, torch.cat([odometry, goal, previous, integral], -1).numpy())
    expected, _ = torch_reference(tmp_path / "p.pt", odometry, goal, previous, integral)
    hover = spec.nominal_airframe.hover_speed
    assert np.abs(out[:, 0:4] - expected.numpy()).max() / hover <= TOLERANCE


@needs_cc
def test_controller_flies_the_protocol_as_the_torch_policy(headers):
    from bfc.evaluation import fly, protocol_starts, success

    starts = protocol_starts(20, seed=0)
    controller = CController(headers["pretrained"][1])
    assert controller.control_hz == 100.0 and controller.metadata["position_integral"]
    by_torch = fly(str(PRETRAINED), starts, seconds=10.0)
    by_c = fly(controller, starts, seconds=10.0, control_hz=controller.control_hz)
    assert by_c.shape == by_torch.shape  # the same rate: 1000 steps at 100 Hz
    assert success(by_c).tolist() == success(by_torch).tolist()
    assert success(by_c).all()
    position = (by_c.get(("state", "position")) - by_torch.get(("state", "position"))).abs().max()
    assert position < 1e-3
    assert controller.integral.shape == (20, 3)


def test_unsupported_activation_is_one_line(tmp_path, monkeypatch):
    from bfc.agent import actor

    monkeypatch.setitem(actor.ACTIVATIONS, "silu", nn.SiLU)  # a spec bfc may allow one day
    spec = PolicySpec(hidden=(8,), activation="silu")
    save_policy(tmp_path / "silu.pt", spec, spec.make_net())
    with pytest.raises(ValueError, match="does not support activation 'silu'") as err:
        export_c(tmp_path / "silu.pt", tmp_path / "silu.h")
    assert "\n" not in str(err.value) and "elu, relu, tanh" in str(err.value)
    assert main([str(tmp_path / "silu.pt"), str(tmp_path / "silu.h")]) == 2
    assert not (tmp_path / "silu.h").exists()


def test_cli_writes_a_header_and_fails_cleanly(tmp_path, capsys):
    out = tmp_path / "sub" / "policy.h"
    assert main([str(PRETRAINED), str(out)]) == 0  # the format from the suffix
    assert out.read_text().startswith("/* policy.h: the bfc policy `policy.pt`") and "100 Hz" in capsys.readouterr().out
    assert main([str(PRETRAINED), str(tmp_path / "policy.inc"), "--format", "c"]) == 0  # any name with --format
    assert (tmp_path / "policy.inc").is_file()
    capsys.readouterr()
    bad = [
        ([str(tmp_path / "a.onnx"), "--format", "c"], "contradicts the output name"),  # a mismatch
        ([str(tmp_path / "a.h"), "--format", "onnx"], "contradicts the output name"),
        ([str(tmp_path / "a.txt")], "cannot tell the format"),  # an unknown suffix, no --format
        ([str(tmp_path / "a.h"), "--opset", "17"], "--opset applies to the ONNX format only"),
        ([str(out / "x.h")], "is a file, not a directory"),  # unwritable: under a file
        ([str(tmp_path), "--format", "c"], "is a directory"),
    ]
    for args, message in bad:
        assert main([str(PRETRAINED), *args]) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("error: ") and message in err, err
    assert not (tmp_path / "a.onnx").exists() and not (tmp_path / "a.h").exists()
    unwritable = subprocess.run(  # a path the OS refuses, through the real command line
        [sys.executable, "-m", "bfc.export", str(PRETRAINED), "/proc/bfc-policy.h"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert unwritable.returncode == 2
    lines = unwritable.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: cannot write the C header to /proc/bfc-policy.h")
