"""Fitting a model to proposals: every frame (:mod:`.frames`; the one driver that runs stage
schedules for many frames in :mod:`.driver`, scoring in :mod:`.evaluator`, random streams in
:mod:`.streams`), a model's geometry
(:mod:`.calibrate`), a depth frame end to end (:mod:`.estimator`) and a sequence
(:mod:`.tracking`); fits read back and their joint angles out (:mod:`.angles`). One
frame's problem is :mod:`hybridfit.problem`."""
