"""The protocol inside training: fixed starts in the air, the deterministic policy, the one judge.

It flies through `run_flights` only: training never imports the classical controllers.
"""

from __future__ import annotations

from bfc.agent import PolicySpec
from bfc.evaluation.flights import run_flights
from bfc.evaluation.judge import judge
from bfc.evaluation.metrics import hover_error, hover_tilt
from bfc.evaluation.protocol import protocol_starts
from bfc.factory import FlightConditions, make_flight_env, physics_step


class ProtocolEvaluator:
    """Flies a policy network from the validation starts (`eval.validation_seed`) and returns the
    `eval/*` metrics: success rate, crash rate, and over the successful flights the hover error and
    tilt (bfc.evaluation.metrics: the same numbers the reports call so). `torchrl=True` flies
    through TorchRL's `env.step` (the same flights, slower: bench/eval_time.py compares the two)."""

    def __init__(self, cfg, torchrl: bool = False):
        self.torchrl = torchrl
        e = cfg.eval
        # eval.physics_dt, or (null) the step training integrates with: validation flies the
        # simulator the policy learns in; the test flights of evaluate.py fly the reference step
        flight = FlightConditions(
            seconds=e.seconds,
            physics_dt=physics_step(cfg) if e.physics_dt is None else e.physics_dt,
            seed=e.validation_seed,
        )
        policy = PolicySpec.from_config(cfg)
        self.env = make_flight_env(e.num_starts, flight, policy=policy, num_threads=cfg.env.num_threads)
        self.starts = protocol_starts(e.num_starts, e.validation_seed)
        self.steps = round(e.seconds / self.env.base_env.dt)
        self.threshold, self.hold_seconds = e.threshold, e.hold_seconds
        self.flights = None

    def __call__(self, net) -> dict[str, float]:
        flights = run_flights(self.env, net, self.starts, self.steps, torchrl=self.torchrl)
        self.flights = flights  # the last evaluation's flights (logger.video films one)
        verdict = judge(flights, self.threshold, self.hold_seconds)
        survived = flights.get("alive")[:, -1]
        metrics = {
            "eval/success_rate": verdict.success.float().mean().item(),
            "eval/crash_rate": 1.0 - survived.float().mean().item(),
        }
        error, tilt = hover_error(flights, verdict.success), hover_tilt(flights, verdict.success)
        if error is not None:
            metrics["eval/hover_error"], metrics["eval/attitude_error"] = error, tilt
        return metrics

    def video(self, title: str):
        """The last evaluation's most tilted start as a TensorBoard video summary (bfc.evaluation.video)."""
        from bfc.evaluation.video import clips_from_flights, pick_starts, tensorboard_video

        chosen = pick_starts(self.starts, 1, "tilted")
        airframe = self.env.base_env.airframe
        clip = clips_from_flights(self.flights, self.starts, chosen, self.threshold, label=title, airframe=airframe)[0]
        return tensorboard_video("eval/video", clip)

    def close(self) -> None:
        self.env.close()
