"""Evaluation on the paper's protocol: fixed starts, batched flights, the success rule."""

from bfc.evaluation.fly import CONTROLLERS, fly, run_flights, success, time_to_success
from bfc.evaluation.protocol import inside_box, protocol_starts, success_and_time

__all__ = [
    "CONTROLLERS",
    "fly",
    "inside_box",
    "protocol_starts",
    "run_flights",
    "success",
    "success_and_time",
    "time_to_success",
]
