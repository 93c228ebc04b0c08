"""The deployable policy file (`policy.pt`): a PolicySpec, the network's weights and a note.

A policy file is data, never code: a dict of tensors, numbers and strings that loads with
`torch.load(path, weights_only=True)`:

    {"format": "bfc-policy-v2", "spec": PolicySpec.to_dict(), "state_dict": GaussianActor's, "info": {...}}

The spec holds every constant the policy's maps use, the observation's scales included; a v2 file
written before those (or some of them) were stored loads with the values it was trained with
(LEGACY_OBSERVATION_SCALES).

It is written atomically (a temporary name, then a rename). Files of the earlier format
(`bfc-policy-v1`: `model`, `env` and `observation` dicts) are read by `_read_v1`, the one legacy
reader; anything else is refused with one line naming what was found.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from bfc.agent.actor import GaussianActor
from bfc.agent.atomic import atomic_write
from bfc.agent.spec import PolicySpec

POLICY_FORMAT = "bfc-policy-v2"
# The observation constants every file written before they were stored was trained with (files
# whose spec has no `observation_scales`: v1, and v2 before it; a file that stores some of them
# has the rest from here): frozen here, not read from the defaults, so that a new default never
# changes an old policy. The settled integration came later: a settled radius equal to the radius
# integrates exactly where the policies before it did.
LEGACY_OBSERVATION_SCALES = {
    "position_clip": 3.0,
    "velocity_scale": 0.5,
    "angular_velocity_scale": 0.1,
    "acceleration_scale": 0.05,
    "integral_radius": 0.3,
    "integral_limit": 0.5,
    "integral_scale": 4.0,
    "integral_settled_radius": 0.3,
    "integral_settled_speed": 0.2,
}


@dataclass
class PolicyFile:
    spec: PolicySpec
    state_dict: dict
    info: dict

    def net(self) -> GaussianActor:
        """The network with the file's weights, in eval mode."""
        net = self.spec.make_net()
        net.load_state_dict(self.state_dict)
        return net.eval()


def atomic_save(obj, path) -> None:
    """torch.save, atomically (bfc.agent.atomic): a reader never sees half a file."""
    atomic_write(path, lambda tmp: torch.save(obj, tmp))


def save_policy(path, spec: PolicySpec, net: GaussianActor, info: dict | None = None) -> None:
    payload = {
        "format": POLICY_FORMAT,
        "spec": spec.to_dict(),
        "state_dict": {k: v.detach().clone() for k, v in net.state_dict().items()},
        "info": dict(info or {}),
    }
    atomic_save(payload, path)


def read_policy(path) -> PolicyFile:
    """Load and check a policy file; FileNotFoundError / ValueError (one line) otherwise."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no policy file at {path}: pass the path of a policy.pt written by train.py")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unpickling failure means "not a policy file"
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(
            f"{path} is not a loadable bfc policy file (weights_only load failed: {first[:200]})"
        ) from None
    found = payload.get("format") if isinstance(payload, dict) else None
    try:
        if found == POLICY_FORMAT:
            stored = payload["spec"].get("observation_scales") or {}
            spec = {**payload["spec"], "observation_scales": {**LEGACY_OBSERVATION_SCALES, **stored}}  # stored win
            policy = PolicyFile(PolicySpec.from_dict(spec), payload["state_dict"], payload.get("info", {}))
        elif found == "bfc-policy-v1":
            policy = _read_v1(payload)
        else:
            what = "a training checkpoint" if isinstance(payload, dict) and "collector" in payload else repr(found)
            raise ValueError(f"expected format {POLICY_FORMAT!r} (or the older 'bfc-policy-v1'), found {what}")
        expected = {k: tuple(v.shape) for k, v in policy.spec.make_net().state_dict().items()}
        stored = {k: tuple(v.shape) for k, v in policy.state_dict.items()}
        if stored != expected:
            raise ValueError("its weights do not match its spec's network")
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path} is not a bfc policy file: {str(err).splitlines()[0]}") from None
    return policy


def load_policy(path) -> tuple[PolicySpec, GaussianActor]:
    """(spec, network in eval mode with the file's weights)."""
    policy = read_policy(path)
    return policy.spec, policy.net()


def _read_v1(payload: dict) -> PolicyFile:
    """bfc 0.1's format: the spec spread over `model` (network, action map), `observation` (kind,
    size, accelerations, integral) and `env` (control rate, airframe), the MLP stored as `mean.*`."""
    model, observation, env = payload["model"], payload["observation"], payload["env"]
    spec = PolicySpec(
        observation=str(observation.get("kind", "heading")),
        include_acceleration=bool(observation["include_acceleration"]),
        position_integral=bool(observation.get("position_integral", False)),
        action_map=str(model.get("action_map", "speed")),  # files from before the thrust map flew speed
        hidden=tuple(int(h) for h in model["actor_hidden"]),
        activation=str(model["activation"]),
        init_std=float(model["init_std"]),
        squash=bool(model.get("squash", False)),
        control_hz=float(env["control_hz"]),
        airframe=dict(env.get("airframe") or {}),
        observation_scales=LEGACY_OBSERVATION_SCALES,
    )
    if spec.observation_size != int(observation["size"]):
        raise ValueError(f"its observation size {observation['size']} does not match its settings")
    state = {("mlp." + k[len("mean.") :] if k.startswith("mean.") else k): v for k, v in payload["state_dict"].items()}
    return PolicyFile(spec, state, dict(payload.get("info", {})))
