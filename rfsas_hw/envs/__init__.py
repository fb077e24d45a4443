"""Gymnasium environments over the twin and the backend: ``rfsas/Intersection-v0`` and RL runs.

Importing this package registers the environment id with Gymnasium (when the
``sim`` extra is installed).
"""

ENV_ID = "rfsas/Intersection-v0"
"""Gymnasium id of :class:`rfsas_hw.envs.env.IntersectionEnv`."""


def _register_envs() -> None:
    try:
        from gymnasium.envs.registration import register, registry
    except ImportError:  # without the `sim` extra there is nothing to register
        return
    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="rfsas_hw.envs.env:IntersectionEnv")


_register_envs()
