"""The Euro NCAP VRU test matrix in SUMO (see docs/ncap.md).

:mod:`~rfsas_hw.ncap.scenarios` plans the cells, :mod:`~rfsas_hw.ncap.world`
builds them in SUMO, :mod:`~rfsas_hw.ncap.runner` drives one run with a
controller (:mod:`~rfsas_hw.ncap.los_aeb`, RF-SAS through
:mod:`~rfsas_hw.ncap.rfsas`, both with :mod:`~rfsas_hw.ncap.cue`) and the
brake of :mod:`~rfsas_hw.ncap.brake`, :mod:`~rfsas_hw.ncap.sweep` runs many on
Dask, :mod:`~rfsas_hw.ncap.scoring` scores them like the protocol and
:mod:`~rfsas_hw.ncap.grid_plot` draws the grids.
"""
