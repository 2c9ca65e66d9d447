"""Random regression forest: joint proposals with confidences from one depth image.

Train with ``train_forest`` (arrays) or ``train_forest_dataset`` (a Dataset); a ``Forest``
gives ``propose(depths, intrinsics) -> Proposals`` (the (F, J, k, 3) / (F, J, k) input of
``hybridfit.fit``) and saves to / loads from one versioned .npz.
"""

from .config import ForestConfig
from .forest import FORMAT, VERSION, Forest, Proposals
from .meanshift import mean_shift
from .segment import dataset_masks, segment_hand
from .train import train_forest, train_forest_dataset

__all__ = ["FORMAT", "VERSION", "Forest", "ForestConfig", "Proposals", "dataset_masks", "mean_shift",
           "segment_hand", "train_forest", "train_forest_dataset"]
