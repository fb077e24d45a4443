"""The digital twin: scenarios, the RF world, captures, scan plans and the braking case.

Everything here feeds the real pipeline (captures, board streams, the
``virtual:`` source); nothing bypasses DF, hashing, the link or the backend.
"""

ENV_ID = "rfsas/Intersection-v0"
"""Gymnasium id of :class:`rfsas_hw.sim.env.IntersectionEnv`."""


def _register_envs() -> None:
    try:
        from gymnasium.envs.registration import register, registry
    except ImportError:  # without the `sim` extra there is nothing to register
        return
    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="rfsas_hw.sim.env:IntersectionEnv")


_register_envs()
