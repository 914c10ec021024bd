"""The multi-cycle loop (paper Algorithm 1): configuration, belief, deployment and the run.

Submodules are imported on first use, so ``from rapidds.loop import RunConfig`` stays cheap
(the run itself needs torch).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rapidds.lazy import submodule_attributes

if TYPE_CHECKING:
    from rapidds.loop.config import ADAPT_LEVELS, RunConfig
    from rapidds.loop.context import RunContext
    from rapidds.loop.cycle import Cycle
    from rapidds.loop.deploy import Deployment, deploy
    from rapidds.loop.model import HumanModel, prior_model
    from rapidds.loop.observation import Observation, Source
    from rapidds.loop.run import AdaptiveRun, CyclePlan, CycleResult, LiveTeammate, load_policy

_WHERE = {
    "ADAPT_LEVELS": "config", "RunConfig": "config",
    "Deployment": "deploy", "deploy": "deploy",
    "HumanModel": "model", "prior_model": "model",
    "AdaptiveRun": "run", "CyclePlan": "run", "CycleResult": "run", "load_policy": "run",
    "LiveTeammate": "run", "Cycle": "cycle", "RunContext": "context",
    "Observation": "observation", "Source": "observation",
}
__all__ = [
    "ADAPT_LEVELS", "AdaptiveRun", "Cycle", "CyclePlan", "CycleResult", "Deployment",
    "HumanModel", "LiveTeammate", "Observation", "RunConfig", "RunContext", "Source", "deploy",
    "load_policy", "prior_model",
]


__getattr__ = submodule_attributes(__name__, _WHERE)
