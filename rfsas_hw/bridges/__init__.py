"""Simulator bridges: RF-SAS inside the simulators people already run.

- :mod:`rfsas_hw.bridges.coords`: every simulator's coordinates to and from
  the rfsas frame.
- :mod:`rfsas_hw.bridges.config`: the typed YAML configuration of a bridge
  (units, buildings, devices per entity kind, penetration, backend profile).
- :mod:`rfsas_hw.bridges.bridge`: :class:`~rfsas_hw.bridges.bridge.Bridge`,
  the one class an adapter calls each step.
- :mod:`rfsas_hw.bridges.sumo`: the SUMO adapter (libsumo or TraCI).

Nothing here is imported eagerly: importing the package costs nothing.
"""
