"""What the C export costs on the Crazyflie's instruction set, measured on an emulated Cortex-M4F.

    python bench/cortex_m4_cost.py [--policy pretrained/policy.pt|tiny] [--hz 168e6]

Builds the policy's header (`python -m bfc.export POLICY policy.h`) with Debian's
`arm-none-eabi-gcc -O2` for a Cortex-M4F (the STM32F405's core) and runs it under
`qemu-system-arm -M mps2-an386 -icount shift=0` (tests/cortex_m4.py), where the virtual clock
advances one nanosecond per instruction: SysTick read around each `bfc_policy_step` on the 2000
parity rows of tests/test_export.py gives the instructions per call (40 per tick; the mean over
the rows resolves finer). Prints the instructions per call (mean, min, max), the share of the
policy's control period they take at --hz assuming one cycle per instruction (an assumption: on a
real STM32F405 loads from flash behind the ART accelerator, VDIV and VSQRT take more, dual-issued
nothing), the flash the policy takes (`arm-none-eabi-size` of the object that holds one call:
code and weights) and its stack use (`-fstack-usage` of that call). Needs gcc-arm-none-eabi,
libnewlib-arm-none-eabi and qemu-system-arm (Debian's; `make test` installs them as root).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests.cortex_m4 and the parity rows of tests/test_export.py

from bfc.agent import load_policy  # noqa: E402
from bfc.agent.c_controller import CFLAGS  # noqa: E402
from bfc.export import export_c  # noqa: E402
from tests import cortex_m4  # noqa: E402
from tests.export_helpers import parity_rows, tiny_policy  # noqa: E402

# One call of the policy, in a function of its own: its object is the policy's flash, its
# -fstack-usage line the call's stack.
CALL = r"""
#include "policy.h"
__attribute__((noinline)) void policy_call(const float *row, float *speeds, float *integral
#if BFC_POLICY_COMMAND_HISTORY > 0
    , const float (*history)[4], float (*history_out)[4]
#endif
)
{
    bfc_policy_step(row, row + 18, row + 21, row + 25, speeds, integral
#if BFC_POLICY_COMMAND_HISTORY > 0
        , history, history_out
#endif
    );
}
"""

COUNT = r"""
#include <stdio.h>
#include "policy.h"
#define SYST_CSR (*(volatile unsigned int *)0xE000E010u)
#define SYST_RVR (*(volatile unsigned int *)0xE000E014u)
#define SYST_CVR (*(volatile unsigned int *)0xE000E018u)
#if BFC_POLICY_COMMAND_HISTORY > 0
static float hist[BFC_POLICY_COMMAND_HISTORY][4], hist_out[BFC_POLICY_COMMAND_HISTORY][4];
void policy_call(const float *row, float *speeds, float *integral, const float (*h)[4], float (*ho)[4]);
#define CALL(row) policy_call(row, speeds, integral, (const float (*)[4])hist, hist_out)
#else
void policy_call(const float *row, float *speeds, float *integral);
#define CALL(row) policy_call(row, speeds, integral)
#endif

int main(int argc, char **argv)
{
    float in[28], speeds[4], integral[3];
    unsigned long long total = 0;
    unsigned int lo = 0xFFFFFFFFu, hi = 0, n = 0, t0, t1, ticks;
    int k;
    FILE *src;
    if (argc < 2 || !(src = fopen(argv[1], "rb"))) return 1;
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0;
    SYST_CSR = 5u; /* on, the CPU clock, no interrupt */
    while (fread(in, sizeof(float), 28, src) == 28) {
#if BFC_POLICY_COMMAND_HISTORY > 0
        for (k = 0; k < 4 * BFC_POLICY_COMMAND_HISTORY; ++k) hist[k / 4][k % 4] = in[21 + k % 4];
#else
        (void)k;
#endif
        t0 = SYST_CVR;
        CALL(in);
        t1 = SYST_CVR;
        ticks = (t0 - t1) & 0xFFFFFFu; /* a 24-bit down-counter */
        total += ticks;
        if (ticks < lo) lo = ticks;
        if (ticks > hi) hi = ticks;
        ++n;
    }
    printf("%u %llu %u %u\n", n, total, lo, hi);
    return 0;
}
"""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default=str(ROOT / "pretrained" / "policy.pt"), help="a policy file, or tiny")
    parser.add_argument("--hz", type=float, default=168e6, help="the target's clock (the STM32F405's 168 MHz)")
    args = parser.parse_args()
    if cortex_m4.MISSING:
        print(f"error: {cortex_m4.MISSING}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        policy = tiny_policy(d / "tiny.pt") if args.policy == "tiny" else Path(args.policy)
        spec, _ = load_policy(policy)
        export_c(policy, d / "policy.h")
        (d / "call.c").write_text(CALL)
        (d / "count.c").write_text(COUNT)
        odometry, goal, previous, integral, _ = parity_rows(spec)
        torch.cat([odometry, goal, previous, integral], -1).numpy().astype(np.float32).tofile(d / "rows.bin")
        elf = cortex_m4.build([d / "call.c", d / "count.c"], d / "count.elf", [*CFLAGS, "-fstack-usage"])
        calls, total, lo, hi = (int(v) for v in cortex_m4.run(elf, d, count_instructions=True).split())
        size = subprocess.run(["arm-none-eabi-size", str(d / "call.o")], capture_output=True, text=True, check=True)
        text, data, bss = (int(v) for v in size.stdout.splitlines()[1].split()[:3])
        frames = {m[1]: int(m[2]) for m in re.finditer(r":(\w+)\t(\d+)\t", (d / "call.su").read_text())}
    per_tick = cortex_m4.INSTRUCTIONS_PER_TICK
    mean, period = total * per_tick / calls, 1.0 / spec.control_hz
    seconds = mean / args.hz
    rows = [
        (
            f"instructions per bfc_policy_step ({calls} rows)",
            f"{mean:,.0f} (min {lo * per_tick:,}, max {hi * per_tick:,})",
        ),
        (
            f"at {args.hz / 1e6:g} MHz, 1 cycle per instruction",
            f"{seconds * 1e6:,.0f} us ({seconds / period:.1%} of {period * 1e3:g} ms)",
        ),
        (
            "flash (code + weights of the call's object)",
            f"{(text + data) / 1024:.1f} KiB (text {text:,} B, data {data} B)",
        ),
        ("RAM outside the stack (bss)", f"{bss} B"),
        (
            "stack of one call (-fstack-usage: every frame of the call's object; libm's not counted)",
            f"{sum(frames.values()):,} B ({', '.join(f'{k} {v}' for k, v in frames.items())})",
        ),
    ]
    print(f"# {policy} ({spec.observation_size} inputs, hidden {list(spec.hidden)}, {spec.control_hz:g} Hz)")
    print(f"# arm-none-eabi-gcc {' '.join(cortex_m4.ARCH)} {' '.join(CFLAGS)}; qemu-system-arm -M mps2-an386")
    print("| | measured |")
    print("|---|---|")
    for name, value in rows:
        print(f"| {name} | {value} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
