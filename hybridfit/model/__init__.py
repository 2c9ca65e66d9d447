"""The hand model: what a model declares (:mod:`.base`), a kinematic tree with its batched
forward kinematics (:mod:`.kinematics`, symbolic in :mod:`.casadi`), rotations
(:mod:`.rotations`), depth rendering of its surface (:mod:`.render`) and distances between that
surface and a depth frame, without rendering (:mod:`.surface`)."""

from .base import ANGLES, GLOBAL_POSE, ORIENTATION, POSITION, Geometry, HandModel, Stage

__all__ = ["ANGLES", "GLOBAL_POSE", "ORIENTATION", "POSITION", "Geometry", "HandModel", "Stage"]
