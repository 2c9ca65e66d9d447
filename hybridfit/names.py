"""The built-in plugins' names as types, so that an editor can list them.

``hybridfit.fit(model=..., objective=..., optimizer=...)`` (and ``track``,
``HybridEstimator``) take a plugin by its registered name, with ``*_config`` settings, or a
configured plugin. Plugins are found by entry point, so a third-party plugin's name is as
valid as a built-in's: each argument is typed ``ModelName | str | HandModel`` (and so on),
where the ``Literal`` lists hybridfit's own plugins for completion; ``hybridfit plugins``
lists every installed one. The lists are exactly the entry points hybridfit's distribution
declares (``tests/test_names.py`` checks).
"""

from __future__ import annotations

from typing import Literal

#: the built-in hand models (entry-point group ``hybridfit.models``)
ModelName = Literal["hand26", "hand27", "hand29"]
#: the built-in objectives (``hybridfit.objectives``)
ObjectiveName = Literal["clamped-then-soft-l1", "clamped-confidence", "gaussian-mixture", "least-squares",
                        "rendered-depth", "hybrid", "soft-l1"]
#: the built-in optimisers (``hybridfit.optimizers``)
OptimizerName = Literal["stepwise-pso", "pso", "stepwise", "cmaes", "nlopt", "casadi-ik", "pymoo", "levenberg-marquardt"]
