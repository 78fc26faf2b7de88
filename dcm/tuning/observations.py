"""Robot trials of a tuning run's proposals, read from a dataset file and checked against the run's skill.

The trials come back as a dataset HDF5 (:mod:`dcm.data.schema`; written by ``python -m dcm.data.import_logs``
from robot logs, or by the simulator robot). Each trial's per-phase stiffness is recovered from its K channel
on the run's phase boundaries, its L_task is scored against the run's own demo force over the run's window, and
its L_comp comes from that per-phase stiffness, so every observation is judged as the run judges its proposals.

Trials of another skill are refused before anything is written, with one line naming what differs: the
control rate, the horizon, a simulator embodiment or domain other than the run's (real-robot logs carry their
own), the demo (each trial's ``demo`` spec when the log has it, else its x_demo against the run's), the phases
(a K channel that is not constant within the run's phases) or a stiffness outside the search space.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.control import compliance_loss

DEMO_TOLERANCE_M = 0.005  # x_demo of a log without a demo spec may differ from the run's by this much
PHASE_TOLERANCE = 0.02  # relative spread of K allowed within a phase (resampling, rounding in the log)


class ObservationMismatch(ValueError):
    """Observations that are not trials of this run's skill; the message names the file and what differs."""


@dataclass
class Observations:
    """The usable content of one observations file for one run."""

    path: Path
    sha256: str
    names: list[str]  # trajectory names in the file
    phase_stiffness: np.ndarray  # (N, P, axes) N/m, recovered from K: the search space's values
    objectives: np.ndarray  # (N, 2) observed (L_task N, L_comp kN/m); NaN L_task for a failed trial


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def recover_phases(stiffness: np.ndarray, boundaries: np.ndarray, where: str) -> np.ndarray:
    """Per-phase translational stiffness (P, 3) of a logged K channel (H, 6): each phase's median, the step on
    either side of a boundary left out (a resampled log may shift a change by one step). Raises
    :class:`ObservationMismatch` when K is not constant within a phase."""
    phases = []
    for p, (start, stop) in enumerate(zip(boundaries[:-1], boundaries[1:])):
        inner = stiffness[start + 1 : max(stop - 1, start + 2), :3] if stop - start > 3 else stiffness[start:stop, :3]
        level = np.median(inner, axis=0)
        spread = np.abs(inner - level) / level
        if spread.max() > PHASE_TOLERANCE:
            step, axis = np.unravel_index(np.argmax(spread), spread.shape)
            raise ObservationMismatch(
                f"{where}: K{'xyz'[axis]} changes within phase {p + 1} (steps {start}..{stop - 1} of the run's "
                f"phase boundaries {boundaries.tolist()}), at step {start + 1 + int(step)}: not a schedule of this "
                "run's phases")
        phases.append(level)
    return np.asarray(phases, dtype=np.float64)


def _differences(expected: dict[str, Any], found: dict[str, Any], prefix: str) -> str:
    from dcm.configs import config_diff

    return "; ".join(f"{prefix}{line}" for line in config_diff(expected, found)[:3])


def load_observations(path: str | Path, run: dict[str, Any], skill: Any, space: Any) -> Observations:
    """Read ``path`` and check it against the run (``run``: its ``skill`` fingerprint, i.e. demo, embodiment,
    domain and control rate); ``skill`` scores the trials, ``space`` bounds their stiffness."""
    from dcm.data.schema import load_dataset
    from dcm.sim.rollout import EMBODIMENTS

    path = Path(path)
    data = load_dataset(path, include_failed=True)  # DatasetError names the file and the field
    where = f"observations {path}"
    control_hz = float(run["control_hz"])
    if not np.isclose(data.control_hz, control_hz):
        raise ObservationMismatch(f"{where}: control rate {data.control_hz:g} Hz, this run's is {control_hz:g} Hz "
                                  "(control_hz)")
    horizon = len(skill.x_demo)
    if data.horizon != horizon:
        raise ObservationMismatch(f"{where}: {data.horizon} steps ({data.horizon / control_hz:g} s) per trial, this "
                                  f"run's demo has {horizon} ({horizon / control_hz:g} s)")
    embodiment = data.attrs.get("embodiment")
    if embodiment in EMBODIMENTS and embodiment != run["embodiment"]:
        raise ObservationMismatch(f"{where}: simulated on embodiment {embodiment}, this run's is {run['embodiment']}")
    domain = data.attrs.get("domain")
    domain = json.loads(domain) if isinstance(domain, str) else domain
    if isinstance(domain, dict) and domain.get("name") != "real" and domain != run["domain"]:
        raise ObservationMismatch(f"{where}: another domain than this run's: "
                                  + _differences(run["domain"], domain, "domain."))
    boundaries = np.asarray(skill.boundaries)
    phases, objectives = [], []
    for i, (name, meta) in enumerate(zip(data.names, data.meta)):
        trajectory = f"{where}, trajectory {name}"
        spec = meta.get("demo")
        spec = json.loads(spec) if isinstance(spec, str) else spec
        if spec:
            if spec != run["demo"]:
                raise ObservationMismatch(f"{trajectory}: another demo than this run's: "
                                          + _differences(run["demo"], spec, "demo."))
        else:
            error = np.abs(data.arrays["x_demo"][i, :, :3] - skill.x_demo[:, :3]).max()
            if error > DEMO_TOLERANCE_M:
                raise ObservationMismatch(f"{trajectory}: its x_demo is up to {error:.3g} m from this run's demo "
                                          f"(allowed {DEMO_TOLERANCE_M:g} m) and it names no demo spec")
        k = recover_phases(np.asarray(data.arrays["K"][i], np.float64), boundaries, trajectory)
        low, high = space.min_Npm * (1 - PHASE_TOLERANCE), space.max_Npm * (1 + PHASE_TOLERANCE)
        if k.min() < low or k.max() > high:
            raise ObservationMismatch(f"{trajectory}: per-phase stiffness {np.round(k, 1).tolist()} N/m leaves the "
                                      f"search space [{space.min_Npm:g}, {space.max_Npm:g}] N/m (stiffness.min_Npm, "
                                      "stiffness.max_Npm)")
        try:
            k = space.from_diagonal(np.clip(k, space.min_Npm, space.max_Npm))
        except ValueError as err:
            raise ObservationMismatch(f"{trajectory}: {err} (stiffness.frame={space.frame})") from None
        failed = bool(meta.get("failed", False))
        force, pose = (np.asarray(data.arrays[key][i], np.float64) for key in ("F_obs", "x_obs"))
        observed_task = np.nan if failed else skill.task_loss(force, pose)
        phases.append(k)
        objectives.append([observed_task, float(compliance_loss(skill.schedules(k[None]))[0])])
    return Observations(path, file_sha256(path), list(data.names), np.stack(phases), np.asarray(objectives))


__all__ = ["ObservationMismatch", "Observations", "file_sha256", "load_observations", "recover_phases"]
