"""Who runs a round of proposed schedules: the simulator, or a real robot through files.

Both get a round folder (:mod:`dcm.tuning.schedule_files`) that the loop has already written.
:class:`SimulatorRobot` runs every schedule there and then, and writes its trials as a dataset file into the
folder, so they come back through the same checks as a real robot's imported logs.
:class:`FileRobot` runs nothing: a person runs the schedules on the robot, imports the logs and resumes the
run; it returns None and the message to print.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

SIM_OBSERVATIONS = "observations_sim.h5"


class Robot(Protocol):
    """Runs the round in ``folder``: the observations file when it has the trials, else None."""

    def run(self, folder: Path, proposals: np.ndarray, round_index: int) -> Path | None: ...


@dataclass
class SimulatorRobot:
    """The simulator as the robot: one rollout per proposal, seeded by the run's simulator seed and the
    schedule (``repeat`` 0: the draw a robot-based search's trial of that schedule gets; a judgement of a
    solution over fresh rollouts uses repeats 1, 2, ...)."""

    simulator: Any
    demo: Any
    skill: Any

    def trials(self, proposals: np.ndarray) -> list[Any]:
        return [self.simulator.rollout(self.demo, self.skill.in_frame(k)) for k in self.skill.schedules(proposals)]

    def run(self, folder: Path, proposals: np.ndarray, round_index: int) -> Path:
        from dcm.data.schema import write_dataset

        trials = self.trials(proposals)
        records = [trial_record(t, self.demo, self.simulator, i) for i, t in enumerate(trials)]
        path = folder / SIM_OBSERVATIONS
        attrs = {"control_hz": self.simulator.control_hz, "embodiment": self.simulator.embodiment_name,
                 "domain": self.simulator.domain.to_dict(), "dataset": f"robot=sim round {round_index}"}
        write_dataset(path, records, {"test": [r["name"] for r in records]}, attrs)
        return path


def trial_record(trial: Any, demo: Any, simulator: Any, index: int) -> dict[str, Any]:
    """A simulated trial as a dataset trajectory (:func:`dcm.data.schema.write_dataset`)."""
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return {"name": f"traj_{index:06d}", "x_demo": f32(demo.x_demo), "F_demo": f32(demo.force_demo),
            "x_attr": f32(trial.x_attr), "K": f32(trial.stiffness), "x_obs": f32(trial.x_obs),
            "F_obs": f32(trial.force_obs), "contact": np.asarray(trial.contact), "L_task": trial.L_task,
            "L_comp": trial.L_comp, "failed": bool(trial.failed), "failure_reason": trial.failure_reason,
            "demo_id": 0, "trial": index, "demo": demo.spec.to_dict(), "embodiment": simulator.embodiment_name,
            "domain": simulator.domain.to_dict(), "seed": simulator.seed}


@dataclass
class FileRobot:
    """A real robot: the round folder is the hand-over; a person runs it and brings the logs back."""

    run_dir: Path

    def run(self, folder: Path, proposals: np.ndarray, round_index: int) -> None:
        return None

    def message(self, folder: Path, count: int) -> str:
        return (f"round {folder.name.split('_')[-1]}: run the {count} schedules of {folder}/round.yaml on the robot, "
                "import the logs (python -m dcm.data.import_logs <logs> --out <trials.h5>), then: "
                f"python tune.py resume={self.run_dir} observations=<trials.h5>")


def make_robot(name: str, run_dir: Path, simulator: Any, demo: Any, skill: Any) -> Robot:
    if name == "sim":
        return SimulatorRobot(simulator, demo, skill)
    return FileRobot(run_dir)


__all__ = ["FileRobot", "Robot", "SIM_OBSERVATIONS", "SimulatorRobot", "make_robot", "trial_record"]
