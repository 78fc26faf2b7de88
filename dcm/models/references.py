"""Reference predictors every learned model is compared with, loadable wherever a checkpoint is.

* ``copy_demo`` (:class:`CopyDemo`): predicts ``F_obs := F_demo`` and ``x_obs := x_demo``. Its force and path
  RMSE are the floor a contact model must beat; its predicted path error is 0, so its L_task is the force
  term alone: 0 for every schedule, so it cannot rank schedules (the tuner refuses it).
* ``stiffness_ridge`` (:class:`StiffnessRegression`): ridge regression of log L_task (of the configured
  objective, :class:`dcm.control.objectives.TaskObjective`; the paper's force RMSE by default) on features of the
  per-phase stiffness alone (:mod:`dcm.models.stiffness_features`), blind to the demo and the attractor.
  It is fitted on **per-skill centred** data, so it learns how stiffness re-orders one skill's trials
  (what the tuner needs) rather than which skills are hard; the global mean is added back so predictions
  have a sensible level. A learned model that does not beat it has not learnt more than "which
  schedules are usually good". Fit it with::

      python -m dcm.models.references fit --dataset data/sim.h5 --out stiffness_ref.json [--objective wipe]

  and use the JSON as ``ckpt=`` of ``python -m dcm.evaluate`` or ``tune.py`` (a robot-free tuner without a
  neural net), or as ``reference=`` of ``dcm.evaluate``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from scipy import linalg

from dcm.console import error_line, quiet_libraries
from dcm.control.objectives import PAPER, ObjectiveError, TaskObjective, task_window_start
from dcm.data.atomic import write_problem
from dcm.data.recording import stored_recording
from dcm.data.schema import POSE_DELTA_WIDTH
from dcm.models.configuration import ModelInputError, check_objective_name
from dcm.models.contact import ContactPrediction
from dcm.models.metrics import within_skill_correlation
from dcm.models.stiffness_features import FEATURE_SPEC, batch_phase_values, feature_names, features

REFERENCE_FORMAT = "dcm.reference"
REFERENCE_VERSION = 1
COPY_DEMO = "copy_demo"
STIFFNESS_RIDGE = "stiffness_ridge"
ALPHAS = tuple(10.0 ** np.arange(-3, 4))  # ridge strengths tried by grouped cross-validation
GROUP_KEY = "demo_id"


class ReferenceError(ModelInputError):
    """A reference file or fit is unusable; the message names the file and field."""


def _numpy(value: Any) -> np.ndarray:
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value)


class CopyDemo:
    """``F_obs := F_demo`` and ``x_obs := x_demo``: the no-model floor for force and path accuracy. Any control
    rate, no file. ``objective``: the L_task it is scored with (it learnt nothing, so any applies)."""

    model_kind: ClassVar[str] = COPY_DEMO
    ranks_schedules: ClassVar[bool] = False  # its L_task is 0 whatever the stiffness
    predicts_pose: ClassVar[bool] = True  # the demo's own
    data_spec = None  # nothing learnt, so nothing to check a dataset against

    def __init__(self, objective: TaskObjective = PAPER) -> None:
        self.objective = objective

    def predict_contact(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                        generator: Any = None) -> ContactPrediction:
        """F_demo and x_demo's translation with zero spreads: numpy copies of the inputs (their float precision
        kept, so the force and path errors to the demo are exactly 0)."""
        F, std = self.predict_forces(x_demo, F_demo, x_attr, K)
        x = np.array(_numpy(x_demo)[..., :POSE_DELTA_WIDTH], dtype=np.result_type(_numpy(x_demo), np.float32))
        return ContactPrediction(F, std, x, np.zeros_like(x))

    def predict_forces(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any, n_samples: int | None = None,
                       generator: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """``(F_demo, zeros)``: numpy copies of the input (its float precision kept, so L_task is exactly 0)."""
        F = np.array(_numpy(F_demo), dtype=np.result_type(_numpy(F_demo), np.float32))
        return F, np.zeros_like(F)

    def describe(self) -> dict[str, Any]:
        return {"model": COPY_DEMO, "ckpt": COPY_DEMO}


class StiffnessRegression:
    """log L_task = intercept + standardised(features(per-phase K)) · coefficients; see the module docstring."""

    model_kind: ClassVar[str] = STIFFNESS_RIDGE
    ranks_schedules: ClassVar[bool] = True
    predicts_pose: ClassVar[bool] = False  # it predicts L_task alone, of the objective it was fitted for

    def __init__(self, n_phases: int, mean: np.ndarray, scale: np.ndarray, coefficients: np.ndarray,
                 intercept: float, control_hz: float, info: dict[str, Any] | None = None,
                 path: str | None = None, objective: TaskObjective = PAPER) -> None:
        self.n_phases = int(n_phases)
        self.mean = np.asarray(mean, dtype=np.float64)
        self.scale = np.asarray(scale, dtype=np.float64)
        self.coefficients = np.asarray(coefficients, dtype=np.float64)
        self.intercept = float(intercept)
        self.control_hz = float(control_hz)
        self.info = dict(info or {})
        self.path = path
        self.objective = objective
        n_features = len(feature_names(self.n_phases))
        for name, arr in (("mean", self.mean), ("scale", self.scale), ("coefficients", self.coefficients)):
            if arr.shape != (n_features,) or not np.all(np.isfinite(arr)):
                raise ReferenceError(f"{path or 'stiffness reference'}: field {name} must be {n_features} finite "
                                     f"numbers for {self.n_phases} phases, got shape {arr.shape}")

    @property
    def data_spec(self) -> Any:
        from dcm.data.schema import target_channel_names
        from dcm.models.configuration import DataSpec

        # A ridge predicts L_task alone; the targets a split needs to score it are the objective's (the pose too
        # where it counts the path), so a wipe ridge is evaluated on the file it was fitted on.
        targets = target_channel_names("force_and_pose" if self.objective.counts_path else "force")
        return DataSpec(target_channels=targets, control_hz=self.control_hz,
                        stiffness_frame=self.info.get("stiffness_frame", "world"))

    def check_phases(self, n_phases: int | None, source: str) -> None:
        """Refuse schedules of another phase count: fewer phases would be read as repeated values silently."""
        if n_phases is not None and int(n_phases) != self.n_phases:
            raise ReferenceError(f"{source}: schedules have {n_phases} phases, but the stiffness reference "
                                 f"{self.path or ''} was fitted on {self.n_phases}-phase schedules")

    @property
    def task_from_s(self) -> float:
        """Where the L_task it learned starts [s]; 0 when the fit record names no start (the whole trajectory)."""
        return float(self.info.get("task_from_s", 0.0))

    def check_objective(self, objective: TaskObjective | None, source: str) -> None:
        """Refuse to score an L_task other than the one the ridge learned (another kind, or other tolerances,
        which weigh force and path otherwise); None is its own."""
        where = f"the stiffness reference {self.path or '(fitted in memory)'}"
        if objective is None:
            return
        check_objective_name(objective, self.objective, where)
        if objective != self.objective:
            raise ReferenceError(f"{source}: {where} ranks L_task of objective {self.objective.describe()}, not "
                                 f"{objective.describe()}; fit one with those tolerances")

    def check_window(self, task_from_s: float, source: str) -> None:
        """Refuse to score a window of L_task other than the one the ridge learned to rank."""
        if abs(float(task_from_s) - self.task_from_s) > 1e-9:
            raise ReferenceError(f"{source}: the stiffness reference {self.path or ''} ranks L_task from "
                                 f"{self.task_from_s:g} s on, not from task_from_s = {float(task_from_s):g} s; fit "
                                 f"one with `python -m dcm.models.references fit --task-from-s {float(task_from_s):g}`")

    # ------------------------------------------------------------------ prediction
    def predict_log_task_loss(self, K: Any) -> np.ndarray:
        """(B,) predicted log L_task for schedules K (B, H, 6) or (H, 6)."""
        values = batch_phase_values(_numpy(K), self.n_phases)
        z = (features(values) - self.mean) / self.scale
        return self.intercept + z @ self.coefficients

    def predict_task_loss(self, x_demo: Any, F_demo: Any, x_attr: Any, K: Any) -> np.ndarray:
        """(B,) predicted L_task (of ``objective``, in its unit); only K is used (the demo and attractor are
        ignored by design)."""
        return np.exp(self.predict_log_task_loss(K))

    # ------------------------------------------------------------------ fitting
    @classmethod
    def fit(cls, K: np.ndarray, L_task: np.ndarray, skills: np.ndarray, n_phases: int, control_hz: float,
            alpha: float | None = None, info: dict[str, Any] | None = None,
            objective: TaskObjective = PAPER) -> StiffnessRegression:
        """Fit on schedules K (N, H, 6), true L_task (N,) of ``objective`` and skill labels (N,).

        Features and log L_task are centred within each skill; ridge (closed form) on the centred data with
        ``alpha`` or, if None, the one of :data:`ALPHAS` with the best grouped cross-validated within-skill
        error. The intercept is the global mean of log L_task.
        """
        L_task = np.asarray(L_task, dtype=np.float64)
        if np.any(~np.isfinite(L_task)) or np.any(L_task <= 0):
            raise ReferenceError("stiffness reference: L_task must be finite and > 0 to fit log L_task")
        skills = np.asarray(skills)
        X = features(batch_phase_values(K, n_phases))
        y = np.log(L_task)
        Xc, yc = _centre(X, skills), _centre(y, skills)
        scale = Xc.std(axis=0)
        scale = np.where(scale > 1e-12, scale, 1.0)  # a feature constant within every skill carries no ranking
        Zc = Xc / scale
        cv: dict[str, Any] | None = None
        if alpha is None:
            alpha, cv = _cross_validate(Zc, yc, skills)
        coefficients = _ridge(Zc, yc, float(alpha))
        model = cls(n_phases, X.mean(axis=0), scale, coefficients, float(y.mean()), control_hz, info,
                    objective=objective)
        pred = model.predict_log_task_loss(K)
        r, n_used = within_skill_correlation(pred, y, skills, "spearman")
        model.info.update(alpha=float(alpha), cv=cv, n_trajectories=int(len(y)),
                          n_skills=int(len(np.unique(skills))),
                          train_fit={"R_within_spearman": r, "R_within_n_skills": n_used})
        return model

    @classmethod
    def fit_dataset(cls, path: str | Path, split: str = "train", alpha: float | None = None,
                    n_phases: int | None = None, index: np.ndarray | None = None,
                    task_from_s: float = 0.0, objective: TaskObjective = PAPER) -> StiffnessRegression:
        """Fit on ``split`` of a dataset file (only its trajectories ``index``, if given), grouped by
        ``demo_id``; L_task of ``objective`` from its F_obs, x_obs, F_demo and x_demo, counted from
        ``task_from_s`` on."""
        from dcm.data.schema import load_dataset

        loaded = load_dataset(path, split=split)
        P = int(n_phases) if n_phases is not None else dataset_phases(loaded)
        rows = slice(None) if index is None else np.asarray(index)
        try:
            start = task_window_start(task_from_s, loaded.control_hz, loaded.horizon)
        except ValueError as err:
            raise ReferenceError(f"dataset {path}: {err}") from None
        F_obs, F_demo, x_obs, x_demo = (loaded.arrays[f][rows].astype(np.float64)
                                        for f in ("F_obs", "F_demo", "x_obs", "x_demo"))
        L = np.asarray(objective.task_loss(F_obs, F_demo, x_obs, x_demo, start))
        info = {"dataset": _dataset_identity(Path(path), loaded.attrs), "split": split, "group_key": GROUP_KEY,
                "phase_method": _phase_method(loaded.attrs),
                "stiffness_frame": str(loaded.attrs.get("stiffness_frame", "world"))}
        if task_from_s:  # only when set: a whole-trajectory fit records no start
            info["task_from_s"] = float(task_from_s)
        if index is not None:
            info["subset"] = f"{len(L)} of {len(loaded)} trajectories"
        try:
            return cls.fit(loaded.arrays["K"][rows], L, loaded.demo_ids[rows], P, loaded.control_hz, alpha, info,
                           objective)
        except ValueError as err:
            raise ReferenceError(f"dataset {path}, split {split}: {err}") from None

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": REFERENCE_FORMAT, "version": REFERENCE_VERSION, "kind": STIFFNESS_RIDGE,
            "description": "ridge regression of log L_task (of objective) on per-phase stiffness features, fitted "
                           "on per-skill centred data; prediction = exp(intercept + ((features - mean) / scale) . "
                           "coefficients)",
            "objective": self.objective.to_dict(),
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "control_hz": self.control_hz,
            "phases": {"n_phases": self.n_phases, "method": self.info.get("phase_method"),
                       "derivation": "constant segments of the commanded K[:, :3] "
                                     "(dcm.models.stiffness_features.phase_values)"},
            "features": {"spec": FEATURE_SPEC, "names": feature_names(self.n_phases)},
            "mean": self.mean.tolist(), "scale": self.scale.tolist(),
            "coefficients": self.coefficients.tolist(), "intercept": self.intercept,
            "fit": {k: v for k, v in self.info.items() if k != "phase_method"},
        }

    def save(self, path: str | Path) -> Path:
        from dcm.data.atomic import atomic_path

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            Path(tmp).write_text(json.dumps(self.to_dict(), indent=2, default=_json_default) + "\n")
        self.path = str(path)
        return path

    @classmethod
    def from_dict(cls, data: dict[str, Any], path: str) -> StiffnessRegression:
        spec = (data.get("features") or {}).get("spec")
        if spec != FEATURE_SPEC:
            raise ReferenceError(f"{path}: field features.spec is {spec!r}; this dcm reads {FEATURE_SPEC!r}")
        try:
            phases = data["phases"]
            info = dict(data.get("fit") or {}, phase_method=phases.get("method"))
            objective = TaskObjective.from_dict(data.get("objective"))  # a file without one ranks the paper's
            return cls(int(phases["n_phases"]), data["mean"], data["scale"], data["coefficients"],
                       float(data["intercept"]), float(data["control_hz"]), info, path, objective)
        except (KeyError, TypeError) as err:
            raise ReferenceError(f"{path}: missing or malformed field {err}") from None
        except ObjectiveError as err:
            raise ReferenceError(f"{path}: field objective: {err}") from None

    def describe(self) -> dict[str, Any]:
        out = {"model": STIFFNESS_RIDGE, "ckpt": self.path or "fitted in memory", "n_phases": self.n_phases,
               "alpha": self.info.get("alpha"), "fitted_on": self.info.get("dataset", {}).get("path"),
               "fitted_split": self.info.get("split")}
        if self.objective != PAPER:  # named only when it is not the paper's, so earlier logs keep their keys
            out["objective"] = self.objective.to_dict()
        return out


def load_reference(path: str | Path) -> StiffnessRegression:
    """A reference JSON written by :meth:`StiffnessRegression.save`; errors name the file and field."""
    path = Path(path)
    if not path.is_file():
        raise ReferenceError(f"{path}: no such reference file")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ReferenceError(f"{path}: not a readable JSON file ({err})") from None
    if not isinstance(data, dict) or data.get("format") != REFERENCE_FORMAT:
        raise ReferenceError(f"{path}: not a dcm reference file (field format is not {REFERENCE_FORMAT!r})")
    if data.get("version") != REFERENCE_VERSION:
        raise ReferenceError(f"{path}: field version is {data.get('version')!r}; this dcm reads {REFERENCE_VERSION}")
    if data.get("kind") != STIFFNESS_RIDGE:
        raise ReferenceError(f"{path}: field kind is {data.get('kind')!r}; known: {[STIFFNESS_RIDGE]}")
    return StiffnessRegression.from_dict(data, str(path))


# ----------------------------------------------------------------------------------------------- helpers
def _centre(values: np.ndarray, skills: np.ndarray) -> np.ndarray:
    """Subtract each skill's mean (rows grouped by ``skills``)."""
    _, inverse = np.unique(skills, return_inverse=True)
    counts = np.bincount(inverse).astype(np.float64)
    sums = np.zeros((counts.size, *values.shape[1:]))
    np.add.at(sums, inverse, values)
    return values - (sums / counts.reshape(-1, *([1] * (values.ndim - 1))))[inverse]


def _ridge(Z: np.ndarray, y: np.ndarray, alpha: float) -> np.ndarray:
    """argmin ||y - Z w||² + alpha ||w||² (no intercept: the data are centred)."""
    return linalg.solve(Z.T @ Z + alpha * np.eye(Z.shape[1]), Z.T @ y, assume_a="pos")


def _cross_validate(Zc: np.ndarray, yc: np.ndarray, skills: np.ndarray, n_folds: int = 5,
                    ) -> tuple[float, dict[str, Any] | None]:
    """The alpha of :data:`ALPHAS` with the lowest held-out within-skill squared error, over skill folds."""
    unique = np.unique(skills)
    if len(unique) < 2:
        return 1.0, None
    folds = np.arange(len(unique)) % min(n_folds, len(unique))
    fold_of = dict(zip(unique.tolist(), folds.tolist()))
    fold = np.array([fold_of[s] for s in skills.tolist()])
    errors = []
    for alpha in ALPHAS:
        sq = 0.0
        for k in np.unique(fold):
            held = fold == k
            w = _ridge(Zc[~held], yc[~held], alpha)
            sq += float(((Zc[held] @ w - yc[held]) ** 2).sum())  # Zc, yc are centred per skill already
        errors.append(sq / len(yc))
    best = int(np.argmin(errors))
    return float(ALPHAS[best]), {"alphas": list(ALPHAS), "mse": errors, "n_folds": int(folds.max() + 1)}


def dataset_phases(loaded: Any, required: bool = True) -> int | None:
    """Number of phases from the trajectories' ``phase_stiffness_Npm`` attribute (all must agree); None if
    the attribute is absent and not ``required``."""
    counts = {len(m["phase_stiffness_Npm"]) for m in loaded.meta if m.get("phase_stiffness_Npm") is not None}
    if not counts and not required:
        return None
    if len(counts) != 1:
        raise ReferenceError(f"dataset {loaded.path}: cannot tell the number of phases from the attribute "
                             f"phase_stiffness_Npm (found {sorted(counts) or 'none'}); pass --n-phases")
    return counts.pop()


def _phase_method(attrs: dict[str, Any]) -> str | None:
    """``stiffness.phases`` of the generating config, if the file records it (informative only)."""
    from dcm.data.schema import DatasetError, read_config

    try:
        return str(read_config(attrs)["stiffness"]["phases"])
    except (DatasetError, KeyError, TypeError):
        return None


def _dataset_identity(path: Path, attrs: dict[str, Any]) -> dict[str, Any]:
    """Path, SHA-256 and identifying root attributes: enough to tell which file a reference was fitted on."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    keep = ("dataset", "created", "plan_fingerprint", "dcm_version", "embodiment", "search", "seed", "horizon",
            "control_hz", "n_trajectories_total")
    identity = {"path": str(path.resolve()), "sha256": digest.hexdigest(),
                "attrs": {k: attrs[k] for k in keep if k in attrs}}
    if (recorded := stored_recording(attrs, path)) is not None:
        identity["recording"] = recorded
    return identity


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot write {type(obj).__name__} to a reference JSON")


def objective_preset(name: str, **tolerances: float | None) -> TaskObjective:
    """The objective of preset ``name`` (conf/objective/<name>.yaml) with the ``tolerances`` that are given."""
    import yaml

    from dcm.configs import CONF_DIR

    preset = CONF_DIR / "objective" / f"{name}.yaml"
    if not preset.is_file():
        known = sorted(p.stem for p in (CONF_DIR / "objective").glob("*.yaml"))
        raise ReferenceError(f"--objective {name}: no such preset; known: {', '.join(known)}")
    values = yaml.safe_load(preset.read_text()) or {}
    values.update({k: v for k, v in tolerances.items() if v is not None})
    try:
        return TaskObjective.from_config(values)
    except ObjectiveError as err:
        raise ReferenceError(f"--objective {name}: {err}") from None


# ----------------------------------------------------------------------------------------------- CLI
def main(argv: list[str] | None = None) -> Path:
    """``python -m dcm.models.references fit --dataset <h5> --out <json> [--split train] [--alpha a]``."""
    parser = argparse.ArgumentParser(prog="python -m dcm.models.references", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    fit = sub.add_parser("fit", help="fit the stiffness-only reference on a dataset split and save it as JSON")
    fit.add_argument("--dataset", required=True, help="dataset file (.h5)")
    fit.add_argument("--out", required=True, help="reference JSON to write")
    fit.add_argument("--split", default="train", help="split to fit on (default: train)")
    fit.add_argument("--alpha", type=float, default=None, help="ridge strength (default: grouped cross-validation)")
    fit.add_argument("--n-phases", type=int, default=None,
                     help="phases of the schedules (default: from the trajectories' phase_stiffness_Npm)")
    fit.add_argument("--task-from-s", type=float, default=0.0,
                     help="learn the L_task of the force from this time [s] on (1.0: without the approach)")
    fit.add_argument("--objective", default="paper",
                     help="the L_task to learn: a preset of conf/objective/ (paper | wipe; default: paper)")
    fit.add_argument("--force-tolerance-N", type=float, default=None, help="objective wipe: its force tolerance")
    fit.add_argument("--path-tolerance-m", type=float, default=None, help="objective wipe: its path tolerance")
    args = parser.parse_args(argv)
    quiet_libraries()
    if problem := write_problem(args.out):
        raise SystemExit(error_line(f"--out {args.out} cannot be written: {problem}"))
    try:
        objective = objective_preset(args.objective, force_tolerance_N=args.force_tolerance_N,
                                     path_tolerance_m=args.path_tolerance_m)
        model = StiffnessRegression.fit_dataset(args.dataset, args.split, args.alpha, args.n_phases,
                                                task_from_s=args.task_from_s, objective=objective)
    except ValueError as err:  # ReferenceError, DatasetError, StiffnessScheduleError
        raise SystemExit(error_line(err)) from None
    out = model.save(args.out)
    fitted = model.info["train_fit"]
    r = fitted["R_within_spearman"]
    print(f"fitted {STIFFNESS_RIDGE} on {model.info['n_trajectories']} trajectories / {model.info['n_skills']} "
          f"skills (alpha={model.info['alpha']:g}, L_task: {model.objective.describe()}); train within-skill Spearman "
          f"{'nan' if not math.isfinite(r) else f'{r:.3f}'} over {fitted['R_within_n_skills']} skills -> {out}",
          file=sys.stderr)
    return out


if __name__ == "__main__":
    main()
