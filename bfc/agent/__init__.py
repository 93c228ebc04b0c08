"""The policy contract, one owner: what a policy is (`PolicySpec`), its network (`GaussianActor`),
its file (`save_policy` / `load_policy`) and its exports (bfc.agent.onnx; bfc.agent.c_export, flown
through bfc.agent.c_controller).

Training builds the spec from its config (`PolicySpec.from_config`); a flight, an evaluation and
an export build everything from the spec in the file.
"""

from bfc.agent.actor import ACTIVATIONS, GaussianActor, SamplingActor, gaussian_net, make_critic, torchrl_actor
from bfc.agent.policy_file import POLICY_FORMAT, PolicyFile, atomic_save, load_policy, read_policy, save_policy
from bfc.agent.spec import PolicySpec

__all__ = [
    "ACTIVATIONS",
    "POLICY_FORMAT",
    "GaussianActor",
    "PolicyFile",
    "PolicySpec",
    "SamplingActor",
    "atomic_save",
    "gaussian_net",
    "load_policy",
    "make_critic",
    "read_policy",
    "save_policy",
    "torchrl_actor",
]
