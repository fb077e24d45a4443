"""A district of roadside units, phones and cars: the model and its scoring.

Needs the ``city`` extra (``eclipse-sumo``, ``sumolib``, ``pyproj``).

Modules, each with one job:

- :mod:`~rfsas_hw.city.net`: find the district net (Berlin-Adlershof, shipped in
  the ``eclipse-sumo`` wheel) or read any net: ``district_net() -> Path``,
  ``read_net(path, origin=None) -> NetInfo`` (site origin, frame transform,
  bounds, junctions with their traffic-light programs, crossings, lanes), and
  the environment SUMO's binaries need (``sumo_env()``, ``sumo_binary()``,
  ``sumo_tool()``).
- :mod:`~rfsas_hw.city.demand`: ``generate(net, out_dir, cfg, seed) -> Demand``:
  vehicle, pedestrian and bicycle route files made by SUMO's ``randomTrips.py``
  and the per-VRU table (id, class, has_phone, device_model, reckless).
- :mod:`~rfsas_hw.city.placement`: ``place_units(info, cfg=None) -> list[UnitSite]``
  (id, x_m, y_m, boresight_deg, junction, tile) and
  ``buildings(info, units, polygons=None, opts=None) -> list[BuildingSpec]``.
- :mod:`~rfsas_hw.city.scoring`: ``CityScorer``, fed online each step
  (``step(t_s, vehicles, vrus)`` with :class:`~rfsas_hw.city.scoring.Actors`
  arrays), each fix (``fix(t_s, emitter_id, person, x_m, y_m, sigma_m)``) and each
  advisory that reached a vehicle (``advisory(t_s, vehicle_id, kind, latency_s)``;
  ``latency(latency_s)`` for one known only later); ``summary() -> CitySummary``
  (JSON-ready).
- :mod:`~rfsas_hw.city.citymap`: ``write_map(scorer, units, info, png, geojson)``.

Interface note between the model (this package's modules above) and the
runtime that drives SUMO, the broker and the backends: every position, heading
and geometry these modules take or return is in the rfsas frame of the net's
:class:`~rfsas_hw.city.net.NetInfo`: metres east/north of ``info.origin``.
SUMO positions convert with ``info.to_frame(x, y)`` (after moving a vehicle's
front-bumper position to its centre), SUMO angles with
``info.heading_to_frame(angle)``. Vehicle ids and person ids are SUMO's own.
"""
