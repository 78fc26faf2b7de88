"""Render one demo and one rollout to a PNG: the bowl with the paths, and F_demo against F_obs.

    python -m dcm.sim.render --out docs/demo_rollout.png [--embodiment panda|tool] [--demo data/demos/spiral.yaml]

The rollout uses a three-phase stiffness schedule (equal-time phases, the tuner's search space), so the
picture shows how a schedule different from the demonstrator's reproduces (or misses) the demo force.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from dcm.console import print_error
from dcm.control import equal_time_phases, schedule_from_phases
from dcm.shipped import SHIPPED_ROOT, shipped_path

DEFAULT_DEMO = SHIPPED_ROOT / "data" / "demos" / "spiral.yaml"
# [Kx, Ky, Kz] per phase [N/m]: stiff start, compliant middle, medium end.
DEFAULT_PHASES_NPM = [[1200.0, 1200.0, 1000.0], [300.0, 300.0, 400.0], [700.0, 700.0, 700.0]]


def render(
    out: str | Path,
    embodiment: str = "panda",
    demo_path: str | Path = DEFAULT_DEMO,
    domain: str = "nominal",
    phases_Npm: list[list[float]] | None = None,
    seed: int = 0,
) -> Path:
    """Record the demo, roll out the schedule, draw the figure; returns the PNG path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dcm.sim.demos import DemoSpec
    from dcm.sim.domain import DomainSpec
    from dcm.sim.rollout import Simulator

    spec = DemoSpec.load(shipped_path(demo_path))
    sim = Simulator(embodiment, spec.bowl, DomainSpec.preset(domain), seed=seed)
    t0 = time.perf_counter()
    demo = sim.record_demo(spec)
    horizon = demo.horizon
    stiffness = schedule_from_phases(np.asarray(phases_Npm or DEFAULT_PHASES_NPM), equal_time_phases(horizon, 3))
    trial = sim.rollout(demo, stiffness)
    elapsed = time.perf_counter() - t0
    t = np.arange(horizon) * demo.dt
    bowl = spec.bowl

    fig = plt.figure(figsize=(13, 6.6), constrained_layout=True)
    grid = fig.add_gridspec(4, 2, width_ratios=[1.1, 1.0], wspace=0.08)
    ax3d = fig.add_subplot(grid[:, 0], projection="3d")
    hx, hy = bowl.semi_axes_m
    gx, gy = np.meshgrid(np.linspace(-hx, hx, 70), np.linspace(-hy, hy, 70))
    inside = np.asarray(bowl.contains(gx, gy))
    gz = np.where(inside, bowl.height(gx, gy), np.nan)
    ax3d.plot_surface(gx * 100, gy * 100, gz * 100, cmap="Blues_r", alpha=0.45, linewidth=0, antialiased=True,
                      rcount=70, ccount=70, vmin=-0.02 * 100, vmax=bowl.rim_height_m * 100 + 1)
    lift = 0.15  # cm, keeps the paths visible above the translucent surface
    ax3d.plot(demo.x_demo[:, 0] * 100, demo.x_demo[:, 1] * 100, demo.x_demo[:, 2] * 100 + lift,
              color="black", lw=2.0, label="demo path $x_{demo}$")
    ax3d.plot(trial.x_obs[:, 0] * 100, trial.x_obs[:, 1] * 100, trial.x_obs[:, 2] * 100 + lift,
              color="tab:orange", lw=1.3, ls="--", label="rollout $x_{obs}$")
    ax3d.plot(trial.x_attr[:, 0] * 100, trial.x_attr[:, 1] * 100, trial.x_attr[:, 2] * 100,
              color="tab:purple", lw=0.9, alpha=0.7, label="attractor $x_{attr}$")
    ax3d.scatter(*(demo.x_demo[0, :3] * 100), color="green", s=30, label="start")
    ax3d.set_xlabel("x [cm]")
    ax3d.set_ylabel("y [cm]")
    ax3d.set_zlabel("z [cm]", labelpad=2)
    ax3d.set_box_aspect((hx, hy, max(bowl.rim_height_m, 0.02) * 1.6), zoom=1.1)
    ax3d.view_init(elev=32, azim=-60)
    ax3d.legend(loc="upper left", fontsize=8)
    ax3d.set_title(f"{bowl.shape.replace('_', ' ')} bowl, rim {bowl.rim_radius_m * 100:.0f} cm, "
                   f"depth {bowl.depth_m * 100:.0f} cm — {spec.family} demo", fontsize=10)

    labels = ["$F_x$", "$F_y$", "$F_z$"]
    ax_first = None
    for i in range(3):
        ax = fig.add_subplot(grid[i, 1], sharex=ax_first)
        ax_first = ax_first or ax
        ax.plot(t, demo.force_demo[:, i], color="black", lw=1.6, label="$F_{demo}$")
        ax.plot(t, trial.force_obs[:, i], color="tab:orange", lw=1.3, ls="--", label="$F_{obs}$")
        ax.set_ylabel(f"{labels[i]} [N]")
        ax.grid(alpha=0.3)
        ax.tick_params(labelbottom=False)
        if i == 0:
            ax.legend(loc="upper right", fontsize=8, ncol=2)
    ax_k = fig.add_subplot(grid[3, 1], sharex=ax_first)
    for i, (name, color) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        ax_k.plot(t, stiffness[:, i], color=color, lw=0.8, ls=":", alpha=0.8)
        ax_k.plot(t, trial.stiffness_applied[:, i], color=color, lw=1.4, label=f"$K_{name}$")
    ax_k.plot([], [], color="gray", lw=0.8, ls=":", label="commanded")
    ax_k.set_ylabel("K [N/m]")
    ax_k.set_xlabel("time [s]")
    ax_k.grid(alpha=0.3)
    ax_k.legend(loc="upper right", fontsize=8, ncol=4)
    status = f"FAILED: {trial.failure_reason}" if trial.failed else (
        f"$L_{{task}}$ = {trial.L_task:.2f} N,  $L_{{comp}}$ = {trial.L_comp:.2f} kN/m")
    fig.suptitle(f"{embodiment} embodiment, {sim.domain.name} domain, {sim.control_hz:g} Hz, H = {horizon}:  {status}",
                 fontsize=11)

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    print(f"wrote {out.resolve()}  ({embodiment}, demo {demo_path}, L_task {trial.L_task:.3f} N, "
          f"L_comp {trial.L_comp:.3f} kN/m, {elapsed:.1f} s)")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/demo_rollout.png", help="PNG file to write")
    parser.add_argument("--embodiment", default="panda", choices=["panda", "tool"])
    parser.add_argument("--demo", default=str(DEFAULT_DEMO), help="demo spec (YAML/JSON)")
    parser.add_argument("--domain", default="nominal", choices=["nominal", "realistic"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        render(args.out, args.embodiment, args.demo, args.domain, seed=args.seed)
    except ValueError as err:  # bad spec, waypoint file, unavailable embodiment: say what, no traceback
        print_error(err)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
