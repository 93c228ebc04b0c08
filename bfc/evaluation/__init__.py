"""Evaluation on the paper's protocol: fixed starts, batched flights, one success rule (`judge`).

`CONTROLLERS` (the classical baselines by name) is imported on first use only, so that training,
which flies its evaluations through `run_flights`, never loads OSQP or SciPy.
"""

from bfc.evaluation.evaluator import ProtocolEvaluator
from bfc.evaluation.flights import run_flights
from bfc.evaluation.flying import fly
from bfc.evaluation.judge import Verdict, inside_box, judge, success, success_and_time, time_to_success
from bfc.evaluation.protocol import TEST_SEED, VALIDATION_SEED, protocol_starts

__all__ = [
    "CONTROLLERS",
    "TEST_SEED",
    "VALIDATION_SEED",
    "ProtocolEvaluator",
    "Verdict",
    "fly",
    "inside_box",
    "judge",
    "protocol_starts",
    "run_flights",
    "success",
    "success_and_time",
    "time_to_success",
]


def __getattr__(name):
    if name == "CONTROLLERS":
        from bfc.controllers import CONTROLLERS

        return CONTROLLERS
    raise AttributeError(f"module 'bfc.evaluation' has no attribute {name!r}")
