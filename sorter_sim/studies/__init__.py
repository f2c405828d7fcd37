"""
Studies built on the model core: the seed's figures, design sweeps, two-stage sorting.

Everything here calls the same core and scene code the nodes run
(``sorter_sim.model.core.simulate``, ``sorter_sim.runtime.scene``); nothing here imports ROS.

- ``paper``: ``sorter paper FIG``, the seed's numerical experiments (sections 3, 5, 6),
  each as a function that computes its data, writes CSV + PNG and returns a
  ``FigureResult`` with the headline figures.
- ``sweep``: ``sorter sweep SPEC.yaml``, grid or random design studies over any scene
  keys, resumable, on local cores or a Dask cluster.
- ``two_stage``: the seed's conclusion, a preliminary disk field in series with the
  final one, and how much it shortens the final field.
"""
