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
from pathlib import Path
from typing import Any

import numpy as np

from dcm.data.atomic import atomic_path
from dcm.tuning.loop_state import (
    CONFIG,
    STATE,
    LoopRun,
    LoopState,
    LoopStateError,
    Round,
    RoundTrials,
    Stop,
    load_state,
    loop_fingerprint,
    resume_config,
    same_schedule,
    save_config,
)
from dcm.tuning.observations import ObservationMismatch, load_observations
from dcm.tuning.pareto import hypervolume, pick_spread, solution_record
from dcm.tuning.proposals import propose
from dcm.tuning.robot import FileRobot, make_robot
from dcm.tuning.schedule_files import check_bowl_in_base, round_dir, write_round

LOOP_RESULTS = "loop.json"


def write_round_folder(run: LoopRun, entry: Round) -> Path:
    """Write round ``entry``'s folder atomically (a temporary folder renamed into place); returns it."""
    from dcm.control import damping_mass

    folder = round_dir(run.out_dir, entry.index)
    proposals = entry.proposals
    schedules = run.skill.schedules(proposals)
    attractors = run.simulator.attractor(run.demo, schedules, run.skill.axes)
    mass = damping_mass(str(run.settings.stiffness['damping']), run.simulator.apparent_mass)
    info = {
        "control_hz": float(run.settings.control_hz), "demo": run.demo.spec.to_dict(), "embodiment": str(run.settings.embodiment),
        "horizon_steps": int(schedules.shape[1]), "phase_boundaries_steps": np.asarray(run.skill.boundaries).tolist(),
        "task_from_s": float(run.settings.task_from_s),
        "damping": {"rule": "D = 2 sqrt(m K) per axis", "mode": str(run.settings.stiffness['damping']),
                    "mass_kg": mass.tolist()},
        "stiffness_filter_tau_s": float(run.simulator.stiffness_tau_s),
        "correction": entry.correction,
    }
    bowl_in_base = check_bowl_in_base(run.loop.bowl_in_base)
    tmp = folder.with_name(folder.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    write_round(tmp, entry.index, proposals, schedules, attractors, mass, run.demo, info, entry.predicted,
                bowl_in_base, run.skill.axes)
    if folder.exists():
        shutil.rmtree(folder)
    tmp.rename(folder)
    return folder


# ----------------------------------------------------------------------------------------------- observing
def add_observations(run: LoopRun, state: LoopState, path: Path) -> None:
    """Check the trials of ``path`` against the run and its pending round (raising before any change), then
    attach them to that round (the state is not yet saved)."""
    if state.stopped is not None or state.pending is None:
        why = state.stopped.message if state.stopped is not None else "no round is waiting for trials"
        raise LoopStateError(f"observations={path}: this run's loop has stopped ({why}); start another run, or "
                             "raise loop.rounds to continue it")
    observations = load_observations(path, run.fingerprint, run.skill, run.space)
    content = _content_hash(observations)
    for r in state.observed_rounds:
        if r.trials.content_sha256 == content:
            raise ObservationMismatch(f"observations {path}: these trials were already added as round {r.index}")
    state.observe(RoundTrials(Path(path).name, content, list(observations.names),
                              np.asarray(observations.phase_stiffness, float),
                              np.asarray(observations.objectives, float).reshape(-1, 2)))


def _content_hash(observations: Any) -> str:
    import hashlib

    digest = hashlib.sha256(np.ascontiguousarray(observations.phase_stiffness, np.float64).tobytes())
    digest.update(np.ascontiguousarray(observations.objectives, np.float64).tobytes())
    return digest.hexdigest()


def judge_round(run: LoopRun, state: LoopState) -> None:
    """Score the round that just got its trials and decide whether the loop stops."""
    entry = state.observed_rounds[-1]
    errors = []
    for k, value in zip(entry.trials.phase_stiffness_Npm, entry.trials.objectives):
        match = np.flatnonzero(same_schedule(entry.proposals, k[None]))
        if len(match) and np.isfinite(value[0]):
            errors.append(abs(entry.predicted[match[0], 0] - value[0]))
    mae = float(np.mean(errors)) if errors else None
    tolerance = float(run.loop.tolerance_N)
    done = len(state.observed_rounds)
    stop = None
    if mae is not None and mae <= tolerance:
        stop = Stop("agreed", f"round {entry.index}: predicted and observed L_task agree within loop.tolerance_N = "
                              f"{tolerance:g} N (mean |error| {mae:.3g} N over {len(errors)} trials)")
    elif done >= int(run.loop.rounds):
        stop = Stop("budget", f"the robot budget is spent: {done} rounds of trials (loop.rounds = "
                              f"{int(run.loop.rounds)})" + ("" if mae is None else f"; the last round's mean |error| "
                              f"{mae:.3g} N exceeds loop.tolerance_N = {tolerance:g} N"))
    state.judge(entry, mae, len(errors), stop)


# ----------------------------------------------------------------------------------------------- the loop
def results(run: LoopRun, state: LoopState) -> dict[str, Any]:
    """``loop.json``: the rounds, the observed front and its hypervolume, and what happens next."""
    reference = run.reference
    finite = lambda a: a[np.isfinite(a).all(axis=1)]  # noqa: E731
    rounds, seen = [], np.zeros((0, 2))
    for r in state.rounds:
        summary = {"round": r.index, "n_proposals": len(r.proposals), "correction": r.correction,
                   "hypervolume_predicted": hypervolume(finite(r.predicted), reference)}
        if r.trials is not None:
            objectives = r.trials.objectives
            seen = np.concatenate([seen, objectives])
            summary.update(observations=r.trials.file, n_trials=len(objectives), prediction_mae_N=r.prediction_mae_N,
                           hypervolume_round=hypervolume(finite(objectives), reference),
                           hypervolume_observed=hypervolume(finite(seen), reference))
        rounds.append(summary)
    params, objectives, _ = state.observed()
    picks = pick_spread(objectives, int(run.settings.robot_free.n_validate)) if len(objectives) else []
    out = {
        "robot": str(run.settings.robot), "correction": str(run.loop.correction),
        "tolerance_N": float(run.loop.tolerance_N), "budget_rounds": int(run.loop.rounds),
        "batch": int(run.loop.batch), "reference_point": run.reference_info, "rounds": rounds,
        "observed": {"n_trials": len(objectives),
                     "hypervolume": hypervolume(finite(objectives), reference) if len(objectives) else 0.0,
                     "solutions": [solution_record(params[i], objectives[i]) for i in picks]},
    }
    if state.stopped is not None:
        out["stopped"] = {"reason": state.stopped.reason, "message": state.stopped.message}
    else:
        pending = state.rounds[-1]
        out["next"] = {"round": pending.index, "folder": f"proposals/round_{pending.index}",
                       "n_schedules": len(pending.proposals)}
    return out


def write_results(run: LoopRun, state: LoopState) -> dict[str, Any]:
    out = results(run, state)
    with atomic_path(run.out_dir / LOOP_RESULTS) as tmp:
        tmp.write_text(json.dumps(out, indent=2, default=float))
    return out


def _next_round(run: LoopRun, state: LoopState) -> None:
    """Propose the next round, write its folder, then the state that names it."""
    entry = propose(run, state, len(state.rounds) + 1)
    state.add_round(entry)
    write_round_folder(run, entry)
    state.save(run.out_dir)


def advance(run: LoopRun, state: LoopState) -> None:
    """After a round's trials: judge it, and unless the loop stops, propose and write the next round; saves."""
    judge_round(run, state)
    if state.stopped is None:
        _next_round(run, state)
    else:
        state.save(run.out_dir)


def run_loop(run: LoopRun, observations: Path | None = None, say: Any = print) -> dict[str, Any]:
    """Start or continue the loop of ``run``; with ``observations``, the trials of its pending round. Runs rounds
    until the loop stops (``robot=sim``) or a real robot has to run the next one (``robot=files``)."""
    state = load_state(run.out_dir, loop_fingerprint(run))
    if state is None:
        if observations is not None:
            raise LoopStateError(f"observations={observations}: {run.out_dir} has no proposals waiting for trials")
        save_config(run.settings.source, run.out_dir)
        state = LoopState(loop_fingerprint(run), [])
        _next_round(run, state)
    elif _more_budget(run, state) and observations is None:  # resumed with a larger loop.rounds
        save_config(run.settings.source, run.out_dir)
        state.resume_budget()
        _next_round(run, state)
    elif observations is not None:
        add_observations(run, state, Path(observations))  # refused: nothing written
        save_config(run.settings.source, run.out_dir)  # a raised loop.rounds is the run's budget from now on
        advance(run, state)
    robot = make_robot(str(run.settings.robot), run.out_dir, run.simulator, run.demo, run.skill)
    while state.stopped is None:
        pending = state.rounds[-1]
        folder = round_dir(run.out_dir, pending.index)
        if not (folder / "round.yaml").is_file():  # a run killed between the folder and the state
            write_round_folder(run, pending)
        path = robot.run(folder, pending.proposals, pending.index)
        if path is None:
            write_results(run, state)
            say(FileRobot(run.out_dir).message(folder, len(pending.proposals)))
            return results(run, state)
        add_observations(run, state, path)
        advance(run, state)
        last = state.observed_rounds[-1]
        say(f"round {last.index}: {len(last.trials.objectives)} trials by robot={run.settings.robot}, "
            f"mean |predicted - observed| L_task {_fmt(last.prediction_mae_N)} N")
    out = write_results(run, state)
    say(f"loop stopped: {state.stopped.message}")
    return out


def _more_budget(run: LoopRun, state: LoopState) -> bool:
    """Whether a loop stopped by its budget may run another round under this invocation's ``loop.rounds``."""
    return state.stopped is not None and state.stopped.reason == "budget" and len(state.rounds) < int(run.loop.rounds)


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3g}"


__all__ = ["CONFIG", "LOOP_RESULTS", "LoopRun", "LoopStateError", "STATE", "add_observations", "advance",
           "loop_fingerprint", "propose", "results", "resume_config", "run_loop", "save_config"]
