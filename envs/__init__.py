"""The paper's car tasks and the TL task suite as Gymnasium environments (registered by ``import tl_gym``).

The car (``TLCarNav-v0``): `dynamics` (the pure batched `car_step` and the car's parameters),
`car_model` (the dynamics with Jacobians, for model-based agents), `tasks` (Figure-1 layouts
and the task formulas, `task_formula`), `car` (the single env and `make_car_env`, the registered
entry point), `vector` (`CarNavVectorEnv`, all cars in one numpy call) and `rendering`
(`draw_layout` for matplotlib Axes, RGB frames, the pygame window); see ``docs/envs.md``. The
suite (``TLPendulum-v0``, ``TLMountainCar-v0``, ``TLParking-v0``): `suite`, and `fast_parking`
(parking-v0 without pandas); see ``docs/tasks.md``.
"""
