"""`CController`: fly a C-exported policy (bfc.agent.c_export) from Python, through ctypes.

So that the header a flight computer compiles is the code the simulator flies: `CController`
compiles it with the system C compiler into a shared library (with a small wrapper that runs
`bfc_policy_step` over a batch of drones) and keeps the per-drone state, the previous command
and the integral, exactly as `OnnxController` does. `build_library` is the compile step alone.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import tempfile
import weakref
from pathlib import Path

import numpy as np

from bfc.agent.c_export import PREFIX
from bfc.agent.fed_back import FedBackController

CFLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Werror")
_HEADER_COPY = "bfc_exported_policy.h"
# the library's entry points: a batch loop over the header's step, and its settings
_WRAPPER = """#include <stddef.h>
#include "{header}"

void bfc_lib_step_rows(int n, const float *odometry, const float *goal, const float *previous,
        const float *integral_in, float *speeds, float *integral_out, const float *history_in, float *history_out)
{{
    int r;
    for (r = 0; r < n; ++r) {{
        {p}_step(odometry + 18 * r, goal + 3 * r, previous + 4 * r, integral_in ? integral_in + 3 * r : NULL,
            speeds + 4 * r, integral_out ? integral_out + 3 * r : NULL
#if {P}_COMMAND_HISTORY > 0
            , (const float (*)[4])(history_in + 4 * {P}_COMMAND_HISTORY * r),
            (float (*)[4])(history_out + 4 * {P}_COMMAND_HISTORY * r)
#endif
        );
    }}
#if {P}_COMMAND_HISTORY == 0
    (void)history_in;
    (void)history_out;
#endif
}}

double bfc_lib_setting(int which)
{{
    switch (which) {{
    case 0: return {P}_CONTROL_HZ;
    case 1: return {P}_HOVER_SPEED;
    case 2: return {P}_MAX_ROTOR_SPEED;
    case 3: return {P}_HAS_INTEGRAL;
    case 4: return {P}_OBSERVATION_SIZE;
    case 6: return {P}_COMMAND_HISTORY;
    default: return {P}_MACS;
    }}
}}

const char *bfc_lib_action_map(void) {{ return {P}_ACTION_MAP; }}
"""


def find_compiler(cc: str | None = None) -> str:
    """The C compiler to use: `cc`, else $CC, else `cc`; FileNotFoundError (one line) if absent."""
    name = cc or os.environ.get("CC") or "cc"
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"no C compiler {name!r} on the PATH: install one (e.g. apt-get install gcc) or set CC")
    return found


def build_library(header_path, out_dir, cc: str | None = None) -> Path:
    """Compile the exported header at `header_path` into `out_dir`/libbfc_policy.so
    (`cc -std=c99 -O2 -Wall -Wextra -Werror -shared -fPIC`); RuntimeError with the compiler's
    first error line when it fails."""
    header_path, out_dir = Path(header_path), Path(out_dir)
    if not header_path.is_file():
        raise FileNotFoundError(f"no C header at {header_path}: write one with python -m bfc.export policy.pt policy.h")
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(header_path, out_dir / _HEADER_COPY)
    source = out_dir / "bfc_policy_lib.c"
    source.write_text(_WRAPPER.format(header=_HEADER_COPY, p=PREFIX, P=PREFIX.upper()))
    return compile_library(source, out_dir / "libbfc_policy.so", str(header_path), cc=cc)


def compile_library(source: Path, library: Path, what: str, cc: str | None = None, flags=()) -> Path:
    """`source` compiled into the shared library `library` (CFLAGS, `flags`, -lm); RuntimeError
    naming `what` with the compiler's first error line when it fails."""
    command = [find_compiler(cc), *CFLAGS, *flags, "-shared", "-fPIC", str(source), "-o", str(library), "-lm"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        first = next((line for line in result.stderr.splitlines() if "error" in line), result.stderr.strip()[:300])
        raise RuntimeError(f"compiling {what} failed: {first}")
    return library


def _pointer(array: np.ndarray | None):
    return None if array is None else array.ctypes.data_as(ctypes.c_void_p)


class CController(FedBackController):
    """Flies an exported C header: reads `"odometry"` and `"goal"`, writes `"action"` (motor speeds,
    rad/s), and feeds its own last command back as `previous_motor_speeds` (and, for a policy
    with a position integral, its own integral), as `OnnxController` does.

    `fly(CController("policy.h"), starts, control_hz=controller.control_hz)` flies it as trained.
    The state it feeds back restarts as `FedBackController` says. cc: the C compiler (default $CC,
    else `cc`).
    """

    def __init__(self, header_path, cc: str | None = None):
        super().__init__()
        self.path = Path(header_path)
        build_dir = tempfile.mkdtemp(prefix="bfc-c-policy-")
        self._cleanup = weakref.finalize(self, shutil.rmtree, build_dir, True)
        self.library_path = build_library(self.path, build_dir, cc=cc)
        lib = ctypes.CDLL(str(self.library_path))
        lib.bfc_lib_step_rows.argtypes = [ctypes.c_int] + [ctypes.c_void_p] * 8
        lib.bfc_lib_step_rows.restype = None
        lib.bfc_lib_setting.argtypes = [ctypes.c_int]
        lib.bfc_lib_setting.restype = ctypes.c_double
        lib.bfc_lib_action_map.restype = ctypes.c_char_p
        self._lib = lib
        self.control_hz = lib.bfc_lib_setting(0)
        self.hover_speed = lib.bfc_lib_setting(1)
        self.max_rotor_speed = lib.bfc_lib_setting(2)
        self.command_history = int(lib.bfc_lib_setting(6))
        self.metadata = {
            "control_hz": self.control_hz,
            "hover_speed": self.hover_speed,
            "max_rotor_speed": self.max_rotor_speed,
            "position_integral": bool(lib.bfc_lib_setting(3)),
            "observation_size": int(lib.bfc_lib_setting(4)),
            "macs": int(lib.bfc_lib_setting(5)),
            "command_history": int(lib.bfc_lib_setting(6)),
            "action_map": lib.bfc_lib_action_map().decode(),
        }

    def step(self, odometry: np.ndarray, goal: np.ndarray, previous: np.ndarray, integral=None, history=None):
        """One control step for n drones, as the ONNX graph: (motor speeds (n, 4), the next
        integral (n, 3), or None for a policy without one). Plain float32 arrays in and out;
        `history` (n, k, 4) rad/s for a policy with a command history (hover when None)."""
        odometry = np.ascontiguousarray(odometry, dtype=np.float32)
        n = odometry.shape[0]
        goal = np.ascontiguousarray(np.broadcast_to(goal, (n, 3)), dtype=np.float32)
        previous = np.ascontiguousarray(previous, dtype=np.float32)
        if odometry.shape != (n, 18) or previous.shape != (n, 4):
            raise ValueError(f"odometry must be (n, 18) and previous (n, 4), got {odometry.shape}, {previous.shape}")
        speeds = np.empty((n, 4), dtype=np.float32)
        integral_out = None
        if self.metadata["position_integral"]:
            integral = None if integral is None else np.ascontiguousarray(integral, dtype=np.float32).reshape(n, 3)
            integral_out = np.empty((n, 3), dtype=np.float32)
        else:
            integral = None
        history_in = history_out = None
        if self.command_history:
            shape = (n, self.command_history, 4)
            history_in = np.full(shape, self.hover_speed, np.float32) if history is None else history
            history_in = np.ascontiguousarray(history_in, dtype=np.float32).reshape(shape)
            history_out = np.empty(shape, dtype=np.float32)
        self._lib.bfc_lib_step_rows(
            n,
            _pointer(odometry),
            _pointer(goal),
            _pointer(previous),
            _pointer(integral),
            _pointer(speeds),
            _pointer(integral_out),
            _pointer(history_in),
            _pointer(history_out),
        )
        return speeds, integral_out
