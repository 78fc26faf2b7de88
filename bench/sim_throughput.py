"""Simulator throughput: control steps/s of each embodiment beside raw physics and robosuite's stock Panda.

    MUJOCO_GL=egl python bench/sim_throughput.py [--rollouts 8] [--repeats 3] [--robosuite-steps 150] [--variants]
                                                 [--frames]

For each embodiment (``tool``, ``panda``) it records a spiral demo on the default bowl and times
``Simulator.rollout`` (control steps/s at 20 Hz, 25 physics substeps of 2 ms). Beside it, the raw ``mj_step``
rate of the *same* model: every control-period state of a rollout is restored and only
``mj_step(model, data, nstep=25)`` is timed, so the physics bound on the control rate is
mj_steps/s / substeps. Then robosuite's stock ``Wipe`` env (Panda + OSC, control_freq=20) is stepped with zero
and with random actions in the same process.

With ``--frames`` each embodiment also rolls out the same schedules (soft along one axis) in the world frame and
in the surface frame (``stiffness.frame=surface``: a frame that turns along the demo, the full matrix R diag Rᵀ),
alternating within each repeat.

Targets: ``tool`` >= 50% of its raw mj_step-bound control rate; ``panda`` >= 5x robosuite's OSC env; a
surface-frame rollout <= 1.2x the cost of a world-frame one.
Each figure is the median over ``--repeats`` repeats, measured in process CPU time (steadier when other jobs
share the machine) and in wall-clock time; the ratios use matching clocks.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from dcm.sim import BowlSpec, DemoSpec, Simulator  # noqa: E402


class Clock:
    """Wall-clock and process CPU time together: on a shared machine CPU time is the steadier cost measure."""

    def __init__(self) -> None:
        self.wall = 0.0
        self.cpu = 0.0

    def __enter__(self) -> Clock:
        self._w, self._c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall += time.perf_counter() - self._w
        self.cpu += time.process_time() - self._c


def bench_embodiment(name: str, rollouts: int, repeats: int) -> dict[str, float]:
    """Rollout control rate and the raw mj_step-bound control rate of the same model and states.

    Rollouts and the raw replay alternate within each repeat so both see the same machine load.
    """
    t0 = time.perf_counter()
    sim = Simulator(embodiment=name, bowl=BowlSpec())
    build_s = time.perf_counter() - t0
    demo = sim.record_demo(DemoSpec(family="spiral", bowl=BowlSpec()))
    horizon = demo.horizon
    schedules = [sim.constant_stiffness(demo, k) for k in np.linspace(300.0, 1500.0, rollouts)]

    # The state at every control period of one rollout, re-created by stepping the embodiment as rollout does.
    emb = sim.embodiment
    model, data = emb.model, emb.data
    n_sub = int(round(sim.dt / model.opt.timestep))
    trial = sim.rollout(demo, schedules[len(schedules) // 2])
    emb.reset(np.asarray(demo.start_pose, dtype=float))
    kind = mujoco.mjtState.mjSTATE_INTEGRATION
    states, ncon = [], []
    for k in range(horizon):
        states.append(np.empty(mujoco.mj_stateSize(model, kind)))
        mujoco.mj_getState(model, data, states[-1], kind)
        emb.step(trial.x_attr[k], trial.stiffness_applied[k])
        ncon.append(data.ncon)

    rows = []
    for _ in range(repeats):
        roll = Clock()
        with roll:
            for stiffness in schedules:
                if sim.rollout(demo, stiffness).failed:
                    raise RuntimeError(f"{name}: a benchmark rollout failed")
        raw = Clock()
        for state in states:
            mujoco.mj_setState(model, data, state, kind)
            with raw:
                mujoco.mj_step(model, data, nstep=n_sub)
        steps = rollouts * horizon
        rows.append((steps / roll.cpu, steps / roll.wall, horizon / raw.cpu, horizon / raw.wall))
    med = [statistics.median(col) for col in zip(*rows)]
    ratios = [r[0] / r[2] for r in rows]
    return {
        "build_s": build_s,
        "rate": med[0],
        "rate_wall": med[1],
        "raw": med[2],
        "raw_wall": med[3],
        "ratio": statistics.median(ratios),
        "mj_steps_per_s": med[2] * n_sub,
        "substeps": n_sub,
        "ncon_mean": float(np.mean(ncon)),
    }


def bench_frames(name: str, rollouts: int, repeats: int) -> dict[str, float]:
    """Control steps/s (CPU time) of world- and surface-frame rollouts of the same diagonals, and their cost ratio."""
    from dcm.control import StiffnessSchedule

    sim = Simulator(embodiment=name, bowl=BowlSpec())
    demo = sim.record_demo(DemoSpec(family="spiral", bowl=BowlSpec()))
    diagonals = [sim.constant_stiffness(demo, [k, k, k / 3.0]) for k in np.linspace(450.0, 1500.0, rollouts)]
    frames = {"world": diagonals,
              "surface": [StiffnessSchedule.for_demo(k, "surface", demo.x_demo, demo.force_demo) for k in diagonals]}
    cpu: dict[str, list[float]] = {frame: [] for frame in frames}
    for _ in range(repeats):
        for frame, schedules in frames.items():
            clock = Clock()
            with clock:
                if any(sim.rollout(demo, k).failed for k in schedules):
                    raise RuntimeError(f"{name}: a {frame}-frame benchmark rollout failed")
            cpu[frame].append(rollouts * demo.horizon / clock.cpu)
    world, surface = statistics.median(cpu["world"]), statistics.median(cpu["surface"])
    return {"world": world, "surface": surface, "cost_ratio": world / surface}


def bench_panda_variants(repeats: int) -> list[tuple[str, float, float]]:
    """The panda's control-law variants: speed and force agreement with the per-physics-step Python controller.

    Returns (label, control steps/s by CPU time, contact-force RMSE [N] against the Python reference).
    """
    from dcm.control import task_loss
    from dcm.sim import DomainSpec
    from dcm.sim.panda import PandaEmbodiment

    bowl = BowlSpec()
    sim = Simulator(embodiment="panda", bowl=bowl)
    demo = sim.record_demo(DemoSpec(family="spiral", bowl=bowl))
    schedules = [sim.constant_stiffness(demo, k) for k in (300.0, 800.0, 1500.0)]
    variants = {
        "actuator, slow terms per period (default)": {},
        "actuator, slow terms per physics step": {"slow_terms": "substep"},
        "python law per physics step, slow per period": {"controller": "python"},
        "python law + slow terms per physics step (ref)": {"controller": "python", "slow_terms": "substep"},
    }
    forces, rates = {}, {}
    key = next(iter(sim._embodiments))
    for label, kwargs in variants.items():
        sim._embodiments[key] = PandaEmbodiment(bowl, DomainSpec(), visual=False, **kwargs)
        cpu = []
        for _ in range(repeats):
            clock = Clock()
            with clock:
                trials = [sim.rollout(demo, k) for k in schedules]
            cpu.append(len(schedules) * demo.horizon / clock.cpu)
        forces[label] = [t.force_obs for t in trials]
        rates[label] = statistics.median(cpu)
    ref = forces["python law + slow terms per physics step (ref)"]
    return [
        (label, rates[label], max(float(task_loss(a, b)) for a, b in zip(forces[label], ref)))
        for label in variants
    ]


def bench_robosuite(steps: int, repeats: int) -> dict[str, float]:
    """robosuite's stock Panda OSC Wipe env stepped with zero and with random actions."""
    import robosuite

    t0 = time.perf_counter()
    env = robosuite.make(
        "Wipe",
        robots="Panda",
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        control_freq=20,
    )
    env.reset()
    build_s = time.perf_counter() - t0
    low, high = env.action_spec
    rng = np.random.default_rng(0)
    out: dict[str, float] = {"build_s": build_s}
    for label, make_action in (
        ("zero", lambda: np.zeros_like(low)),
        ("random", lambda: rng.uniform(low, high)),
    ):
        cpu, wall = [], []
        for _ in range(repeats):
            env.reset()
            clock = Clock()
            with clock:
                for _ in range(steps):
                    _, _, done, _ = env.step(make_action())
                    if done:
                        env.reset()
            cpu.append(steps / clock.cpu)
            wall.append(steps / clock.wall)
        out[label], out[label + "_wall"] = statistics.median(cpu), statistics.median(wall)
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rollouts", type=int, default=8, help="rollouts per timed repeat (H=160 each)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats; the median is reported")
    parser.add_argument("--robosuite-steps", type=int, default=150, help="env steps per robosuite repeat")
    parser.add_argument("--skip-robosuite", action="store_true")
    parser.add_argument("--variants", action="store_true", help="also time the panda's control-law variants")
    parser.add_argument("--frames", action="store_true", help="also time surface- against world-frame rollouts")
    args = parser.parse_args()

    t_start = time.perf_counter()
    print(f"mujoco {mujoco.__version__}, {os.cpu_count()} CPUs; shared machine: figures are noisy.")
    results = {name: bench_embodiment(name, args.rollouts, args.repeats) for name in ("tool", "panda")}
    rs = None if args.skip_robosuite else bench_robosuite(args.robosuite_steps, args.repeats)

    print()
    print("control steps/s (median of repeats; by process CPU time, and by wall clock)")
    print(f"{'setup':46s} {'cpu':>8s} {'wall':>8s} {'build s':>8s}")
    for name, r in results.items():
        print(f"{name + ' Simulator.rollout':46s} {r['rate']:8.0f} {r['rate_wall']:8.0f} {r['build_s']:8.2f}")
        label = f"{name} raw mj_step bound ({r['mj_steps_per_s']:.0f} steps/s / {r['substeps']})"
        print(f"{label:46s} {r['raw']:8.0f} {r['raw_wall']:8.0f}")
    if rs is not None:
        print(f"{'robosuite Wipe Panda OSC, zero actions':46s} {rs['zero']:8.0f} {rs['zero_wall']:8.0f} {rs['build_s']:8.2f}")
        print(f"{'robosuite Wipe Panda OSC, random actions':46s} {rs['random']:8.0f} {rs['random_wall']:8.0f}")

    print()
    for name, r in results.items():
        print(f"{name}: {r['ncon_mean']:.1f} contacts per physics step on average (sphere on heightfield facets)")
    tool = results["tool"]
    print(f"tool:  {tool['ratio']:.0%} of its raw mj_step-bound control rate (target >= 50%): "
          f"{'PASS' if tool['ratio'] >= 0.5 else 'MISS'}")
    print(f"panda: {results['panda']['ratio']:.0%} of its raw mj_step-bound control rate (for reference)")
    if rs is not None:
        for clock, key in (("cpu", ""), ("wall", "_wall")):
            osc = max(rs["zero" + key], rs["random" + key])  # the faster robosuite figure: the harder comparison
            ratio = results["panda"]["rate" + key] / osc
            print(f"panda: {ratio:.1f}x robosuite's OSC Wipe env ({osc:.0f} steps/s, {clock}) (target >= 5x): "
                  f"{'PASS' if ratio >= 5.0 else 'MISS'}")
    if args.variants:
        print("\npanda control-law variants (spiral demo, K = 300/800/1500 N/m)")
        print(f"{'variant':50s} {'cpu steps/s':>11s} {'max force RMSE vs ref [N]':>26s}")
        for label, rate, rmse in bench_panda_variants(min(args.repeats, 2)):
            print(f"{label:50s} {rate:11.0f} {rmse:26.3f}")
    if args.frames:
        print("\nstiffness frames (the same diagonals; control steps/s by CPU time)")
        for name in results:
            r = bench_frames(name, args.rollouts, args.repeats)
            print(f"{name}: world {r['world']:.0f}, surface {r['surface']:.0f}: a surface-frame rollout costs "
                  f"{r['cost_ratio']:.2f}x a world-frame one (target <= 1.2x): "
                  f"{'PASS' if r['cost_ratio'] <= 1.2 else 'MISS'}")
    print(f"\ntotal benchmark time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
