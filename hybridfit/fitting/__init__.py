"""Fitting a model to proposals: one frame's problem (:mod:`.problem`), every frame
(:mod:`.frames`, the compiled path in :mod:`.compiled`), a model's geometry
(:mod:`.calibrate`), a depth frame end to end (:mod:`.estimator`) and a sequence
(:mod:`.tracking`)."""
