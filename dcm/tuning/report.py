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


def plot_pareto(
    path: Path,
    predicted: np.ndarray,
    validated: np.ndarray,
    robot_based: np.ndarray,
    reference: np.ndarray,
    model_name: str,
) -> None:
    """Objective space: every virtual trial, the predicted front, its simulator validation and robot-based trials."""
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
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
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_solution_forces(
    path: Path,
    dt: float,
    force_demo: np.ndarray,
    force_predicted: np.ndarray | None,
    force_realised: np.ndarray,
    stiffness: np.ndarray,
    title: str,
) -> None:
    """Demo, predicted (if the predictor has forces) and simulator-realised forces of one solution, over its
    stiffness schedule."""
    t = np.arange(len(force_demo)) * dt
    fig, axes = plt.subplots(4, 1, figsize=(7, 7.5), sharex=True)
    for axis, name in enumerate(("F_x", "F_y", "F_z")):
        ax = axes[axis]
        ax.plot(t, force_demo[:, axis], "k--", lw=1.2, label="demo")
        if force_predicted is not None:
            ax.plot(t, force_predicted[:, axis], c="tab:blue", lw=1.0, label="predicted by the model")
        ax.plot(t, force_realised[:, axis], c="tab:orange", lw=1.0, label="realised in the simulator")
        ax.set_ylabel(f"{name} [N]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=3)
    for axis, name in enumerate(("K_x", "K_y", "K_z")):
        axes[3].plot(t, stiffness[:, axis], lw=1.0, label=name)
    axes[3].set_ylabel("stiffness [N/m]")
    axes[3].set_xlabel("time [s]")
    axes[3].legend(fontsize=7, ncol=3)
    axes[3].grid(alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
