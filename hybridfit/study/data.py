"""A study's data as cached shared steps: generated data, the forest, proposals per (k, |P~|),
the model calibration, and the proposal baselines (Oracle, top-1) computed from proposals.

Every step is cached (``Cache``) by a hash of what determines it: the synthetic data by its
generator config, the forest by its training data and config, the proposals by the forest,
the test data, k and |P~|. Files named in a study are hashed by content.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import HybridfitError
from ..io import frame_slice, load_npz
from ..metrics import joint_errors, oracle
from .cache import Cache, code_versions
from .spec import (DatasetData, ProposalsData, SyntheticDepthData, SyntheticProposalsData, SyntheticStressData,
                   TrialSettings)

#: the arrays a trial needs: proposals (F, J, k, 3), confidences (F, J, k), joint_names (J,),
#: ground_truth (F, J, 3) mm, empty (F,) frames without proposals
ProposalSet = dict[str, np.ndarray]


def _skeleton_file(data) -> bool:
    """Whether the data names its skeleton by a user's skeleton file."""
    from ..datasets.skeletons import is_skeleton_file

    return isinstance(getattr(data, "dataset", None), str) and is_skeleton_file(data.dataset)


def file_hash(path: Path) -> str:
    """sha256 of a file, or of every file in a folder (names and contents: the depth images
    too; a FIFO or device in it is not a file and is left out). A cache entry is named by its
    key, which already hashes what made it. A path that is neither a regular file nor a folder
    (a FIFO or a device, read forever) is a one-line HybridfitError."""
    path = Path(path)
    if path.exists() and not path.is_dir() and not path.is_file():
        raise HybridfitError(f"{path}: not a regular file (a FIFO, device or socket, which would be read forever); "
                             "give a file or a folder")
    if (path.parent / f"{path.name.split('.')[0]}.payload.json").is_file():
        return f"cache:{path.name}"
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(str(f.relative_to(path) if path.is_dir() else "").encode() + b"\0")
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:20]


class StudyData:
    """The data of a study: ``key`` (its identity) and ``proposals(k, proposal_set)``."""

    def __init__(self, data, cache: Cache, jobs: int = 1, log: Callable[[str], None] = print, progress: bool = False):
        self.data, self.cache, self.jobs, self.log, self.progress = data, cache, jobs, log, progress
        self._sets: dict[tuple[int, int], ProposalSet] = {}
        self._calibrated: dict[str, dict[str, Any]] = {}  # by model
        self._depth: dict[str, Any] | None = None
        self.key = self._key()

    # ------------------------------------------------------------------ identity

    def _key(self) -> str:
        d = self.data
        payload = d.model_dump(mode="json")
        for name in ("test", "train", "forest_file", "file", "ground_truth"):
            value = getattr(d, name, None)
            if isinstance(value, Path):
                payload[name] = file_hash(value)
            elif isinstance(value, list):
                payload[name] = [file_hash(v) for v in value]
        if _skeleton_file(d):
            payload["dataset"] = file_hash(Path(d.dataset))  # a user's skeleton: its content, not its path
        payload["code"] = code_versions()  # results of other code are never reused
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:20]

    def uses_proposal_set(self) -> bool:
        """Whether |P~| changes the proposals (forest data only)."""
        return isinstance(self.data, (SyntheticDepthData, DatasetData))

    # ------------------------------------------------------------------ proposals

    def proposals(self, k: int, proposal_set: int, skeleton: str | None = None) -> ProposalSet:
        """The proposal set for (k, |P~|) (and the skeleton of stress data), from the cache or
        computed once."""
        ck = (k, proposal_set if self.uses_proposal_set() else 0, skeleton)
        if ck not in self._sets:
            d = self.data
            if isinstance(d, SyntheticStressData):
                self._sets[ck] = _top_k(self._stress(skeleton or "icvl")[0], k)
            elif isinstance(d, SyntheticProposalsData):
                self._sets[ck] = _top_k(self._synthetic(), k)
            elif isinstance(d, ProposalsData):
                self._sets[ck] = _top_k(self._file_proposals(), k)
            else:
                self._sets[ck] = self._forest_proposals(k, proposal_set)
        return self._sets[ck]

    def _synthetic(self) -> ProposalSet:
        from ..synthetic.proposals import synthetic_proposals

        d = self.data
        cfg = d.model_dump(exclude={"kind"})

        def make(tmp: Path) -> None:
            self.log(f"generating {d.frames} synthetic proposal frames")
            out = synthetic_proposals(cfg.pop("frames"), **cfg)
            np.savez(tmp, **{k: out[k] for k in ("proposals", "confidences", "joint_names", "ground_truth")})

        _, path = self.cache.get("synthetic-proposals", d.model_dump(mode="json"), make, ".npz")
        z = load_npz(path)
        z["empty"] = np.zeros(len(z["proposals"]), bool)
        return z

    def _stress(self, skeleton: str) -> tuple[ProposalSet, np.ndarray]:
        """(the fitted frames, the calibration frames' ground truth (C, Q, 3) mm) of the
        skeleton's stress sequence (cached)."""
        from ..synthetic.stress import stress_proposals

        d = self.data
        C = d.calibrate.frames if d.calibrate is not None else 0
        payload = {**d.model_dump(mode="json"), "skeleton": skeleton}

        def make(tmp: Path) -> None:
            self.log(f"generating {C + d.frames} stress frames, skeleton {skeleton}")
            z = stress_proposals(C + d.frames, dataset=skeleton, k=d.k, seed=d.seed, **d.stress.model_dump())
            np.savez(tmp, **{k: z[k] for k in ("proposals", "confidences", "joint_names", "ground_truth")})

        z = load_npz(self.cache.get("synthetic-stress", payload, make, ".npz")[1])
        fitted = {k: (v if k == "joint_names" else v[C:]) for k, v in z.items()}
        fitted["empty"] = np.zeros(d.frames, bool)
        return fitted, z["ground_truth"][:C]

    def _stress_calibration(self, skeleton: str, model: str) -> dict[str, Any]:
        """The model calibrated on the skeleton's calibration frames (cached per model)."""
        from ..fitting.calibrate import calibrate
        from ..datasets.skeletons import dataset_model_config

        d = self.data
        fitted, truth = self._stress(skeleton)
        payload = {**d.model_dump(mode="json"), "skeleton": skeleton, "model": model,
                   "method": "prior-regularised, held out 20%"}

        def make(tmp: Path) -> None:
            self.log(f"calibrating {model} on {len(truth)} stress frames, skeleton {skeleton}")
            c = d.calibrate
            r = calibrate(truth, [str(n) for n in fitted["joint_names"]], model=model,
                          model_config=dataset_model_config(model, {}, skeleton),
                          rounds=c.rounds, budget=c.budget, seed=c.seed, jobs=self.jobs)
            tmp.write_text(json.dumps({"settings": r.settings, "error_after_mm": r.error_after,
                                       "error_heldout_mm": r.error_heldout}, indent=1))

        saved = json.loads(self.cache.get("stress-calibration", payload, make, ".json")[1].read_text())
        self.log(f"calibration ({model}, {skeleton}): fit error {saved['error_after_mm']:.2f} mm in-sample, "
                 f"{saved['error_heldout_mm']:.2f} mm held out")
        return saved["settings"]

    def _file_proposals(self) -> ProposalSet:
        from ..datasets.results import read_proposals
        from ..datasets.results import read_xyz  # a binary file is named, not decoded
        from ..datasets.skeletons import skeleton
        from ..io import load_proposals

        d = self.data
        files = d.file if isinstance(d.file, list) else [d.file]
        if len(files) == 1 and files[0].suffix == ".npz":
            z = load_proposals(files[0])
            props, conf = z["proposals"], z["confidences"]
            names = z.get("joint_names")
            truth = z.get("ground_truth")
        else:
            z = read_proposals(files, d.dataset)  # from-results' confidences, camera coordinates
            props, conf, names, truth = z["proposals"], z["confidences"], z["joint_names"], None
        if names is None:
            if d.dataset is None:
                raise HybridfitError(f"{files[0]}: no joint_names; set data.dataset to name its skeleton")
            names = np.asarray(skeleton(d.dataset).model_names)
        if d.ground_truth is not None:
            truth = read_xyz(d.ground_truth, d.dataset)
        if truth is None:
            raise HybridfitError(f"{files[0]}: no ground_truth in the file; set data.ground_truth")
        if truth.shape != props.shape[:2] + (3,):
            raise HybridfitError(f"data.ground_truth: shape {truth.shape} does not match the proposals' "
                                 f"{props.shape[:2] + (3,)}")
        sel = frame_slice(d.frames, len(props), "data.frames")
        order = np.argsort(-conf, axis=-1, kind="stable")  # most confident first
        props = np.take_along_axis(props, order[..., None], axis=2)
        conf = np.take_along_axis(conf, order, axis=2)
        return {"proposals": props[sel], "confidences": conf[sel], "joint_names": np.asarray(names),
                "ground_truth": np.asarray(truth, float)[sel], "empty": np.zeros(len(props[sel]), bool)}

    def _datasets(self) -> tuple[Path, Path | None]:
        """(test folder, training folder or None), generated for synthetic depth data."""
        from ..synthetic.sets import make_test, make_train

        d = self.data
        if isinstance(d, DatasetData):
            return d.test, d.train
        frames = self._train_subset()
        payload = d.train.model_dump(mode="json")
        if frames is not None:  # only the frames the forest trains on are rendered
            payload = {**payload, "subset": d.train_subset, "subset_seed": d.forest.seed}
        _, train = self.cache.get("train-data", payload, lambda tmp: (
            self.log(f"rendering {'the training grid' if frames is None else f'{len(frames)} frames of the training grid'}"),
            make_train(tmp, d.train, frames=frames, progress=self.progress)))
        _, test = self.cache.get("test-data", d.test.model_dump(mode="json"), lambda tmp: (
            self.log("rendering the test sequence"), make_test(tmp, d.test, progress=self.progress)))
        return test, train

    def _train_subset(self) -> np.ndarray | None:
        """The grid frames the forest trains on (sorted), None for all."""
        from ..synthetic.poses import grid_poses, grid_subset

        d = self.data
        if not isinstance(d, SyntheticDepthData):
            return None
        return grid_subset(len(grid_poses(d.train)), d.train_subset, d.forest.seed)

    def forest_path(self) -> Path:
        """The trained forest (cached by its training data and config)."""
        from ..datasets import open_dataset
        from ..forest import train_forest_dataset

        d = self.data
        if isinstance(d, DatasetData) and d.forest_file is not None:
            return d.forest_file
        _, train = self._datasets()
        payload = {"train": file_hash(train), "forest": d.forest.model_dump(mode="json"), "subset": d.train_subset}

        def make(tmp: Path) -> None:
            ds = open_dataset(train)  # a synthetic folder or a real dataset's
            idx = None
            if isinstance(d, DatasetData) and d.train_subset is not None and d.train_subset < len(ds):
                rng = np.random.default_rng(d.forest.seed)
                idx = np.sort(rng.choice(len(ds), d.train_subset, replace=False))
            self.log(f"training the forest on {len(ds) if idx is None else len(idx)} frames "
                     f"({d.forest.n_trees} trees, depth {d.forest.max_depth})")
            train_forest_dataset(ds, d.forest, idx, jobs=self.jobs, progress=self.progress).save(tmp)

        return self.cache.get("forest", payload, make, ".npz")[1]

    def _forest_proposals(self, k: int, proposal_set: int) -> ProposalSet:
        from ..datasets import open_dataset
        from ..fitting.estimator import HybridEstimator

        d = self.data
        forest = self.forest_path()
        test, _ = self._datasets()
        frames = getattr(d, "frames", None)
        payload = {"forest": file_hash(forest), "test": file_hash(test), "k": k, "proposal_set": proposal_set,
                   "stride": d.stride, "bandwidth_mm": d.bandwidth_mm, "frames": frames}

        def make(tmp: Path) -> None:
            ds = open_dataset(test)
            idx = np.arange(len(ds) if frames is None else min(frames, len(ds)))
            self.log(f"proposals for {len(idx)} test frames, k = {k}, |P~| = {proposal_set}")
            est = HybridEstimator(forest, k=k, proposal_set=proposal_set, stride=d.stride, bandwidth_mm=d.bandwidth_mm)
            p = est.propose_dataset(ds, idx, progress=self.progress)
            np.savez(tmp, proposals=p.proposals, confidences=p.confidences, empty=p.empty,
                  joint_names=np.asarray(p.joint_names), ground_truth=np.asarray(ds.joints_xyz, float)[idx])

        return load_npz(self.cache.get("proposals", payload, make, ".npz")[1])

    # ------------------------------------------------------------------ depth

    def depth_frames(self) -> dict[str, Any]:
        """The test frames' depth as ``observations`` (a list of ``Observation``, None for a
        frame without hand pixels) and ground-truth model ``params`` (F, P), P = 0 when the
        data has none; the same frames as the proposals. Forest data only."""
        if self._depth is None:
            from ..datasets.folder import load_dataset
            from ..objective import dataset_observations

            if not self.uses_proposal_set():
                raise HybridfitError(f"data kind {self.data.kind!r} has no depth images; objectives that compare "
                                     f"with the depth need synthetic-depth or dataset data")
            test, _ = self._datasets()
            ds = load_dataset(test)
            frames = getattr(self.data, "frames", None)
            idx = np.arange(len(ds) if frames is None else min(frames, len(ds)))
            self.log(f"reading the depth of {len(idx)} test frames")
            self._depth = {"observations": dataset_observations(ds, idx, str(test)),
                           "params": np.asarray(ds.params, float)[idx]}
        return self._depth

    # ------------------------------------------------------------------ model

    def model_config(self, settings: TrialSettings) -> dict[str, Any]:
        """The model config a trial runs with: the dataset's derived points and the trial's
        model calibrated on the data's calibration frames (if asked), under the trial's own
        model_config."""
        from ..datasets.skeletons import dataset_model_config

        cfg = dict(settings.model_settings)
        d = self.data
        if isinstance(d, SyntheticStressData):
            skeleton = settings.skeleton or "icvl"
            if d.calibrate is not None:
                cfg = {**self._stress_calibration(skeleton, settings.model), **cfg}
            return dataset_model_config(settings.model, cfg, skeleton)
        if isinstance(d, DatasetData):  # a real dataset's folder: its skeleton's derived points
            from ..datasets import detect

            kind = detect(d.test)
            return cfg if kind == "synthetic" else dataset_model_config(settings.model, cfg, kind)
        if not isinstance(d, ProposalsData) or d.dataset is None:
            return cfg
        if d.calibrate is not None:
            cfg = {**self.calibration(settings.model), **cfg}
        return dataset_model_config(settings.model, cfg, d.dataset)

    def calibration(self, model: str) -> dict[str, Any]:
        """The model's settings calibrated on the ground truth's frames (cached per model)."""
        if model not in self._calibrated:
            from ..fitting.calibrate import calibrate
            from ..datasets.results import read_xyz
            from ..datasets.skeletons import dataset_model_config, skeleton

            d, c = self.data, self.data.calibrate
            dataset = file_hash(Path(d.dataset)) if _skeleton_file(d) else d.dataset
            payload = {"ground_truth": file_hash(d.ground_truth), "dataset": dataset, **c.model_dump(mode="json"),
                       "model": model,
                       "method": "prior-regularised, held out 20%"}  # calibrations made by the earlier code differ

            def make(tmp: Path) -> None:
                sk = skeleton(d.dataset)
                truth = read_xyz(d.ground_truth, d.dataset)
                truth = truth[frame_slice(c.frames, len(truth), "data.calibrate.frames")]
                self.log(f"calibrating {model} on {len(truth)} frames of {d.ground_truth.name}")
                r = calibrate(truth, sk.model_names, model=model, model_config=dataset_model_config(model, {}, d.dataset),
                              mirror={"auto": None, "right": False, "left": True}[c.hand], rounds=c.rounds,
                              budget=c.budget, seed=c.seed, jobs=self.jobs)
                tmp.write_text(json.dumps({"settings": r.settings, "error_before_mm": r.error_before,
                                           "error_after_mm": r.error_after, "error_heldout_mm": r.error_heldout,
                                           "heldout_frames": len(r.heldout_frames)}, indent=1))

            _, path = self.cache.get("calibration", payload, make, ".json")
            saved = json.loads(path.read_text())
            self.log(f"calibration ({model}): fit error {saved['error_after_mm']:.2f} mm in-sample, "
                     f"{saved['error_heldout_mm']:.2f} mm on {saved['heldout_frames']} held-out frames")
            self._calibrated[model] = saved["settings"]
        return self._calibrated[model]


def _top_k(z: ProposalSet, k: int) -> ProposalSet:
    K = z["proposals"].shape[2]
    if k > K:
        raise HybridfitError(f"k = {k} but the data has only {K} proposals per joint")
    return {**z, "proposals": np.ascontiguousarray(z["proposals"][:, :, :k]),
            "confidences": np.ascontiguousarray(z["confidences"][:, :, :k])}


def baseline_errors(z: ProposalSet, method: str) -> np.ndarray:
    """(F, J) errors of a baseline taken from the proposals directly: ``oracle`` (the
    proposal closest to the truth) or ``top1`` (the most confident one: plain regression)."""
    truth = z["ground_truth"]
    if method == "top1":
        e = joint_errors(z["proposals"][:, :, 0], truth)
    else:
        e = joint_errors(oracle(z["proposals"], truth), truth)
    e[z["empty"]] = np.nan
    return e
