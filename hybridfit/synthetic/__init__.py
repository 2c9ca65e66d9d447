"""Synthetic data: proposals drawn from the model (:mod:`.proposals`), stress data that
behaves like real annotations (:mod:`.stress`), and rendered depth data sets: poses
(:mod:`.poses`), sensor noise (:mod:`.noise`) and the sets written to disk (:mod:`.sets`)."""
