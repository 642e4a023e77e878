"""drake_att: spacecraft attitude determination on Drake.

Layers (dependency direction top to bottom):

* ``drake_att.rotations``, ``drake_att.noise``, ``drake_att.orbit`` - math, no Drake.
* ``drake_att.filters`` - estimator cores in plain numpy, no Drake.
* ``drake_att.systems`` - thin Drake ``LeafSystem`` wrappers (plant, sensors, estimators).
* ``drake_att.scenarios`` - typed YAML configs and the diagram builder.
* ``drake_att.analysis`` - simulation, metrics, Monte Carlo, plots, CLI.
"""

__version__ = "0.1.0"
