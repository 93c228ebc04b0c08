"""Thrust and body torques <-> the four motor speeds of an airframe (its layout and spins).

Shared by the Lee controller and the MPC's attitude loop, so both command the airframe the env
flies: the same rotor positions, k_f, moment constant, spin directions and speed limits.
"""

from __future__ import annotations

import torch

from bfc.envs.params import AirframeParams


def allocation_matrix(airframe: AirframeParams) -> torch.Tensor:
    """(4, 4) float64 M with [thrust, torque_x, torque_y, torque_z] = M @ rotor forces (N).

    A rotor at (x, y) pushing F along body z gives torque r x F = (y F, -x F, 0); its reaction
    yaw moment is spin * moment_constant * F (AirframeParams.torque_rows, what the env applies).
    """
    rows = [[1.0] * 4, *zip(*airframe.torque_rows(), strict=True)]
    return torch.tensor(rows, dtype=torch.float64)


class Mixer:
    """Batched: `speeds = mixer(thrust (n,), torque (n, 3))` in rad/s, within [min, max]. When a
    motor would saturate, the thrust gives way first so the torques (the attitude) are kept."""

    def __init__(self, airframe: AirframeParams):
        self.airframe = airframe
        self.matrix = allocation_matrix(airframe)
        self.inverse = torch.linalg.inv(self.matrix)
        self.max_speed = float(airframe.max_rotor_speed)

    def __call__(self, thrust: torch.Tensor, torque: torch.Tensor) -> torch.Tensor:
        if thrust.shape != torque.shape[:-1] or torque.shape[-1] != 3:
            raise ValueError(
                f"thrust (n,) and torque (n, 3) expected, got {tuple(thrust.shape)} and {tuple(torque.shape)}"
            )
        wrench = torch.cat((thrust.unsqueeze(-1), torque), -1).to(torch.float64)
        forces = wrench @ self.inverse.T
        # Saturation gives way in thrust, not torque: shift all four forces together (which changes
        # only the thrust) to bring them inside [min, max] where the spread allows, then clip.
        f_min = self.airframe.motor_constant * self.airframe.min_rotor_speed**2
        f_max = self.airframe.motor_constant * self.max_speed**2
        low = (f_min - forces.min(-1, keepdim=True).values).clamp_min(0.0)
        high = (forces.max(-1, keepdim=True).values - f_max).clamp_min(0.0)
        forces = (forces + low - high).clamp(f_min, f_max)
        return (forces / self.airframe.motor_constant).sqrt()

    def wrench(self, speeds: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(thrust (n,), torque (n, 3)) that motor speeds (n, 4) produce: the inverse map."""
        out = (self.airframe.motor_constant * speeds.to(torch.float64) ** 2) @ self.matrix.T
        return out[..., 0], out[..., 1:]
