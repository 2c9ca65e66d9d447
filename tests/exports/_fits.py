"""Fits files as ``hybridfit fit --out`` writes them, naming their model (``model``,
``model_settings``), made here with ``hybridfit.fit`` on synthetic proposals (small budget)."""

from __future__ import annotations

import json

import numpy as np

import hybridfit

#: (label, model, settings) of the fits the export tests cover: both hands of hand26, and hand27
MODELS = [("hand26", "hand26", {}), ("hand26-left", "hand26", {"mirror": True}), ("hand27", "hand27", {})]


def make_fits(path, model="hand26", settings=None, frames=4, failed=(), seed=1, named=True):
    """Write a fits file of ``frames`` fitted synthetic frames, the rows ``failed`` marked as
    failed fits (NaN, as ``fit`` writes them); named=False: without the model keys (an older
    hybridfit's file). Returns the arrays written."""
    settings = dict(settings or {})
    data = hybridfit.synthetic_proposals(frames, seed=seed, model=model, model_config=settings)
    result = hybridfit.fit(data["proposals"], data["confidences"], model=model, model_config=settings,
                           optimizer="pso", budget=200, seed=seed)
    arrays = result.to_npz()
    for f in failed:
        arrays["failed"][f] = True
        for key in ("params", "joints", "model_joints"):
            arrays[key][f] = np.nan
    arrays.pop("model", None), arrays.pop("model_settings", None)  # made here, whatever `fit` writes
    if named:
        plugin = hybridfit.create("model", model, settings)
        arrays["model"] = np.asarray(model)
        arrays["model_settings"] = np.asarray(json.dumps(plugin.get_params()))
    np.savez(path, **arrays)
    return arrays
