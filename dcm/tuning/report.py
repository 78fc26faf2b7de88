"""Figures of a tuning run: the Pareto fronts, and the forces a validated solution realises."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dcm.tuning.pareto import pareto_mask  # noqa: E402


def _front(points: np.ndarray) -> np.ndarray:
    points = points[np.isfinite(points).all(axis=1)]
    front = points[pareto_mask(points)]
    return front[np.argsort(front[:, 1])]


def draw_pareto(ax: plt.Axes, predicted: np.ndarray, validated: np.ndarray, robot_based: np.ndarray,
                reference: np.ndarray, model_name: str) -> None:
    """Objective space: every virtual trial, the predicted front, its simulator validation and robot-based trials."""
    ax.scatter(predicted[:, 1], predicted[:, 0], s=6, c="0.8", label=f"virtual trials ({model_name})")
    front = _front(predicted)
    ax.step(front[:, 1], front[:, 0], where="post", c="tab:blue", lw=1.2, label="predicted Pareto front")
    if len(robot_based):
        ax.scatter(robot_based[:, 1], robot_based[:, 0], s=14, marker="x", c="tab:orange",
                   label=f"robot-based trials (N={len(robot_based)})")
        rb_front = _front(robot_based)
        ax.step(rb_front[:, 1], rb_front[:, 0], where="post", c="tab:orange", lw=1.2)
    ax.scatter(validated[:, 1], validated[:, 0], s=40, c="tab:blue", edgecolors="k",
               label="robot-free solutions, validated in sim", zorder=3)
    ax.scatter([reference[1]], [reference[0]], marker="*", s=80, c="k", label="hypervolume reference")
    ax.set_xlabel("L_comp  [kN/m]  (mean translational stiffness norm)")
    ax.set_ylabel("L_task  [N]  (force RMSE to the demo)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)


def draw_forces(axes: list[plt.Axes], t: np.ndarray, force_demo: np.ndarray, force_predicted: np.ndarray | None,
                force_realised: np.ndarray, channels: tuple[int, ...] = (0, 1, 2)) -> None:
    """Demo, predicted (if the predictor has forces) and simulator-realised force, one axis per channel."""
    for ax, axis in zip(axes, channels):
        ax.plot(t, force_demo[:, axis], "k--", lw=1.2, label="demo")
        if force_predicted is not None:
            ax.plot(t, force_predicted[:, axis], c="tab:blue", lw=1.0, label="predicted by the model")
        ax.plot(t, force_realised[:, axis], c="tab:orange", lw=1.0, label="realised in the simulator")
        ax.set_ylabel(f"{('F_x', 'F_y', 'F_z')[axis]} [N]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=3)


def draw_stiffness(ax: plt.Axes, t: np.ndarray, stiffness: np.ndarray) -> None:
    """The translational stiffness schedule K_x, K_y, K_z over time."""
    for axis, name in enumerate(("K_x", "K_y", "K_z")):
        ax.plot(t, stiffness[:, axis], lw=1.0, label=name)
    ax.set_ylabel("stiffness [N/m]")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=7, ncol=3)
    ax.grid(alpha=0.3)


def plot_pareto(path: Path, predicted: np.ndarray, validated: np.ndarray, robot_based: np.ndarray,
                reference: np.ndarray, model_name: str) -> None:
    """The Pareto figure alone (see :func:`draw_pareto`)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    draw_pareto(ax, predicted, validated, robot_based, reference, model_name)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_solution_forces(path: Path, dt: float, force_demo: np.ndarray, force_predicted: np.ndarray | None,
                         force_realised: np.ndarray, stiffness: np.ndarray, title: str) -> None:
    """Demo, predicted and simulator-realised forces of one solution, over its stiffness schedule."""
    t = np.arange(len(force_demo)) * dt
    fig, axes = plt.subplots(4, 1, figsize=(7, 7.5), sharex=True)
    draw_forces(list(axes[:3]), t, force_demo, force_predicted, force_realised)
    draw_stiffness(axes[3], t, stiffness)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_overview(path: Path, pareto: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, str], dt: float,
                  force_demo: np.ndarray, force_predicted: np.ndarray | None, force_realised: np.ndarray,
                  stiffness: np.ndarray, title: str) -> None:
    """One picture of a tuning run: the Pareto fronts beside the chosen solution's normal force and schedule."""
    t = np.arange(len(force_demo)) * dt
    fig = plt.figure(figsize=(12, 4.8))
    grid = fig.add_gridspec(2, 2, width_ratios=(1, 1.2))
    draw_pareto(fig.add_subplot(grid[:, 0]), *pareto)
    force_ax = fig.add_subplot(grid[0, 1])
    draw_forces([force_ax], t, force_demo, force_predicted, force_realised, channels=(2,))
    draw_stiffness(fig.add_subplot(grid[1, 1], sharex=force_ax), t, stiffness)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
