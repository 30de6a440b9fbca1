"""The paper's car tasks as Gymnasium environments (registered as ``TLCarNav-v0`` by ``import tl_gym``).

Modules: `dynamics` (the pure batched `car_step` and the car's parameters),
`tasks` (Figure-1 layouts and the task formulas, `task_formula`), `car` (the single
env and `make_car_env`, the registered entry point), `vector` (`CarNavVectorEnv`,
all cars in one numpy call) and `rendering` (`draw_layout` for matplotlib Axes,
RGB frames, the pygame window). See ``docs/envs.md``.
"""
