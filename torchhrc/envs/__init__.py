"""gymnasium environments of torchhrc models and tasks (the ``gym`` extra).

``pip install torchhrc[gym]``. Importing this package imports gymnasium and registers:

* ``torchhrc/PlaceAndDrill-v0``: :class:`~torchhrc.tasks.place_and_drill.env.PlaceAndDrillEnv`
  (options ``epsilon``, ``noise``, ``horizon``, ``type_probabilities``);
* ``torchhrc/HandFinishing-v0``: :class:`~torchhrc.tasks.hand_finishing.env.HandFinishingEnv`
  (options ``noise``, ``epsilon``, ``horizon``, ``task``, ``type_probabilities``);
* ``torchhrc/POMDP-v0`` and ``torchhrc/MOMDP-v0``: :class:`~torchhrc.envs.pomdp_env.POMDPEnv`
  and :class:`~torchhrc.envs.momdp_env.MOMDPEnv` of the ``model`` passed to ``make``.

``import torchhrc`` does not import gymnasium; ``gymnasium.make("torchhrc.envs:torchhrc/
PlaceAndDrill-v0")`` imports this package first (gymnasium's ``module:id`` form).

Example:
    >>> import gymnasium
    >>> import torchhrc.envs
    >>> env = gymnasium.make("torchhrc/PlaceAndDrill-v0", epsilon=0.2)
    >>> obs, info = env.reset(seed=0)
    >>> int(obs["x"]), env.unwrapped.human.epsilon
    (0, 0.2)
"""

from __future__ import annotations

try:
    import gymnasium
except ImportError as error:  # pragma: no cover - exercised only without the extra
    raise ImportError("torchhrc.envs needs gymnasium: pip install 'torchhrc[gym]'") from error

from torchhrc._deprecation import moved_attribute
from torchhrc.envs.agent import Agent, BeliefAgent, RandomAgent, rollout
from torchhrc.envs.momdp_env import MOMDPEnv
from torchhrc.envs.pomdp_env import POMDPEnv

__all__ = [
    "ENV_IDS",
    "Agent",
    "BeliefAgent",
    "MOMDPEnv",
    "POMDPEnv",
    "RandomAgent",
    "rollout",
]

#: The environment ids this package registers with gymnasium.
ENV_IDS: tuple[str, ...] = (
    "torchhrc/PlaceAndDrill-v0",
    "torchhrc/HandFinishing-v0",
    "torchhrc/POMDP-v0",
    "torchhrc/MOMDP-v0",
)

_ENTRY_POINTS = {
    "torchhrc/PlaceAndDrill-v0": "torchhrc.tasks.place_and_drill.env:PlaceAndDrillEnv",
    "torchhrc/HandFinishing-v0": "torchhrc.tasks.hand_finishing.env:HandFinishingEnv",
    "torchhrc/POMDP-v0": "torchhrc.envs.pomdp_env:POMDPEnv",
    "torchhrc/MOMDP-v0": "torchhrc.envs.momdp_env:MOMDPEnv",
}

for _env_id, _entry_point in _ENTRY_POINTS.items():
    if _env_id not in gymnasium.registry:
        gymnasium.register(
            id=_env_id,
            entry_point=_entry_point,
            vector_entry_point=(
                "torchhrc.tasks.place_and_drill.vector_env:PlaceAndDrillVectorEnv"
                if _env_id == "torchhrc/PlaceAndDrill-v0"
                else None
            ),
            disable_env_checker=False,
        )

#: Names that moved to their task's folder (issue 32: the generic envs import no task), kept
#: here for one release as deprecated aliases: name -> the module that holds it now.
_MOVED_TO_TASKS = {
    "HandFinishingEnv": "torchhrc.tasks.hand_finishing.env",
    "quick_hand_finishing_task": "torchhrc.tasks.hand_finishing.env",
    "PlaceAndDrillEnv": "torchhrc.tasks.place_and_drill.env",
    "PlaceAndDrillHuman": "torchhrc.tasks.place_and_drill.env",
    "PlaceAndDrillVectorEnv": "torchhrc.tasks.place_and_drill.vector_env",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED_TO_TASKS)
