"""The robot in the loop: propose a round of schedules, run them on the robot, learn from the trials, propose again.

Round 1 is the robot-free search's Pareto front, ``loop.batch`` picks spread along it (the schedules a one-shot
run validates). After each round's trials come back (:mod:`dcm.tuning.observations`):

1. they join the run's observed trials, and the observed front is scored by its hypervolume on the run's stored
   reference point;
2. the round's prediction is compared with what was observed (mean |predicted - observed| L_task): within
   ``loop.tolerance_N`` the model agrees with the robot on this skill and the loop stops; it also stops when
   ``loop.rounds`` rounds (the robot budget) have run;
3. otherwise the model is corrected on this skill from every observed trial (:mod:`dcm.tuning.correction`), a
   robot-free search of ``loop.n_trials`` virtual trials runs on the corrected objective (seeded per round), and
   the next ``loop.batch`` schedules are picks spread along the corrected front of every virtual trial so far,
   none of them a schedule already observed.

Everything lives in the run directory: ``loop/config.yaml`` (the run's settings, which ``resume=`` reuses),
``loop/state.json`` (every round's proposals, their predictions and the observed trials, under the run's
fingerprint), ``proposals/round_<r>/`` (:mod:`dcm.tuning.schedule_files`) and ``loop.json`` (the scores; no
timings or paths of this machine, so the same seed and trials give the same bytes). A round's folder is
written before the state that names it, so a killed run repeats that step and writes the same files. Refused
observations leave every file as it was.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.data.atomic import atomic_path
from dcm.tuning.correction import make_correction
from dcm.tuning.observations import ObservationMismatch, load_observations
from dcm.tuning.pareto import hypervolume, pick_spread, solution_record
from dcm.tuning.robot import FileRobot, make_robot
from dcm.tuning.schedule_files import check_bowl_in_base, round_dir, write_round

STATE = Path("loop") / "state.json"
CONFIG = Path("loop") / "config.yaml"
LOOP_RESULTS = "loop.json"
ROUND_BATCH = 1 << 40  # model samples of round r's search are seeded like batches from r * ROUND_BATCH on
OBSERVED_BATCH = 1 << 39  # ... and the re-prediction of trials that were not proposed, like this batch
SAME_SCHEDULE_RTOL = 1e-4  # per-phase stiffness this close is the same schedule (logs keep ~7 digits)


class LoopStateError(ValueError):
    """A loop state or request this run cannot continue; the message names the file or setting."""


@dataclass
class LoopRun:
    """A tune run set up for the loop (what :func:`dcm.tuning.run.tune` has built before validation)."""

    cfg: Any
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
        return self.cfg.loop


def loop_fingerprint(run: LoopRun) -> dict[str, Any]:
    """What determines the loop's proposals besides the observed trials: the robot-free run's fingerprint and
    size, and the loop settings that shape a proposal (not the budget, the tolerance or who runs the trials)."""
    from dcm.tuning.checks import to_container

    loop = to_container(run.loop)
    keep = ("batch", "correction", "lengthscale", "noise_ratio", "ridge_alpha", "n_trials", "bowl_in_base")
    return json.loads(json.dumps({**run.fingerprint, "robot_free_n_trials": int(run.cfg.robot_free.n_trials),
                                  "loop": {k: loop.get(k) for k in keep}}, sort_keys=True, default=str))


# ----------------------------------------------------------------------------------------------- state
def load_state(run: LoopRun) -> dict[str, Any] | None:
    path = run.out_dir / STATE
    if not path.is_file():
        return None
    state = json.loads(path.read_text())
    expected = loop_fingerprint(run)
    if state.get("fingerprint") != expected:
        from dcm.tuning.optimize import fingerprint_differences

        differences = "; ".join(fingerprint_differences(state.get("fingerprint") or {}, expected))
        raise LoopStateError(f"{path}: this run's loop was started with other settings: {differences}; "
                             "resume it with its own settings or start another run directory")
    return state


def save_state(run: LoopRun, state: dict[str, Any]) -> None:
    path = run.out_dir / STATE
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(state, indent=1))


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


def _arrays(rounds: list[dict[str, Any]], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(phase stiffness, objectives) of every round's ``observations`` or ``search`` entry."""
    parts = [r[key] for r in rounds if r.get(key)]
    if not parts:
        return np.zeros((0, 0, 3)), np.zeros((0, 2))
    return (np.concatenate([np.asarray(p["phase_stiffness_Npm"], float) for p in parts]),
            np.concatenate([np.asarray(p["objectives"], float).reshape(-1, 2) for p in parts]))


# ----------------------------------------------------------------------------------------------- proposing
def _same(candidates: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(N,) whether each candidate schedule is one of ``observed``."""
    if not len(observed) or not len(candidates):
        return np.zeros(len(candidates), dtype=bool)
    a, b = candidates.reshape(len(candidates), 1, -1), observed.reshape(1, len(observed), -1)
    return (np.abs(a - b) <= SAME_SCHEDULE_RTOL * np.abs(b)).all(-1).any(-1)


def _model_predictions(run: LoopRun, state: dict[str, Any], params: np.ndarray, rounds: list[int]) -> np.ndarray:
    """The model's own (uncorrected) L_task of observed trials: the prediction made when the schedule was
    proposed, or a fresh one for a trial the robot ran without it being proposed."""
    proposed = {}
    for r in state["rounds"]:
        for k, value in zip(r["proposals"], r["model_L_task_N"]):
            proposed.setdefault(r["round"], []).append((np.asarray(k, float), value))
    out = np.full(len(params), np.nan)
    missing = []
    for i, (k, r) in enumerate(zip(params, rounds)):
        match = [value for candidate, value in proposed.get(r, []) if _same(k[None], candidate[None])[0]]
        if match:
            out[i] = match[0]
        else:
            missing.append(i)
    if missing:
        out[missing] = run.model_objective(params[missing], OBSERVED_BATCH)[:, 0]
    return out


def fit_correction(run: LoopRun, state: dict[str, Any]) -> Any:
    observed, objectives = _arrays(state["rounds"], "observations")
    rounds = [r["round"] for r in state["rounds"] if r.get("observations")
              for _ in r["observations"]["objectives"]]
    model = _model_predictions(run, state, observed, rounds)
    correction = make_correction(str(run.loop.correction), run.space.min_Npm, run.space.max_Npm,
                                 lengthscale=float(run.loop.lengthscale), noise_ratio=float(run.loop.noise_ratio),
                                 ridge_alpha=float(run.loop.ridge_alpha))
    return correction.fit(observed, objectives[:, 0] - model)


def round_search(run: LoopRun, round_index: int, correction: Any) -> tuple[np.ndarray, np.ndarray]:
    """``loop.n_trials`` virtual trials of a search on the corrected objective, seeded by the round: their per-phase
    stiffness and the model's own (uncorrected) objectives."""
    from dcm.search import make_search
    from dcm.tuning.optimize import optimize

    n_trials = int(run.loop.n_trials)
    if n_trials == 0:
        return np.zeros((0, run.space.n_phases, 3)), np.zeros((0, 2))
    seed = int(np.random.SeedSequence([int(run.cfg.seed), round_index]).generate_state(1)[0] >> 1)
    search = make_search(run.cfg.search.name, run.space, seed, **run.search_options)
    raw: list[np.ndarray] = []

    def corrected(proposals: np.ndarray, first: int) -> np.ndarray:
        predicted = run.model_objective(proposals, round_index * ROUND_BATCH + first)
        raw.append(predicted.copy())
        predicted[:, 0] += correction(proposals)
        return predicted

    log = optimize(search, corrected, n_trials, int(run.cfg.robot_free.batch_size),
                   desc=f"round {round_index} search (corrected model)")
    return log.arrays()[0], np.concatenate(raw)


def pick_batch(objectives: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` rows: picks spread along the front, then along the next front of what is left, ...
    (a round runs ``loop.batch`` schedules even where the corrected front holds fewer)."""
    left, chosen = np.arange(len(objectives)), []
    while len(chosen) < count:
        picks = pick_spread(objectives[left], count - len(chosen))
        if not len(picks):
            break
        chosen.extend(left[picks].tolist())
        left = np.delete(left, picks)
    return np.asarray(chosen, dtype=int)


def propose(run: LoopRun, state: dict[str, Any], round_index: int) -> dict[str, Any]:
    """Round ``round_index``'s entry: its proposals with their predicted (corrected) and model objectives."""
    batch = int(run.loop.batch)
    if round_index == 1:
        correction = make_correction("none", run.space.min_Npm, run.space.max_Npm)
        search = (np.zeros((0, run.space.n_phases, 3)), np.zeros((0, 2)))
    else:
        correction = fit_correction(run, state)
        search = round_search(run, round_index, correction)
    earlier, earlier_raw = _arrays(state["rounds"], "search")
    params = np.concatenate([p for p in (run.free_params, earlier, search[0]) if len(p)])
    raw = np.concatenate([p for p in (run.free_predicted, earlier_raw, search[1]) if len(p)])
    predicted = raw.copy()
    predicted[:, 0] += correction(params)
    observed, _ = _arrays(state["rounds"], "observations")
    proposed = np.concatenate([np.asarray(r["proposals"], float) for r in state["rounds"]]) if state["rounds"] \
        else np.zeros((0, run.space.n_phases, 3))
    fresh = np.flatnonzero(~_same(params, observed) & ~_same(params, proposed))
    picks = fresh[pick_batch(predicted[fresh], batch)]
    entry = {"round": round_index, "proposals": params[picks].tolist(), "predicted": predicted[picks].tolist(),
             "model_L_task_N": raw[picks, 0].tolist(), "correction": correction.describe(), "observations": None}
    if len(search[0]):
        entry["search"] = {"phase_stiffness_Npm": search[0].tolist(), "objectives": search[1].tolist()}
    return entry


def write_round_folder(run: LoopRun, entry: dict[str, Any]) -> Path:
    """Write round ``entry``'s folder atomically (a temporary folder renamed into place); returns it."""
    from dcm.control import damping_mass
    from dcm.tuning.checks import to_container

    folder = round_dir(run.out_dir, entry["round"])
    proposals = np.asarray(entry["proposals"], float)
    schedules = run.skill.schedules(proposals)
    attractors = run.simulator.attractor(run.demo, schedules)
    mass = damping_mass(str(run.cfg.stiffness.damping), run.simulator.apparent_mass)
    info = {
        "control_hz": float(run.cfg.control_hz), "demo": run.demo.spec.to_dict(), "embodiment": str(run.cfg.embodiment),
        "horizon_steps": int(schedules.shape[1]), "phase_boundaries_steps": np.asarray(run.skill.boundaries).tolist(),
        "task_from_s": float(run.cfg.get("task_from_s", 0.0)),
        "damping": {"rule": "D = 2 sqrt(m K) per axis", "mode": str(run.cfg.stiffness.damping),
                    "mass_kg": mass.tolist()},
        "stiffness_filter_tau_s": float(run.simulator.stiffness_tau_s),
        "correction": entry["correction"],
    }
    bowl_in_base = check_bowl_in_base(to_container(run.loop.get("bowl_in_base")))
    tmp = folder.with_name(folder.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    write_round(tmp, entry["round"], proposals, schedules, attractors, mass, run.demo, info,
                np.asarray(entry["predicted"], float), bowl_in_base)
    if folder.exists():
        shutil.rmtree(folder)
    tmp.rename(folder)
    return folder


# ----------------------------------------------------------------------------------------------- observing
def add_observations(run: LoopRun, state: dict[str, Any], path: Path) -> dict[str, Any]:
    """Check the trials of ``path`` against the run and its pending round (raising before any change), then
    attach them to that round; returns the updated state (not yet saved)."""
    pending = [r for r in state["rounds"] if r.get("observations") is None]
    if state.get("stopped") or not pending:
        why = state["stopped"]["message"] if state.get("stopped") else "no round is waiting for trials"
        raise LoopStateError(f"observations={path}: this run's loop has stopped ({why}); start another run, or "
                             "raise loop.rounds to continue it")
    observations = load_observations(path, run.fingerprint, run.skill, run.space)
    content = _content_hash(observations)
    for r in state["rounds"]:
        if r.get("observations") and r["observations"]["content_sha256"] == content:
            raise ObservationMismatch(f"observations {path}: these trials were already added as round {r['round']}")
    pending[0]["observations"] = {
        "file": Path(path).name, "content_sha256": content, "trajectories": observations.names,
        "phase_stiffness_Npm": observations.phase_stiffness.tolist(), "objectives": observations.objectives.tolist()}
    return state


def _content_hash(observations: Any) -> str:
    import hashlib

    digest = hashlib.sha256(np.ascontiguousarray(observations.phase_stiffness, np.float64).tobytes())
    digest.update(np.ascontiguousarray(observations.objectives, np.float64).tobytes())
    return digest.hexdigest()


def judge_round(run: LoopRun, state: dict[str, Any]) -> None:
    """Score the round that just got its trials and decide whether the loop stops (in ``state``)."""
    entry = [r for r in state["rounds"] if r.get("observations")][-1]
    observed = entry["observations"]
    params, objectives = np.asarray(observed["phase_stiffness_Npm"], float), np.asarray(observed["objectives"], float)
    proposals, predicted = np.asarray(entry["proposals"], float), np.asarray(entry["predicted"], float)
    errors = []
    for k, value in zip(params, objectives):
        match = np.flatnonzero(_same(proposals, k[None]))
        if len(match) and np.isfinite(value[0]):
            errors.append(abs(predicted[match[0], 0] - value[0]))
    mae = float(np.mean(errors)) if errors else None
    tolerance = float(run.loop.tolerance_N)
    entry["prediction_mae_N"] = mae
    entry["n_compared"] = len(errors)
    done = sum(1 for r in state["rounds"] if r.get("observations"))
    if mae is not None and mae <= tolerance:
        state["stopped"] = {"reason": "agreed", "message": (
            f"round {entry['round']}: predicted and observed L_task agree within loop.tolerance_N = {tolerance:g} N "
            f"(mean |error| {mae:.3g} N over {len(errors)} trials)")}
    elif done >= int(run.loop.rounds):
        state["stopped"] = {"reason": "budget", "message": (
            f"the robot budget is spent: {done} rounds of trials (loop.rounds = {int(run.loop.rounds)})"
            + ("" if mae is None else f"; the last round's mean |error| {mae:.3g} N exceeds "
               f"loop.tolerance_N = {tolerance:g} N"))}


# ----------------------------------------------------------------------------------------------- the loop
def results(run: LoopRun, state: dict[str, Any]) -> dict[str, Any]:
    """``loop.json``: the rounds, the observed front and its hypervolume, and what happens next."""
    reference = run.reference
    finite = lambda a: a[np.isfinite(a).all(axis=1)]  # noqa: E731
    rounds, seen = [], np.zeros((0, 2))
    for r in state["rounds"]:
        summary = {"round": r["round"], "n_proposals": len(r["proposals"]), "correction": r["correction"],
                   "hypervolume_predicted": hypervolume(finite(np.asarray(r["predicted"], float)), reference)}
        if r.get("observations"):
            objectives = np.asarray(r["observations"]["objectives"], float).reshape(-1, 2)
            seen = np.concatenate([seen, objectives])
            summary.update(observations=r["observations"]["file"], n_trials=len(objectives),
                           prediction_mae_N=r.get("prediction_mae_N"),
                           hypervolume_round=hypervolume(finite(objectives), reference),
                           hypervolume_observed=hypervolume(finite(seen), reference))
        rounds.append(summary)
    params, objectives = _arrays(state["rounds"], "observations")
    picks = pick_spread(objectives, int(run.cfg.robot_free.n_validate)) if len(objectives) else []
    out = {
        "robot": str(run.cfg.robot), "correction": str(run.loop.correction),
        "tolerance_N": float(run.loop.tolerance_N), "budget_rounds": int(run.loop.rounds),
        "batch": int(run.loop.batch), "reference_point": run.reference_info, "rounds": rounds,
        "observed": {"n_trials": len(objectives),
                     "hypervolume": hypervolume(finite(objectives), reference) if len(objectives) else 0.0,
                     "solutions": [solution_record(params[i], objectives[i]) for i in picks]},
    }
    if state.get("stopped"):
        out["stopped"] = state["stopped"]
    else:
        pending = state["rounds"][-1]
        out["next"] = {"round": pending["round"], "folder": f"proposals/round_{pending['round']}",
                       "n_schedules": len(pending["proposals"])}
    return out


def write_results(run: LoopRun, state: dict[str, Any]) -> dict[str, Any]:
    out = results(run, state)
    with atomic_path(run.out_dir / LOOP_RESULTS) as tmp:
        tmp.write_text(json.dumps(out, indent=2, default=float))
    return out


def advance(run: LoopRun, state: dict[str, Any]) -> dict[str, Any]:
    """After a round's trials: judge it, and unless the loop stops, propose and write the next round; saves."""
    judge_round(run, state)
    if not state.get("stopped"):
        entry = propose(run, state, len(state["rounds"]) + 1)
        state["rounds"].append(entry)
        write_round_folder(run, entry)
    save_state(run, state)
    return state


def run_loop(run: LoopRun, observations: Path | None = None, say: Any = print) -> dict[str, Any]:
    """Start or continue the loop of ``run``; with ``observations``, the trials of its pending round. Runs rounds
    until the loop stops (``robot=sim``) or a real robot has to run the next one (``robot=files``)."""
    state = load_state(run)
    if state is None:
        if observations is not None:
            raise LoopStateError(f"observations={observations}: {run.out_dir} has no proposals waiting for trials")
        save_config(run.cfg, run.out_dir)
        state = {"fingerprint": loop_fingerprint(run), "rounds": [], "stopped": None}
        entry = propose(run, state, 1)
        state["rounds"].append(entry)
        write_round_folder(run, entry)
        save_state(run, state)
    elif _more_budget(run, state) and observations is None:  # resumed with a larger loop.rounds
        save_config(run.cfg, run.out_dir)
        state["stopped"] = None
        entry = propose(run, state, len(state["rounds"]) + 1)
        state["rounds"].append(entry)
        write_round_folder(run, entry)
        save_state(run, state)
    elif observations is not None:
        state = add_observations(run, state, Path(observations))  # refused: nothing written
        save_config(run.cfg, run.out_dir)  # a raised loop.rounds is the run's budget from now on
        state = advance(run, state)
    robot = make_robot(str(run.cfg.robot), run.out_dir, run.simulator, run.demo, run.skill)
    while not state.get("stopped"):
        pending = state["rounds"][-1]
        folder = round_dir(run.out_dir, pending["round"])
        if not (folder / "round.yaml").is_file():  # a run killed between the folder and the state
            write_round_folder(run, pending)
        path = robot.run(folder, np.asarray(pending["proposals"], float), pending["round"])
        if path is None:
            write_results(run, state)
            say(FileRobot(run.out_dir).message(folder, len(pending["proposals"])))
            return results(run, state)
        state = advance(run, add_observations(run, state, path))
        last = [r for r in state["rounds"] if r.get("observations")][-1]
        say(f"round {last['round']}: {len(last['observations']['objectives'])} trials by robot={run.cfg.robot}, "
            f"mean |predicted - observed| L_task {_fmt(last.get('prediction_mae_N'))} N")
    out = write_results(run, state)
    say(f"loop stopped: {state['stopped']['message']}")
    return out


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


def _more_budget(run: LoopRun, state: dict[str, Any]) -> bool:
    """Whether a loop stopped by its budget may run another round under this invocation's ``loop.rounds``."""
    stopped = state.get("stopped") or {}
    return stopped.get("reason") == "budget" and len(state["rounds"]) < int(run.loop.rounds)


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3g}"


__all__ = ["CONFIG", "LOOP_RESULTS", "LoopRun", "LoopStateError", "STATE", "add_observations", "advance",
           "load_state", "loop_fingerprint", "propose", "results", "resume_config", "run_loop", "save_config"]
