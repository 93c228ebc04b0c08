"""C on the Crazyflie's instruction set: a program built with Debian's `gcc-arm-none-eabi` for a
Cortex-M4F (the STM32F405's core: `-mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard`)
and run under Debian's `qemu-system-arm` on the MPS2 AN386 board (a Cortex-M4) with semihosting,
so that it reads and writes files in its working directory as the host harness does. Used by
tests/test_export_c.py (parity on the target) and bench/cortex_m4_cost.py (instructions per call).

The program's `main` is renamed `bfc_main` and called by cortex_m4/startup.c (the vector table,
the FPU on, .bss cleared, newlib's semihosted I/O) with argv = {"bfc", "rows.bin", "out.bin"}.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

HERE = Path(__file__).resolve().parent / "cortex_m4"
GCC, QEMU = shutil.which("arm-none-eabi-gcc"), shutil.which("qemu-system-arm")
MISSING = (
    None
    if GCC and QEMU
    else "no Cortex-M4 toolchain or emulator (apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi "
    "qemu-system-arm; `make test` installs them as root)"
)
ARCH = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
# QEMU's clock for mps2-an386 is 25 MHz; with -icount shift=0 each instruction advances the
# virtual clock one nanosecond, so one SysTick tick (CPU clock) is 40 instructions
INSTRUCTIONS_PER_TICK = 40


def build(sources: list[Path], out: Path, cflags: list[str]) -> Path:
    """An ELF for the board from C `sources` (their `main` renamed), compiled with `cflags`."""
    objects = []
    for src in [*sources, HERE / "startup.c"]:
        obj = out.parent / (src.stem + ".o")
        flags = cflags if src in sources else ["-O2"]
        _run([GCC, *ARCH, *flags, "-Dmain=bfc_main", "-I", str(out.parent), "-c", str(src), "-o", str(obj)])
        objects.append(str(obj))
    link = ["--specs=rdimon.specs", "-nostartfiles", "-T", str(HERE / "link.ld")]
    _run([GCC, *ARCH, *link, *objects, "-lm", "-o", str(out)])
    return out


def run(elf: Path, cwd: Path, count_instructions: bool = False, timeout: int = 300) -> str:
    """Run `elf` on the emulated board in `cwd` (its files are the program's); its stdout.
    count_instructions: one nanosecond of virtual time per instruction (-icount shift=0)."""
    cmd = [QEMU, "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "none"]
    cmd += ["-semihosting-config", "enable=on,target=native", "-kernel", str(elf)]
    if count_instructions:
        cmd += ["-icount", "shift=0"]
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"{elf.name} on the emulated Cortex-M4 exited {done.returncode}: {done.stderr[-2000:]}")
    return done.stdout


def _run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:2])} ... failed: {done.stderr[-3000:]}")
