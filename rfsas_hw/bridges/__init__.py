"""Simulator bridges: RF-SAS inside the simulators people already run.

- :mod:`rfsas_hw.bridges.coords`: every simulator's coordinates to and from
  the rfsas frame.
- :mod:`rfsas_hw.bridges.config`: the typed YAML configuration of a bridge
  (units, buildings, devices per entity kind, penetration, backend profile).
- :mod:`rfsas_hw.bridges.bridge`: :class:`~rfsas_hw.bridges.bridge.Bridge`,
  the one class an adapter calls each step.
- :mod:`rfsas_hw.bridges.sumo`: the SUMO adapter (libsumo or TraCI).
- :mod:`rfsas_hw.bridges.adapter`: what a Gymnasium driving env's adapter offers
  :class:`rfsas_hw.envs.rfsas_wrapper.RfsasWrapper`;
  :mod:`rfsas_hw.bridges.crossing` plans people crossing from behind a building.
- :mod:`rfsas_hw.bridges.highway`, :mod:`rfsas_hw.bridges.metadrive`: the
  highway-env and MetaDrive adapters; :mod:`rfsas_hw.bridges.carla`: a
  client-side RF-SAS sensor for a ``carla.World``.

Nothing here is imported eagerly: importing the package costs nothing.
"""
