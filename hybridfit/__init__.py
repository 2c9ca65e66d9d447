"""hybridfit: 3D hand pose from joint proposals by fitting an anatomically valid hand model.

The method of Poier et al., "Hybrid One-Shot 3D Hand Pose Estimation by Exploiting
Uncertainties", BMVC 2015, as a framework of pluggable hand models, objectives and
optimisers (entry-point groups ``hybridfit.models``, ``hybridfit.objectives``,
``hybridfit.optimizers``). Optimisers minimise; lengths are millimetres, angles radians.
"""

from .errors import HybridfitError
from .fitting.estimator import HybridEstimator
from .fitting.frames import FitResult, fit
from .fitting.refine import fit_and_refine
from .model.base import HandModel, Stage
from .objective import Objective
from .optimizer import OptimizeResult, Optimizer, Task
from .plugin import Plugin, Settings
from .problem import Problem
from .registry import available, create
from .synthetic.stress import stress_proposals
from .synthetic.proposals import synthetic_proposals

__version__ = "0.3.0"

__all__ = [
    "FitResult", "HandModel", "HybridEstimator", "HybridfitError", "Objective", "OptimizeResult", "Optimizer",
    "Plugin", "Problem", "Settings", "Stage", "Task", "available", "create", "fit", "fit_and_refine", "stress_proposals",
    "synthetic_proposals",
    "__version__",
]
