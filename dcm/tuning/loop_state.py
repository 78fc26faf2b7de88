"""The robot loop's state: its rounds (proposals, predictions, the trials observed on them) and why it stopped.

``loop/state.json`` holds one :class:`LoopState`; its format is the one earlier versions wrote (a list of round
mappings under the run's fingerprint), so a loop started by them resumes. Only :class:`LoopState`'s methods change
a state: a round is added, observed, then judged, each in one place.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.data.atomic import atomic_path

STATE = Path("loop") / "state.json"
CONFIG = Path("loop") / "config.yaml"
SAME_SCHEDULE_RTOL = 1e-4  # per-phase stiffness this close is the same schedule (logs keep ~7 digits)


class LoopStateError(ValueError):
    """A loop state or request this run cannot continue; the message names the file or setting."""


def same_schedule(candidates: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(N,) whether each candidate schedule (N, P, 3) is one of ``observed``."""
    if not len(observed) or not len(candidates):
        return np.zeros(len(candidates), dtype=bool)
    a, b = candidates.reshape(len(candidates), 1, -1), observed.reshape(1, len(observed), -1)
    return (np.abs(a - b) <= SAME_SCHEDULE_RTOL * np.abs(b)).all(-1).any(-1)


@dataclass(frozen=True)
class RoundTrials:
    """The robot's trials of one round, as read from its observations file."""

    file: str  # the file's name
    content_sha256: str  # of the trials' stiffness and objectives: the same trials are refused twice
    trajectories: list[str]
    phase_stiffness_Npm: np.ndarray  # (N, P, 3)
    objectives: np.ndarray  # (N, 2) observed (L_task N, L_comp kN/m)

    def to_json(self) -> dict[str, Any]:
        return {"file": self.file, "content_sha256": self.content_sha256, "trajectories": list(self.trajectories),
                "phase_stiffness_Npm": self.phase_stiffness_Npm.tolist(), "objectives": self.objectives.tolist()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RoundTrials:
        return cls(data["file"], data["content_sha256"], list(data["trajectories"]),
                   np.asarray(data["phase_stiffness_Npm"], float), np.asarray(data["objectives"], float).reshape(-1, 2))


@dataclass
class Round:
    """One round: its proposals with the (corrected) objectives predicted for them and the model's own L_task,
    the correction it was proposed under, its search's virtual trials, then the robot's trials and how far the
    prediction was from them."""

    index: int
    proposals: np.ndarray  # (B, P, 3) N/m
    predicted: np.ndarray  # (B, 2) corrected prediction
    model_L_task_N: np.ndarray  # (B,) the model's own
    correction: dict[str, Any]
    search_params: np.ndarray | None = None  # (S, P, 3) the round's virtual trials, None without a search
    search_objectives: np.ndarray | None = None  # (S, 2) the model's own objectives of them
    trials: RoundTrials | None = None
    prediction_mae_N: float | None = None
    n_compared: int | None = None  # set once judged

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"round": self.index, "proposals": self.proposals.tolist(),
                               "predicted": self.predicted.tolist(), "model_L_task_N": self.model_L_task_N.tolist(),
                               "correction": self.correction,
                               "observations": None if self.trials is None else self.trials.to_json()}
        if self.search_params is not None:
            out["search"] = {"phase_stiffness_Npm": self.search_params.tolist(),
                             "objectives": self.search_objectives.tolist()}
        if self.n_compared is not None:
            out.update(prediction_mae_N=self.prediction_mae_N, n_compared=self.n_compared)
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Round:
        search = data.get("search")
        return cls(int(data["round"]), np.asarray(data["proposals"], float),
                   np.asarray(data["predicted"], float).reshape(-1, 2), np.asarray(data["model_L_task_N"], float),
                   data["correction"], None if not search else np.asarray(search["phase_stiffness_Npm"], float),
                   None if not search else np.asarray(search["objectives"], float).reshape(-1, 2),
                   None if not data.get("observations") else RoundTrials.from_json(data["observations"]),
                   data.get("prediction_mae_N"), data.get("n_compared"))


@dataclass(frozen=True)
class Stop:
    reason: str  # "agreed" | "budget"
    message: str


@dataclass
class LoopState:
    """Every round so far and why the loop stopped (None while it runs), under the loop's fingerprint."""

    fingerprint: dict[str, Any]
    rounds: list[Round]
    stopped: Stop | None = None

    # ------------------------------------------------------------------ reading
    @property
    def pending(self) -> Round | None:
        """The first round still waiting for its trials."""
        return next((r for r in self.rounds if r.trials is None), None)

    @property
    def observed_rounds(self) -> list[Round]:
        return [r for r in self.rounds if r.trials is not None]

    def observed(self) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """(phase stiffness, objectives, round index) of every observed trial."""
        rounds = self.observed_rounds
        if not rounds:
            return np.zeros((0, 0, 3)), np.zeros((0, 2)), []
        return (np.concatenate([r.trials.phase_stiffness_Npm for r in rounds]),
                np.concatenate([r.trials.objectives for r in rounds]),
                [r.index for r in rounds for _ in r.trials.objectives])

    def searched(self) -> tuple[np.ndarray, np.ndarray]:
        """(phase stiffness, the model's objectives) of every round search's virtual trials."""
        rounds = [r for r in self.rounds if r.search_params is not None and len(r.search_params)]
        if not rounds:
            return np.zeros((0, 0, 3)), np.zeros((0, 2))
        return np.concatenate([r.search_params for r in rounds]), np.concatenate([r.search_objectives for r in rounds])

    # ------------------------------------------------------------------ changing
    def add_round(self, entry: Round) -> None:
        self.rounds.append(entry)

    def resume_budget(self) -> None:
        """A loop stopped by its budget runs on under a larger ``loop.rounds``."""
        self.stopped = None

    def observe(self, trials: RoundTrials) -> None:
        """Attach ``trials`` to the pending round."""
        self.pending.trials = trials

    def judge(self, entry: Round, mae_N: float | None, n_compared: int, stop: Stop | None) -> None:
        """Record how far round ``entry``'s prediction was from its trials, and whether the loop stops."""
        entry.prediction_mae_N, entry.n_compared = mae_N, n_compared
        if stop is not None:
            self.stopped = stop

    # ------------------------------------------------------------------ files
    def to_json(self) -> dict[str, Any]:
        return {"fingerprint": self.fingerprint, "rounds": [r.to_json() for r in self.rounds],
                "stopped": None if self.stopped is None else {"reason": self.stopped.reason,
                                                              "message": self.stopped.message}}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> LoopState:
        stopped = data.get("stopped")
        return cls(data.get("fingerprint") or {}, [Round.from_json(r) for r in data.get("rounds", [])],
                   None if not stopped else Stop(stopped["reason"], stopped["message"]))

    def save(self, out_dir: Path) -> None:
        path = out_dir / STATE
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_json(), indent=1))


@dataclass
class LoopRun:
    """A tune run set up for the loop (:func:`dcm.tuning.run.run_robot_loop`: its setup and robot-free search)."""

    settings: Any  # dcm.tuning.settings.TuneSettings
    out_dir: Path
    fingerprint: dict[str, Any]  # the robot-free log's fingerprint (skill, predictor, search)
    simulator: Any
    demo: Any
    skill: Any
    space: Any
    model_objective: Any  # ModelObjective of the run
    free_params: np.ndarray  # (N, P, 3) the robot-free search's virtual trials
    free_predicted: np.ndarray  # (N, 2)
    reference_info: dict[str, Any]
    search_options: dict[str, Any]  # the robot-free search's options, which each round's search shares

    @property
    def reference(self) -> np.ndarray:
        return np.array([self.reference_info["L_task_N"], self.reference_info["L_comp_kNpm"]])

    @property
    def loop(self) -> Any:
        return self.settings.loop


def loop_fingerprint(run: LoopRun) -> dict[str, Any]:
    """What determines the loop's proposals besides the observed trials: the robot-free run's fingerprint and
    size, and the loop settings that shape a proposal (not the budget, the tolerance or who runs the trials)."""
    loop = asdict(run.loop)
    keep = ("batch", "correction", "lengthscale", "noise_ratio", "ridge_alpha", "n_trials", "bowl_in_base")
    return json.loads(json.dumps({**run.fingerprint, "robot_free_n_trials": int(run.settings.robot_free.n_trials),
                                  "loop": {k: loop.get(k) for k in keep}}, sort_keys=True, default=str))


def load_state(out_dir: Path, expected: dict[str, Any]) -> LoopState | None:
    """The loop state of the run in ``out_dir``, None if it has none; refused when another loop fingerprint
    (``expected``: this invocation's) wrote it."""
    path = out_dir / STATE
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    if data.get("fingerprint") != expected:
        from dcm.tuning.optimize import fingerprint_differences

        differences = "; ".join(fingerprint_differences(data.get("fingerprint") or {}, expected))
        raise LoopStateError(f"{path}: this run's loop was started with other settings: {differences}; "
                             "resume it with its own settings or start another run directory")
    return LoopState.from_json(data)


def save_config(cfg: Any, out_dir: Path) -> None:
    """The run's settings, for ``resume=``: resolved, with ``out_dir`` the run directory."""
    from omegaconf import OmegaConf

    from dcm.tuning.checks import to_container

    plain = to_container(cfg)
    plain.update(out_dir=str(out_dir), resume=None, observations=None)
    path = out_dir / CONFIG
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(OmegaConf.to_yaml(OmegaConf.create(plain)))


RESUME_OVERRIDES = ("loop.rounds", "loop.tolerance_N", "robot", "torch_threads", "device")


def resume_config(run_dir: str | Path, overrides: list[str] = ()) -> Any:
    """The settings of the loop run in ``run_dir`` (its ``loop/config.yaml``), with the command line's
    ``overrides`` (``key=value``) of :data:`RESUME_OVERRIDES` applied; any other override is refused, since the
    run's proposals and trials belong to its own settings."""
    from omegaconf import OmegaConf

    from dcm.tuning.checks import TuneConfigError

    path = Path(run_dir) / CONFIG
    if not path.is_file():
        raise TuneConfigError(f"resume={run_dir}: no {CONFIG} there: not a run started with robot=sim or robot=files")
    cfg = OmegaConf.load(path)
    changes = []
    for item in overrides:
        key = item.split("=", 1)[0].lstrip("+~")
        if key in ("resume", "observations") or key.startswith("hydra"):
            continue
        if key not in RESUME_OVERRIDES:
            raise TuneConfigError(f"resume={run_dir} keeps that run's settings; {key} cannot change (only "
                                  f"{', '.join(RESUME_OVERRIDES)}); start a new run for other settings")
        changes.append(item.lstrip("+"))
    return OmegaConf.merge(cfg, OmegaConf.from_dotlist(changes)) if changes else cfg


__all__ = ["CONFIG", "LoopRun", "LoopState", "LoopStateError", "RESUME_OVERRIDES", "Round", "RoundTrials", "STATE", "Stop",
           "load_state", "loop_fingerprint", "resume_config", "same_schedule", "save_config"]
