"""Wall-clock of one in-training evaluation: the protocol's 100 starts flown for 10 s by a policy
file, as `train.py` evaluates every `eval.interval_frames` (ProtocolEvaluator: one batched env,
the deterministic policy, the judge).

    python bench/eval_time.py [--policy pretrained/policy.pt] [--rounds 5]

Prints the median over rounds (shared cloud cores change speed from one second to the next) and
raw MuJoCo's time for the same physics (100 bodies, the policy's control rate, 10 s, in-air hover):
the floor under any evaluation of this length. Three, in alternating rounds: the pipeline
(`run_flights`' default) on the training step (what training's validation flies, eval.physics_dt
null) and on the reference 0.002 s step (evaluate.py's test flights), and TorchRL's `env.step` on
the reference step (the pipeline's flights, bit for bit).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import mujoco
import torch
from env_throughput import hover_rate  # bench/ is the script's directory
from omegaconf import OmegaConf

from bfc.agent import load_policy
from bfc.config import compose
from bfc.envs import REFERENCE_PHYSICS_DT
from bfc.evaluation.evaluator import ProtocolEvaluator
from bfc.factory import make_base_env


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", default="pretrained/policy.pt")
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args()
    torch.set_num_threads(1)
    spec, actor = load_policy(args.policy)
    hz = spec.control_hz
    cfg = compose(
        [
            f"env.control_hz={hz}",
            "eval.validation_seed=0",  # the test starts
            f"model.position_integral={spec.position_integral}",
            f"model.include_acceleration={spec.include_acceleration}",
            f"model.observation={spec.observation}",
            f"model.action_map={spec.action_map}",
            f"model.actor_hidden=[{','.join(map(str, spec.hidden))}]",
            f"model.activation={spec.activation}",
        ]
    )
    reference = OmegaConf.merge(cfg, {"eval": {"physics_dt": REFERENCE_PHYSICS_DT}})
    evaluators = {
        "pipeline, training step (in-training validation)": ProtocolEvaluator(cfg),
        f"pipeline, reference {REFERENCE_PHYSICS_DT} s (evaluate.py)": ProtocolEvaluator(reference),
        f"TorchRL env.step, reference {REFERENCE_PHYSICS_DT} s": ProtocolEvaluator(reference, torchrl=True),
    }
    times, success = {name: [] for name in evaluators}, {}
    for ev in evaluators.values():
        ev(actor)  # warm-up
    for _ in range(args.rounds):  # alternating rounds: shared cores change speed
        for name, ev in evaluators.items():
            t = time.perf_counter()
            success[name] = ev(actor)["eval/success_rate"]
            times[name].append(time.perf_counter() - t)
    for ev in evaluators.values():
        ev.close()
    steps, raw = round(cfg.eval.seconds * hz), {}
    for label, physics_dt in (("training step", None), (f"reference {REFERENCE_PHYSICS_DT} s", REFERENCE_PHYSICS_DT)):
        env = make_base_env(
            OmegaConf.merge(cfg, {"env": {"physics_dt": physics_dt}}), num_envs=cfg.eval.num_starts, randomize=False
        )
        raw[label] = min(env.num_envs * steps / hover_rate(env, steps) for _ in range(3))  # seconds, best of 3
        env.close()
    print(
        f"# {platform.processor() or platform.machine()}, mujoco {mujoco.__version__}, torch {torch.__version__}; "
        f"{args.policy} at {hz:g} Hz, {cfg.eval.num_starts} starts, {cfg.eval.seconds:g} s"
    )
    for name, t in times.items():
        print(
            f"evaluation ({name}): median {statistics.median(t):.2f} s (min {min(t):.2f}, max {max(t):.2f}, "
            f"{args.rounds} rounds; success {success[name]:.2f})"
        )
    for label, seconds in raw.items():
        print(f"raw MuJoCo for the same physics ({label}): {seconds:.2f} s")


if __name__ == "__main__":
    main()
