"""The protocol inside training: fixed starts in the air, the deterministic policy, the one judge.

It flies through `run_flights` only: training never imports the classical controllers.
"""

from __future__ import annotations

import torch
from omegaconf import OmegaConf

from bfc import keys
from bfc.evaluation.flights import run_flights
from bfc.evaluation.judge import judge
from bfc.evaluation.metrics import tail_distance, tilt_degrees
from bfc.evaluation.protocol import protocol_starts
from bfc.factory import make_env


class ProtocolEvaluator:
    """Flies a policy from `cfg.eval`'s starts (validation starts during training) and returns the
    `eval/*` metrics: success rate, position and tilt error over the last 2 s of the flights that
    did not crash, crash rate. `lean=False` flies through TorchRL's `env.step` (the same flights,
    slower: bench/eval_time.py compares the two)."""

    def __init__(self, cfg, lean: bool = True):
        self.lean = lean
        e = cfg.eval
        # eval.physics_dt, or (null) the step training integrates with: validation flies the
        # simulator the policy learns in; the test flights of evaluate.py fly the reference step
        physics = {} if e.physics_dt is None else {"physics_dt": e.physics_dt}
        eval_cfg = OmegaConf.merge(cfg, {"env": {"episode_seconds": e.seconds + 1.0, **physics}})
        self.env = make_env(eval_cfg, num_envs=e.num_starts, samplers=False, noise={"kind": "none"}, given_starts=True)
        self.env.set_seed(e.seed)
        self.starts = protocol_starts(e.num_starts, e.seed)
        self.steps = round(e.seconds / self.env.base_env.dt)
        self.threshold, self.hold_seconds = e.threshold, e.hold_seconds

    def __call__(self, actor) -> dict[str, float]:
        flights = run_flights(self.env, actor, self.starts, self.steps, lean=self.lean)
        verdict = judge(flights, self.threshold, self.hold_seconds)
        err = tail_distance(flights)
        tail = slice(-err.shape[1], None)
        tilt = tilt_degrees(flights.get(keys.QUATERNION)[:, tail])
        survived = flights.get("alive")[:, -1]
        pick = survived if bool(survived.any()) else torch.ones_like(survived)
        return {
            "eval/success_rate": verdict.success.float().mean().item(),
            "eval/position_error": err[pick].mean().item(),
            "eval/attitude_error": tilt[pick].mean().item(),
            "eval/crash_rate": 1.0 - survived.float().mean().item(),
        }

    def close(self) -> None:
        self.env.close()
