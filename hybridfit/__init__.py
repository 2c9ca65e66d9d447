"""hybridfit: 3D hand pose from joint proposals by fitting an anatomically valid hand model.

The method of Poier et al., "Hybrid One-Shot 3D Hand Pose Estimation by Exploiting
Uncertainties", BMVC 2015, as a framework of pluggable hand models, objectives and
optimisers (entry-point groups ``hybridfit.models``, ``hybridfit.objectives``,
``hybridfit.optimizers``). Optimisers minimise; lengths are millimetres, angles radians.
"""

import importlib
from typing import TYPE_CHECKING

from . import _environment

_environment.prepare()  # before numba is imported: NUMBA_NUM_THREADS, a cache folder that works

if TYPE_CHECKING:  # the same names for type checkers and the API docs (never imported at run time)
    from .errors import HybridfitError
    from .fitting.estimator import HybridEstimator
    from .fitting.frames import FitResult, fit
    from .model.base import HandModel, Stage
    from .objective import Objective
    from .optimizer import Optimizer
    from .task import OptimizeResult, Task
    from .plugin import Plugin, Settings
    from .problem import Problem
    from .registry import available, create
    from .synthetic.proposals import synthetic_proposals
    from .synthetic.stress import stress_proposals

#: public names -> the module that defines them, imported on first use (PEP 562), so that
#: ``import hybridfit`` (and the command line's start-up) stays light and a Ctrl-C during
#: start-up reaches the command line's handler
_LAZY = {
    "HybridfitError": "errors", "HybridEstimator": "fitting.estimator", "FitResult": "fitting.frames",
    "fit": "fitting.frames", "HandModel": "model.base", "Stage": "model.base", "Objective": "objective",
    "OptimizeResult": "task", "Optimizer": "optimizer", "Task": "task", "Plugin": "plugin",
    "Settings": "plugin", "Problem": "problem", "available": "registry", "create": "registry",
    "stress_proposals": "synthetic.stress", "synthetic_proposals": "synthetic.proposals",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    else:  # a submodule (hybridfit.io, hybridfit.metrics, ...)
        try:
            value = importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as err:
            if err.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__version__ = "0.15.0"

__all__ = [
    "FitResult", "HandModel", "HybridEstimator", "HybridfitError", "Objective", "OptimizeResult", "Optimizer",
    "Plugin", "Problem", "Settings", "Stage", "Task", "available", "create", "fit", "stress_proposals",
    "synthetic_proposals",
    "__version__",
]
