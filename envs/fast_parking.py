"""highway-env's parking-v0 with its goal observation read by numpy: the same values, several times faster.

parking-v0 builds its ``KinematicsGoal`` observation through a one-row pandas DataFrame, and reads
it four times a step (the observation, the reward, the termination and the info's ``is_success``):
profiled on this machine, that is about 80 % of a step. `NumpyParkingEnv` is parking-v0 with the
same observation read straight from the vehicle's ``to_dict()``; the values are equal to the last
bit (tests/test_suite_envs.py compares whole episodes). `TLParking-v0` runs on it. It also has
`compute_terminated`, for hindsight relabelling, and one config key of its own, ``terminate_on_success``
(default True, parking-v0's rule): False lets the episode go on after the car reaches the slot, so that
only a crash (or the time limit) ends it.

This module imports highway-env: import it only after checking that the extra is installed.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np
from highway_env.envs.common.observation import KinematicsGoalObservation
from highway_env.envs.parking_env import ParkingEnv


class NumpyKinematicsGoalObservation(KinematicsGoalObservation):
    """`KinematicsGoalObservation` without pandas: ``observation``, ``achieved_goal``, ``desired_goal``."""

    def observe(self) -> dict[str, np.ndarray]:
        """The observer's features and its goal's, divided by the scales, as highway-env computes them."""
        vehicle = self.observer_vehicle
        if not vehicle:
            return super().observe()
        state = self._features(vehicle.to_dict())
        goal = self._features(vehicle.goal.to_dict())
        return OrderedDict(
            [
                ("observation", state / self.scales),
                ("achieved_goal", state / self.scales),
                ("desired_goal", goal / self.scales),
            ]
        )

    def _features(self, values: dict[str, Any]) -> np.ndarray:
        return np.array([values[name] for name in self.features], dtype=np.float64)


class NumpyParkingEnv(ParkingEnv):
    """parking-v0 whose ``KinematicsGoal`` observations (its own and the reward's) skip pandas.

    With ``config["terminate_on_success"] = False`` the episode does not end at the slot.
    """

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        """parking-v0's config, plus ``terminate_on_success`` (True: end the episode at the slot, as parking-v0)."""
        config = super().default_config()
        config["terminate_on_success"] = True
        return config

    def _is_terminated(self) -> bool:
        """parking-v0's rule (crashed or parked), or only crashed when ``terminate_on_success`` is False."""
        if self.config["terminate_on_success"]:
            return super()._is_terminated()
        return any(vehicle.crashed for vehicle in self.controlled_vehicles)

    def define_spaces(self) -> None:
        """highway-env's spaces, then the numpy reader in place of each ``KinematicsGoalObservation``."""
        super().define_spaces()
        if type(self.observation_type) is KinematicsGoalObservation:
            self.observation_type = NumpyKinematicsGoalObservation(self, **self.config["observation"])
        self.observation_type_parking = NumpyKinematicsGoalObservation(self, **self.PARKING_OBS["observation"])

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: dict[str, Any]) -> bool:
        """Whether this env ends an episode at this goal pair: crashed (``info["crashed"]``) or parked there.

        Gymnasium-Robotics' ``GoalEnv`` method, which parking-v0 lacks: hindsight relabelling
        (`tl_gym.relabel`) ends a relabelled episode where ``_is_terminated`` would have. Parked
        counts only with ``terminate_on_success``.
        """
        if info.get("crashed", False):
            return True
        return bool(self.config["terminate_on_success"] and self._is_success(achieved_goal, desired_goal))
