"""TorchRL's Collector, resumable (imported only when `collector.kind=torchrl` asks for it: TorchRL's
collectors package costs half a second of start-up)."""

from __future__ import annotations

from torchrl.collectors import Collector

from bfc.torchrl_compat import collector_carrier, load_collector_carrier


class ResumableCollector(Collector):
    """TorchRL's synchronous Collector whose `state_dict()` is a whole snapshot of collection.

    TorchRL's own state dict holds the transforms' state, the policy and the frame counter; a run
    that must resume bit-identically after a kill also needs the base env (physics, motors,
    generators: `BFCEnv.state_dict`) and the in-flight tensordict the next step starts from
    (current observations, episode sums and step counts; bfc.torchrl_compat).
    """

    def state_dict(self):
        sd = super().state_dict()
        sd["env_state_dict"] = self.env.state_dict()
        sd["carrier"] = collector_carrier(self).to_dict()
        return sd

    def load_state_dict(self, state_dict, **kwargs) -> None:
        super().load_state_dict(state_dict, **kwargs)
        load_collector_carrier(self, state_dict["carrier"])
