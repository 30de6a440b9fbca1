"""tl_gym: temporal-logic rewards and policy search for Gymnasium.

The engine (`parse`, `Formula`) turns TLTL formulas and trajectories into exact
and smoothed robustness; `TLTLRewardWrapper` pays it as reward on any Gymnasium
env; `import tl_gym` registers the paper's car task and the TL task suite (their code is in
`tl_gym.envs`), and `tl_gym.agents` holds TLPS, REPS and stable-baselines3 adapters.
"""

from importlib.metadata import PackageNotFoundError, version

from gymnasium.envs.registration import register, registry

from tl_gym import logic
from tl_gym.errors import EpisodeError, SpecError, TLGymError, TraceError, UnknownSignalError
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.parser import parse
from tl_gym.wrapper import TLTLRewardWrapper

try:
    __version__ = version("tl_gym")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0"

# The car env, registered with string entry points so that `import tl_gym` stays cheap.
if "TLCarNav-v0" not in registry:
    register(
        id="TLCarNav-v0",
        entry_point="tl_gym.envs.car:make_car_env",
        vector_entry_point="tl_gym.envs.vector:CarNavVectorEnv",
    )
# The TL task suite on third-party envs (tl_gym.envs.suite, docs/tasks.md); TLParking-v0 needs highway-env.
for _id, _entry in (
    ("TLPendulum-v0", "make_pendulum"), ("TLMountainCar-v0", "make_mountain_car"), ("TLParking-v0", "make_parking"),
):
    if _id not in registry:
        register(id=_id, entry_point=f"tl_gym.envs.suite:{_entry}")
del _id, _entry

__all__ = [
    "EpisodeError", "Formula", "SpecError", "TLGymError", "TLTLRewardWrapper", "TraceError", "UnknownSignalError",
    "logic", "parse",
    "__version__",
]
